"""Export labelled stereo sequences of the LARS capture task for trackers.

Command::

    python -m auv_envs.datasets.lars --out DIR --episodes N --seed S \\
        [--sea-state severe] [--steps 150] [--width 640 --height 480]

On-disk format (version 1)::

    DIR/index.json                  format version, arguments, sequence list
    DIR/seq_0000/meta.json          seed, sea state, difficulty, image size, calibration
                                    (fx, fy, cx, cy, baseline, hand-eye 4x4s)
    DIR/seq_0000/left/000000.png    RGB frames (8-bit PNG), one per step
    DIR/seq_0000/right/000000.png
    DIR/seq_0000/labels.npz         per-frame arrays, T frames:
        time              (T,)       s
        bbox              (T, 2, 4)  AUV box per image (left, right) as
                                     x_min, y_min, x_max, y_max in pixels,
                                     clipped to the image; NaN when out of view
        corners_px        (T, 2, 3, 2) marker corners A1, A2, A3, noise-free
        corners_visible   (T, 2, 3)  in the image and not under a crest
        corners_world     (T, 3, 3)  marker corners in the world frame, m
        corners_left_cam  (T, 3, 3)  the same in the left camera frame, m
        occluded          (T,)       a wash-over crest hides a corner
        distractors       (T,)       analogs (look-alikes) in the left image
        joint_position    (T, 3)     rad
        end_position      (T, 3)     arm end in the world frame, m
        auv_position      (T, 3)     AUV CG in the world frame, m

Pixel coordinates follow ``auv_envs.core.camera``: origin at the top-left
corner of the image, pixel centres at half-integers. The arm follows the AUV
with a privileged tracker (inverse kinematics on the true AUV position plus
a slow random wander, so the views vary); the labels never depend on it.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import cv2
import numpy as np

from auv_envs.core.camera import points_in_camera, project
from auv_envs.core.env import TaskEnv
from auv_envs.tasks.lars.env import CAMERA_MOUNT_IN_END, CONTROL_PERIOD, LARSCaptureTask
from auv_envs.tasks.lars.scene import auv_rotation

FORMAT_VERSION = 1


def tracking_action(env: TaskEnv, info: dict, wander=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Position-control action: arm end ``0.8 m + wander`` above the AUV, cameras over it.

    Privileged (uses ``info["true_position"]``): for data generation and
    tests, not an agent. ``env`` must use ``control="position"``.
    """
    env = env.unwrapped
    cal = env.calibration
    pos = info["true_position"]
    target = np.array(
        [pos[0] + wander[0], pos[1] - CAMERA_MOUNT_IN_END[1] + wander[1],
         pos[2] + cal.auv_diameter / 2.0 + 0.8 + wander[2]]
    )
    q = cal.arm.inverse_kinematics(target)
    lo, hi = cal.joint_limits[:, 0], cal.joint_limits[:, 1]
    return np.clip((2.0 * q - lo - hi) / (hi - lo), -1.0, 1.0).astype(np.float32)


def auv_bounding_boxes(env: TaskEnv, info: dict, q) -> np.ndarray:
    """AUV boxes (2, 4) in the left and right images: the projected hull box, clipped."""
    cal = env.unwrapped.calibration
    half_l, r = cal.auv_length / 2.0, cal.auv_diameter / 2.0
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    body = signs * (half_l, r, r)
    rot = auv_rotation(info["true_pitch"], info["true_yaw"], np)
    world = body @ rot.T + info["true_position"]
    k = cal.stereo.left
    out = np.full((2, 4), np.nan)
    for i, pose in enumerate(cal.camera_poses(q)):
        pixels, in_front = project(k, points_in_camera(world, pose[:3, 3], pose[:3, :3]))
        if not in_front.all():
            continue
        box = np.array([*pixels.min(axis=0), *pixels.max(axis=0)])
        box[[0, 2]] = np.clip(box[[0, 2]], 0.0, k.width)
        box[[1, 3]] = np.clip(box[[1, 3]], 0.0, k.height)
        if box[2] > box[0] and box[3] > box[1]:
            out[i] = box
    return out


