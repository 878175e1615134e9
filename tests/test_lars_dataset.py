"""The LARS tracker data set exporter: files, labels, consistency with the images."""

from __future__ import annotations

import json

import cv2
import numpy as np

from auv_envs.core.camera import CameraIntrinsics
from auv_envs.datasets.lars import export_dataset, load_sequence, main
from auv_envs.tasks.lars.stereo import StereoRig, triangulate


def test_export_and_reload(tmp_path):
    paths = export_dataset(tmp_path, episodes=2, seed=10, sea_state="severe", steps=40,
                           image_size=(160, 120))
    index = json.loads((tmp_path / "index.json").read_text())
    assert index["sequences"] == ["seq_0000", "seq_0001"]
    meta, labels = load_sequence(paths[0])
    assert meta["seed"] == 10 and meta["sea_state"] == "severe" and meta["frames"] == 40
    assert len(list((paths[0] / "left").glob("*.png"))) == 40
    image = cv2.imread(str(paths[0] / "left" / "000000.png"))
    assert image.shape == (120, 160, 3)
    assert labels["corners_px"].shape == (40, 2, 3, 2)
    assert labels["bbox"].shape == (40, 2, 4)
    # Corner pixels triangulate back to the stored camera-frame corners (eq. 2).
    k = meta["intrinsics"]
    intr = CameraIntrinsics(160, 120, k["fx"], k["fy"], k["cx"], k["cy"])
    rig = StereoRig(intr, intr, meta["baseline"])
    pts = triangulate(rig, labels["corners_px"][0, 0], labels["corners_px"][0, 1])
    np.testing.assert_allclose(pts, labels["corners_left_cam"][0], atol=1e-6)
    # Corners that are visible lie inside the AUV's box.
    for t in range(40):
        for cam in range(2):
            box = labels["bbox"][t, cam]
            for (u, v), seen in zip(labels["corners_px"][t, cam],
                                    labels["corners_visible"][t, cam], strict=True):
                if seen:
                    assert box[0] - 1 <= u <= box[2] + 1 and box[1] - 1 <= v <= box[3] + 1
    # Different seeds, different sequences.
    _, other = load_sequence(paths[1])
    assert not np.allclose(other["auv_position"], labels["auv_position"])


def test_command_line(tmp_path, capsys):
    main(["--out", str(tmp_path), "--episodes", "1", "--seed", "3", "--steps", "5",
          "--width", "64", "--height", "48"])
    assert "wrote 1 sequence" in capsys.readouterr().out
    meta, labels = load_sequence(tmp_path / "seq_0000")
    assert meta["sea_state"] == "calm" and labels["occluded"].sum() == 0
