"""LTAT perception ([LTAT] §2.1): shipped tracker weights and their checks, marker
corners against the true projections, the online detector, re-acquisition after a
wash-over, and the ``ltat-ckf-pd`` registration.

Ground truth (``info["true_pixels"]``, ``true_visible``, ``marker_occluded``)
is read here only to score the front end, never passed to it.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from auv_envs.core.assets import sha256_file
from auv_envs.core.env import TaskEnv
from auv_envs.datasets.lars import tracking_action
from auv_envs.metrics import box_iou
from auv_envs.tasks.lars.env import LARSCaptureTask
from baselines.evaluation import EVAL_SEED_BASE
from baselines.lars.perception.corners import MarkerCornerExtractor
from baselines.lars.perception.detector import OnlineDetector
from baselines.lars.perception.front_end import LTATFrontEnd
from baselines.lars.perception.siamese import (
    ARCHITECTURE,
    META_FILE,
    WEIGHTS_FILE,
    Pyramid,
    SiameseNet,
    SiameseTracker,
    default_weights_dir,
    load_siamese,
    marker_box,
)
from baselines.lars.perception.stereo import find_marker_pair, match_stereo
from baselines.registry import agent_names, agent_spec, make_agent

#: Severe-sea episode with a wash-over over the marker at steps 16-34 and
#: analogs in view (found with the privileged tracking arm; seeds >= 100000
#: never train the tracker).
WASH_SEED = 100000
#: Re-acquisition: IoU with the true marker box above this, ...
REACQUIRE_IOU = 0.5
#: ... within this many frames of the marker being fully visible again.
REACQUIRE_FRAMES = 10
#: Corner error bound on calm frames, px (measured: mean <= 1.2, max 2.7 px).
CORNER_TOLERANCE = 3.5


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def shipped():
    return load_siamese()


def _rollout(seed, sea_state, steps, offset=(0.0, 0.0, 0.0), offset_from=0):
    """Stereo observations and infos with the exporter's privileged tracking arm,
    which moves ``offset`` (m, world) off its station from step ``offset_from`` on."""
    # (the default 30 s time limit is far beyond the <= 48 steps rolled out here)
    env = TaskEnv(LARSCaptureTask, obs_mode="stereo", sea_state=sea_state, control="position")
    try:
        obs, info = env.reset(seed=seed)
        out = [(obs, info)]
        for k in range(steps - 1):
            wander = offset if k >= offset_from else (0.0, 0.0, 0.0)
            obs, _, terminated, truncated, info = env.step(tracking_action(env, info, wander))
            out.append((obs, info))
            if terminated or truncated:
                break
        return out, env.calibration
    finally:
        env.close()


@pytest.fixture(scope="module")
def calm_rollout():
    return _rollout(EVAL_SEED_BASE + 5, "calm", 16)


@pytest.fixture(scope="module")
def wash_rollout():
    return _rollout(WASH_SEED, "severe", 48)


def _image_size(calibration):
    return calibration.stereo.left.width, calibration.stereo.left.height


# ---------------------------------------------------------------------- weights
def test_shipped_weights_load_small_and_documented(shipped):
    net, meta = shipped
    assert isinstance(net, SiameseNet) and not net.training
    assert meta["architecture"] == ARCHITECTURE
    for key in ("command", "seed", "data", "iterations", "wall_time_s", "package_version",
                "weights_sha256"):
        assert key in meta
    assert (default_weights_dir() / WEIGHTS_FILE).stat().st_size < 2_000_000
    train_seeds = [s for seeds in meta["data"]["train_seeds"].values() for s in seeds]
    assert max(train_seeds) < EVAL_SEED_BASE


def _copy_weights(tmp_path):
    target = tmp_path / "siamese"
    shutil.copytree(default_weights_dir(), target)
    return target


def test_missing_weights_name_the_training_command(tmp_path):
    target = _copy_weights(tmp_path)
    (target / WEIGHTS_FILE).unlink()
    with pytest.raises(FileNotFoundError, match="baselines.lars.training.siamese train"):
        load_siamese(target)
    with pytest.raises(FileNotFoundError, match="missing"):
        load_siamese(tmp_path / "nowhere")


def test_corrupt_weights_fail_the_checksum(tmp_path):
    target = _copy_weights(tmp_path)
    data = bytearray((target / WEIGHTS_FILE).read_bytes())
    data[len(data) // 2] ^= 0xFF
    (target / WEIGHTS_FILE).write_bytes(bytes(data))
    with pytest.raises(ValueError, match="corrupt"):
        load_siamese(target)


def test_corrupt_or_mismatched_metadata(tmp_path):
    target = _copy_weights(tmp_path)
    meta_path = target / META_FILE
    meta = json.loads(meta_path.read_text())
    meta_path.write_text("{not json")
    with pytest.raises(ValueError, match="corrupt Siamese tracker metadata"):
        load_siamese(target)
    meta["architecture"] = {**meta["architecture"], "channels": [8, 8, 8, 8, 8]}
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="architecture"):
        load_siamese(target)


def test_weights_of_another_shape_are_refused(tmp_path):
    target = _copy_weights(tmp_path)
    state = torch.load(target / WEIGHTS_FILE, weights_only=True)
    state.pop(next(iter(state)))
    torch.save(state, target / WEIGHTS_FILE)
    meta = json.loads((target / META_FILE).read_text())
    meta["weights_sha256"] = sha256_file(target / WEIGHTS_FILE)
    (target / META_FILE).write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="cannot load"):
        load_siamese(target)


# ---------------------------------------------------------------------- corners
def test_corners_on_calm_frames_match_true_projections(calm_rollout):
    rollout, calibration = calm_rollout
    extractor = MarkerCornerExtractor()
    checked = 0
    for obs, info in rollout[::3]:
        truth = info["true_pixels"]
        assert info["true_visible"].all()
        for v, key in enumerate(("left", "right")):
            corners = extractor.find(obs[key], marker_box(truth[v]))
            assert corners is not None
            err = np.linalg.norm(corners - truth[v], axis=1)
            # Labels: each corner is within tolerance of its own label's truth.
            assert err.max() <= CORNER_TOLERANCE, (v, corners, truth[v])
            checked += 1
    assert checked >= 10


def test_front_end_finds_marker_from_first_frame_without_truth(calm_rollout):
    rollout, calibration = calm_rollout
    front = LTATFrontEnd(calibration)
    front.reset(0)
    for k, (obs, info) in enumerate(rollout[:8]):
        features = front(obs, {})  # no truth passed in
        assert features["pixels"].dtype == np.float32 and features["pixels"].shape == (2, 3, 2)
        assert features["visible"].dtype == np.int8 and features["visible"].shape == (2, 3)
        np.testing.assert_array_equal(features["joint_position"], obs["joint_position"])
        assert features["visible"].all(), k
        err = np.linalg.norm(features["pixels"] - info["true_pixels"], axis=2)
        assert err.max() <= CORNER_TOLERANCE, (k, err)
    assert front.stats()["ltat_initialised_at"] == 0


def test_marker_cut_by_one_image_border_gives_the_corners_seen_in_both():
    """Arm held still while the AUV drifts: the apex leaves the left image first
    (seed 100004, from step 2; the right image keeps all three corners)."""
    env = TaskEnv(LARSCaptureTask, obs_mode="stereo", sea_state="calm", control="position")
    try:
        obs, info = env.reset(seed=EVAL_SEED_BASE + 4)
        lo, hi = env.calibration.joint_limits.T
        hold = ((2.0 * obs["joint_position"] - lo - hi) / (hi - lo)).astype(np.float32)
        front = LTATFrontEnd(env.calibration)
        front.reset(0)
        partial_frames = 0
        for _ in range(12):
            features = front(obs, {})
            vis = features["visible"].astype(bool)
            truth_vis = info["true_visible"].astype(bool)
            if not vis.all():  # a partial report never claims a corner outside the image
                assert not (vis & ~truth_vis).any()
            if vis.any():
                err = np.linalg.norm(features["pixels"] - info["true_pixels"], axis=2)[vis]
                assert err.max() <= CORNER_TOLERANCE
            if truth_vis[1].all() and not truth_vis[0, 2]:
                partial_frames += vis[:, :2].all() and not vis[:, 2].any()
            obs, _, _, _, info = env.step(hold)
    finally:
        env.close()
    assert partial_frames >= 5
    assert front.stats()["ltat_partial_frames"] >= 5


def test_stereo_check_rejects_wrong_size_and_rows(calm_rollout):
    rollout, calibration = calm_rollout
    truth = rollout[0][1]["true_pixels"]
    rig, sides = calibration.stereo, calibration.marker_sides
    assert match_stereo(truth[0], truth[1], rig, sides)
    # The analogs' marker is 0.8x: the same pixels claimed for a 1.25x larger marker fail.
    assert not match_stereo(truth[0], truth[1], rig, tuple(1.25 * s for s in sides))
    shifted = truth[1] + (0.0, 6.0)
    assert not match_stereo(truth[0], shifted, rig, sides)


def test_first_detection_picks_the_auv_not_an_analog(wash_rollout):
    rollout, calibration = wash_rollout
    extractor = MarkerCornerExtractor()
    for obs, info in rollout[:10]:
        if info["distractors_in_view"] and info["true_visible"].all():
            candidates = extractor.candidates(obs["left"])
            pair = find_marker_pair(extractor, obs["left"], obs["right"], calibration.stereo,
                                    calibration.marker_sides)
            assert pair is not None
            assert np.linalg.norm(pair - info["true_pixels"], axis=2).max() <= CORNER_TOLERANCE
            break
    else:
        pytest.fail("no frame with an analog in view and the marker visible")
    assert len(candidates) >= 2, "the analog's triangle is a colour candidate too"


# ---------------------------------------------------------------------- detector
def test_online_detector_learns_the_marker(calm_rollout, shipped):
    rollout, _ = calm_rollout
    net, _ = shipped
    detector = OnlineDetector(net, np.random.default_rng(0))
    added = 0
    for obs, info in rollout[:10]:
        box = marker_box(info["true_pixels"][0])
        added += detector.add_samples(detector.features([Pyramid(obs["left"])], box)[0], box)
    assert added >= detector.params.min_positives
    assert detector.ready and detector.fits >= 1
    obs, info = rollout[-1]
    box = marker_box(info["true_pixels"][0])
    feats = detector.features([Pyramid(obs["left"])], box)[0]
    found = detector.detect(feats)
    assert found, "no window above the detector's threshold"
    centre, _ = found[0]
    true_centre = 0.5 * (box[:2] + box[2:])
    assert np.linalg.norm(centre - true_centre) <= feats.cell


# ---------------------------------------------------------------------- re-acquisition
def test_ltat_reacquires_after_wash_over(wash_rollout):
    rollout, calibration = wash_rollout
    front = LTATFrontEnd(calibration)
    front.reset(WASH_SEED)
    occluded = [bool(info["marker_occluded"]) for _, info in rollout]
    first_hidden = occluded.index(True)
    last_hidden = len(occluded) - 1 - occluded[::-1].index(True)
    assert 5 < first_hidden < last_hidden < len(rollout) - REACQUIRE_FRAMES
    lost_before = None
    ious, corner_frames = [], []
    for k, (obs, info) in enumerate(rollout):
        features = front(obs, {})
        if k == first_hidden:
            lost_before = front.stats()["ltat_lost_views"]
        if last_hidden < k <= last_hidden + REACQUIRE_FRAMES:
            truth_box = marker_box(info["true_pixels"][0], _image_size(calibration))
            ious.append(box_iou(front.last_output.boxes[0], truth_box))
            if features["visible"].all():
                err = np.linalg.norm(features["pixels"] - info["true_pixels"], axis=2)
                corner_frames.append(err.max())
    stats = front.stats()
    assert stats["ltat_initialised_at"] == 0
    # The wash-over made the tracker lose the marker (so re-acquisition was needed) ...
    assert stats["ltat_lost_views"] > lost_before
    # ... and LTAT has it again within REACQUIRE_FRAMES of it reappearing.
    assert max(ious) > REACQUIRE_IOU, ious
    assert ious[-1] > REACQUIRE_IOU, ious
    assert corner_frames and max(corner_frames) <= CORNER_TOLERANCE


def test_detector_reacquires_when_the_camera_moved_during_wash_over(shipped):
    """The arm moves 0.39 m while the crest hides the marker: it reappears ~170 px
    away, outside the held tracker's reach; the online detector must find it."""
    rollout, calibration = _rollout(WASH_SEED, "severe", 46, offset=(0.25, 0.3, 0.0),
                                    offset_from=20)
    front = LTATFrontEnd(calibration)
    front.reset(WASH_SEED)
    alone = SiameseTracker(shipped[0])
    visible_again = None
    for k, (obs, info) in enumerate(rollout):
        features = front(obs, {})
        pyramids = [Pyramid(obs["left"]), Pyramid(obs["right"])]
        if k == 0:
            alone.init(pyramids, [marker_box(info["true_pixels"][v]) for v in range(2)])
        else:
            alone.track(pyramids)
        if k > 20 and visible_again is None and info["true_visible"].all():
            visible_again = k
    assert visible_again is not None and visible_again < len(rollout) - REACQUIRE_FRAMES
    stats = front.stats()
    assert stats["ltat_redetections"] >= 1
    truth_box = marker_box(rollout[-1][1]["true_pixels"][0], _image_size(calibration))
    assert box_iou(front.last_output.boxes[0], truth_box) > REACQUIRE_IOU
    assert features["visible"].all()
    err = np.linalg.norm(features["pixels"] - rollout[-1][1]["true_pixels"], axis=2)
    assert err.max() <= CORNER_TOLERANCE
    # The tracker alone, without the detector, does not get it back.
    assert box_iou(alone.box(0), truth_box) < REACQUIRE_IOU