def export_sequence(
    out_dir: Path, seed: int, sea_state: str, steps: int, image_size=(640, 480),
    difficulty: str = "easy",
) -> Path:
    """Render one seeded episode into ``out_dir`` (see the module docstring) at the
    env's ``difficulty`` level (default ``easy``, the released scene)."""
    out_dir = Path(out_dir)
    (out_dir / "left").mkdir(parents=True, exist_ok=True)
    (out_dir / "right").mkdir(parents=True, exist_ok=True)
    env = TaskEnv(LARSCaptureTask,
        obs_mode="stereo", sea_state=sea_state, control="position",
        image_size=tuple(image_size), time_limit=max(steps, 1) * CONTROL_PERIOD + 1.0,
        difficulty=difficulty,
    )
    try:
        obs, info = env.reset(seed=seed)
        # The tracker's wander comes from its own generator: the episode's
        # stream stays that of an agent-free reset.
        wander_rng = np.random.default_rng([seed, 7])
        amp = wander_rng.uniform(0.05, 0.25, 3) * (1.0, 1.0, 0.5)
        freq = wander_rng.uniform(0.05, 0.2, 3)
        phase = wander_rng.uniform(0, 2 * math.pi, 3)
        cal = env.calibration
        records = {k: [] for k in (
            "time", "bbox", "corners_px", "corners_visible", "corners_world",
            "corners_left_cam", "occluded", "distractors", "joint_position",
            "end_position", "auv_position")}
        for t in range(steps):
            q = env.physics.data.qpos.copy()  # full precision for the labels
            left_pose, _ = cal.camera_poses(q)
            cv2.imwrite(str(out_dir / "left" / f"{t:06d}.png"), obs["left"][..., ::-1])
            cv2.imwrite(str(out_dir / "right" / f"{t:06d}.png"), obs["right"][..., ::-1])
            records["time"].append(info["time"])
            records["bbox"].append(auv_bounding_boxes(env, info, q))
            records["corners_px"].append(info["true_pixels"])
            records["corners_visible"].append(info["true_visible"])
            records["corners_world"].append(info["true_corners"])
            records["corners_left_cam"].append(
                points_in_camera(info["true_corners"], left_pose[:3, 3], left_pose[:3, :3])
            )
            records["occluded"].append(info["marker_occluded"])
            records["distractors"].append(info["distractors_in_view"])
            records["joint_position"].append(q)
            records["end_position"].append(info["end_position"])
            records["auv_position"].append(info["true_position"])
            if t == steps - 1:
                break
            time = info["time"]
            wander = amp * np.sin(2 * math.pi * freq * time + phase)
            obs, _, terminated, truncated, info = env.step(tracking_action(env, info, wander))
            if terminated or truncated:
                break
        np.savez_compressed(out_dir / "labels.npz", **{k: np.array(v) for k, v in records.items()})
        k = cal.stereo.left
        meta = {
            "format_version": FORMAT_VERSION,
            "env_id": "auv_envs/LARSCapture-v0",
            "seed": int(seed),
            "sea_state": sea_state,
            "difficulty": difficulty,
            "frames": len(records["time"]),
            "image_size": [k.width, k.height],
            "frame_period": cal.control_period,
            "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
            "baseline": cal.stereo.baseline,
            "left_in_end": cal.left_in_end.tolist(),
            "right_in_end": cal.right_in_end.tolist(),
            "marker_sides": list(cal.marker_sides),
            "marker_depth_offset": cal.marker.depth_offset,
        }
        (out_dir / "meta.json").write_text(json.dumps(meta, indent=2))
    finally:
        env.close()
    return out_dir


def export_dataset(
    out: str | Path, episodes: int, seed: int, sea_state: str = "calm", steps: int = 150,
    image_size=(640, 480),
) -> list[Path]:
    """Export ``episodes`` sequences seeded ``seed, seed + 1, ...`` under ``out``."""
    if episodes < 1 or steps < 1:
        raise ValueError(f"episodes and steps must be >= 1, got {episodes}, {steps}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [
        export_sequence(out / f"seq_{i:04d}", seed + i, sea_state, steps, image_size)
        for i in range(episodes)
    ]
    index = {
        "format_version": FORMAT_VERSION,
        "sea_state": sea_state,
        "seed": seed,
        "episodes": episodes,
        "steps": steps,
        "image_size": list(image_size),
        "sequences": [p.name for p in paths],
    }
    (out / "index.json").write_text(json.dumps(index, indent=2))
    return paths


def load_sequence(path: str | Path) -> tuple[dict, dict]:
    """``(meta, labels)`` of one exported sequence; images stay on disk."""
    path = Path(path)
    meta = json.loads((path / "meta.json").read_text())
    with np.load(path / "labels.npz") as npz:
        labels = {k: npz[k] for k in npz.files}
    return meta, labels


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description="Export labelled LARS stereo sequences.")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sea-state", choices=("calm", "severe"), default="calm")
    parser.add_argument("--steps", type=int, default=150, help="frames per sequence")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    args = parser.parse_args(argv)
    paths = export_dataset(
        args.out, args.episodes, args.seed, args.sea_state, args.steps, (args.width, args.height)
    )
    print(f"wrote {len(paths)} sequence(s) to {args.out}")


if __name__ == "__main__":
    main()