# ---------------------------------------------------------------------- agent
def test_ltat_ckf_pd_is_registered_for_stereo():
    spec = agent_spec("ltat-ckf-pd")
    assert spec.obs_mode == "stereo"
    assert spec.applies_to("auv_envs/LARSCapture-v0")


def test_ltat_ckf_pd_builds_on_the_ckf_pd_agent():
    from baselines.lars.agents import CKFPDAgent

    env = TaskEnv(LARSCaptureTask, obs_mode="stereo")
    try:
        assert "ckf-pd" in agent_names()  # a builtin: the inner agent must be there
        agent = make_agent("ltat-ckf-pd", env)
        assert isinstance(agent.front_end, LTATFrontEnd)
        assert isinstance(agent.inner, CKFPDAgent)
    finally:
        env.close()


def test_front_end_rejects_wrong_images(calm_rollout):
    _, calibration = calm_rollout
    front = LTATFrontEnd(calibration)
    obs = dict(calm_rollout[0][0][0])
    obs["left"] = obs["left"][:100]
    with pytest.raises(ValueError, match="left image"):
        front(obs, {})
    with pytest.raises(ValueError, match="'stereo' observation"):
        front({"pixels": np.zeros((2, 3, 2))}, {})
    with pytest.raises(ValueError, match="obs_mode='stereo'"):
        from baselines.lars.agents import make_front_end

        make_front_end(TaskEnv(LARSCaptureTask, obs_mode="features"))
