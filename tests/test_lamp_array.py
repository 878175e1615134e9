"""[LAMP]'s lamp-array front end on rendered docking frames, its parts, and bad input."""

from __future__ import annotations

import functools
import math

import cv2
import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from auv_envs.core.camera import CameraIntrinsics, points_in_camera, project
from auv_envs.core.frames import rotation_from_euler
from baselines.docking.estimation.camera_position import CameraPositionFilter
from baselines.docking.perception.front_end import LampArrayFrontEnd
from baselines.docking.perception.identity import identify_l_shape, ring_labelings
from baselines.docking.perception.lamp_tracking import (
    DETECTED,
    PREDICTED,
    BlobEKF,
    LampTrackerParams,
)
from baselines.docking.perception.segmentation import SegmentationParams, segment_lamps
from baselines.frontend import FrontEndAgent
from baselines.kalman import kalman_gain
from baselines.registry import agent_spec, make_agent
from tests.conftest import DOCKING_IDS

LAMP_ID, RING_ID = "auv_envs/LampArrayDocking-v2", "auv_envs/DockingStation-v2"
N_FRAMES = 24


def _observation(image: np.ndarray, info: dict) -> dict:
    """The image observation of the noise-free ``mismatch`` scenario, rebuilt from info."""
    return {
        "image": image,
        "velocity": info["true_velocity"][[0, 1, 2, 5]].astype(np.float32),
        "attitude": info["true_euler"].astype(np.float32),
    }


def _lamps_apart(info: dict, intrinsics: CameraIntrinsics, min_gap: float = 25.0,
                 border: float = 15.0) -> bool:
    if not info["true_visible"].all():
        return False
    px = info["true_pixels"]
    gaps = np.linalg.norm(px[:, None] - px[None], axis=-1) + 1e9 * np.eye(len(px))
    size = np.array([intrinsics.width, intrinsics.height])
    inside = ((px > border) & (px < size - border)).all()
    return bool(gaps.min() >= min_gap and inside)


@functools.cache
def _render_sequence(env_id: str, seed: int = 100_000) -> tuple[list, object]:
    """``pd-state`` docks a state env (no rendering, fast); from the first step with every
    lamp visible and apart, ``N_FRAMES`` frames are rendered at 640x480."""
    env = gym.make(env_id, obs_mode="state", render_mode="rgb_array", render_camera="onboard")
    try:
        agent = make_agent("pd-state", env)
        obs, info = env.reset(seed=seed)
        frames = []
        while len(frames) < N_FRAMES:
            if frames or _lamps_apart(info, env.unwrapped.calibration.intrinsics):
                frames.append((_observation(env.render(), info), info["true_pixels"].copy(),
                               info["true_visible"].copy()))
            obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
            if terminated or truncated:
                break
        return frames, env.unwrapped.calibration
    finally:
        env.close()


@pytest.fixture(scope="module", params=[LAMP_ID, RING_ID], ids=["lamp-array", "six-lights"])
def rendered(request):
    frames, calibration = _render_sequence(request.param)
    assert len(frames) == N_FRAMES, "the reference controller docked before the frames were taken"
    return request.param, frames, calibration


def _paint_out(image: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Hide the lamps at ``pixels`` (and only them) under discs of the water's colour."""
    blobs = segment_lamps(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
    out = image.copy()
    water = tuple(int(c) for c in np.median(image.reshape(-1, 3), axis=0))
    for uv in pixels:
        j = np.argmin(np.linalg.norm(blobs.centres - uv, axis=1))
        cv2.circle(out, (round(uv[0]), round(uv[1])), math.ceil(blobs.radii[j]) + 2, water, -1)
    return out


# --------------------------------------------------------------------------- on renders


def test_segmentation_finds_every_lamp_within_1px(rendered):
    _, frames, _ = rendered
    for obs, true_px, _ in frames[:: N_FRAMES // 4]:
        blobs = segment_lamps(cv2.cvtColor(obs["image"], cv2.COLOR_RGB2GRAY))
        assert len(blobs) == len(true_px)
        gaps = np.linalg.norm(true_px[:, None] - blobs.centres[None], axis=-1).min(axis=1)
        assert gaps.max() <= 1.0, gaps


def test_front_end_labels_every_lamp_at_initialisation(rendered):
    _, frames, cal = rendered
    front_end = LampArrayFrontEnd(cal)
    obs, true_px, _ = frames[0]
    out = front_end(obs, {})
    assert front_end.initialised
    assert out["visible"].dtype == np.int8 and out["pixels"].dtype == np.float32
    np.testing.assert_array_equal(out["visible"], 1)
    errors = np.linalg.norm(out["pixels"] - true_px, axis=1)
    assert errors.max() <= 1.0, errors  # by label: a wrong identity would be tens of px off
    np.testing.assert_array_equal(front_end.tracks.status, DETECTED)


def test_tracks_follow_the_lamps_and_match_the_features_space(rendered):
    env_id, frames, cal = rendered
    front_end = LampArrayFrontEnd(cal)
    features_space = gym.make(env_id, obs_mode="features").observation_space
    for obs, true_px, true_vis in frames:
        out = front_end(obs, {})
        assert features_space.contains(out)
        np.testing.assert_array_equal(out["visible"], true_vis)
        errors = np.linalg.norm(out["pixels"] - true_px, axis=1)
        assert errors.max() <= 1.0, errors
        np.testing.assert_array_equal(out["velocity"], obs["velocity"])
        np.testing.assert_array_equal(out["attitude"], obs["attitude"])
    assert front_end.stats()["lamp_initialisations"] == 1


@pytest.mark.parametrize("hidden", [(0, 2), "all"], ids=["two-lamps", "every-lamp"])
def test_tracks_survive_an_occlusion_and_reassign_correctly(rendered, hidden):
    _, frames, cal = rendered
    front_end = LampArrayFrontEnd(cal)
    hidden = np.arange(len(cal.light_labels)) if hidden == "all" else np.array(hidden)
    occluded = range(4, 12)  # 0.8 s
    for k, (obs, true_px, _) in enumerate(frames):
        if k in occluded:
            obs = dict(obs, image=_paint_out(obs["image"], true_px[hidden]))
        out = front_end(obs, {})
        errors = np.linalg.norm(front_end.tracks.pixels - true_px, axis=1)
        if k in occluded:
            np.testing.assert_array_equal(out["visible"], ~np.isin(np.arange(len(true_px)), hidden))
            assert (front_end.tracks.status[hidden] == PREDICTED).all()
            assert errors[hidden].max() <= 3.0, errors  # predicted where the lamps are
        else:
            np.testing.assert_array_equal(out["visible"], 1)
            assert errors.max() <= 1.0, (k, errors)  # each lamp back under its own label
    assert front_end.stats()["lamp_initialisations"] == 1  # never re-initialised


class _PoisonedInfo(dict):
    """An empty info dict that fails the test on any read (item, membership, iteration,
    length or truth value, views, copies)."""

    def _read(self, *args, **kwargs):
        raise AssertionError("the front end read info")

    __getitem__ = __contains__ = __iter__ = __len__ = __reversed__ = __or__ = _read
    get = keys = items = values = copy = pop = setdefault = _read


def test_front_end_never_reads_info(rendered):
    # The same frames through three front ends: with an empty info, with the true lamp
    # pixels and visibility in info, and with an info that fails on any read. The
    # features are the same bit for bit: nothing in info reaches them.
    _, frames, cal = rendered
    frames = frames[:4]
    infos = {
        "empty": [{} for _ in frames],
        "truth": [{"true_pixels": px.copy(), "true_visible": vis.copy()}
                  for _, px, vis in frames],
        "poisoned": [_PoisonedInfo() for _ in frames],
    }
    outputs = {}
    for kind, kind_infos in infos.items():
        front_end = LampArrayFrontEnd(cal)
        outputs[kind] = [front_end(obs, info)
                         for (obs, _, _), info in zip(frames, kind_infos, strict=True)]
    for kind in ("truth", "poisoned"):
        for step, (a, b) in enumerate(zip(outputs["empty"], outputs[kind], strict=True)):
            assert a.keys() == b.keys()
            for key in a:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"{kind} {step} {key}")


def test_reset_starts_over_and_reruns_identically(rendered):
    _, frames, cal = rendered
    front_end = LampArrayFrontEnd(cal)
    first = [front_end(obs, {})["pixels"] for obs, _, _ in frames[:6]]
    front_end.reset(1)
    assert not front_end.initialised
    assert np.isnan(front_end.tracks.pixels).all()
    again = [front_end(obs, {})["pixels"] for obs, _, _ in frames[:6]]
    np.testing.assert_array_equal(first, again)


def test_no_lamps_means_no_initialisation(rendered):
    _, frames, cal = rendered
    front_end = LampArrayFrontEnd(cal)
    obs = frames[0][0]
    out = front_end(dict(obs, image=np.zeros_like(obs["image"])), {})
    assert not front_end.initialised
    np.testing.assert_array_equal(out["visible"], 0)
    np.testing.assert_array_equal(out["pixels"], 0.0)


# --------------------------------------------------------------------------- identity rules

L_LAYOUT = np.array([[1.2, 0, -0.6], [1.8, 0, -0.6], [2.4, 0, -0.6], [2.4, 0.5, -0.6]])


def _view(points: np.ndarray, cam_pos, yaw: float, pitch: float, roll: float = 0.0):
    """Project world points with a camera looking along its body x (OpenCV axes)."""
    k = CameraIntrinsics.from_fovy(640, 480, 45.0)
    body_to_cv = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    rot = rotation_from_euler(roll, pitch, yaw, np) @ body_to_cv
    return project(k, points_in_camera(points, np.asarray(cam_pos, float), rot))[0]


@pytest.mark.parametrize("seed", range(5))
def test_l_shape_rule_labels_perspective_views_in_any_order(seed):
    rng = np.random.default_rng(seed)
    for _ in range(20):
        cam = [rng.uniform(-6, -1.5), rng.uniform(-1.5, 1.5), rng.uniform(0.0, 1.5)]
        target = L_LAYOUT.mean(axis=0) - cam
        yaw = math.atan2(target[1], target[0]) + rng.uniform(-0.1, 0.1)
        pitch = math.atan2(-target[2], math.hypot(target[0], target[1]))
        pixels = _view(L_LAYOUT, cam, yaw, pitch, rng.uniform(-0.1, 0.1))
        order = rng.permutation(4)
        labels = identify_l_shape(pixels[order], L_LAYOUT)
        if labels is not None:  # None is allowed (ambiguous), a wrong labelling is not
            np.testing.assert_array_equal(order[labels], np.arange(4))


def test_l_shape_rule_labels_a_typical_view_and_refuses_a_square():
    pixels = _view(L_LAYOUT, [-3.0, 0.3, 1.2], 0.0, math.radians(25))
    np.testing.assert_array_equal(identify_l_shape(pixels, L_LAYOUT), [0, 1, 2, 3])
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    assert identify_l_shape(square, L_LAYOUT) is None
    # Mirrored (D on the other side of A -> C): not this array.
    mirrored = pixels * [-1.0, 1.0]
    np.testing.assert_array_equal(identify_l_shape(mirrored, L_LAYOUT), [2, 1, 0, 3])


HEXAGON = np.radians([90, 150, 210, 270, 330, 30])


@pytest.mark.parametrize("missing", [(), (2,), (0, 3)], ids=["all", "one-hidden", "two-hidden"])
def test_ring_labelings_keep_the_cyclic_order_and_include_the_truth(missing):
    seen_lights = np.array([i for i in range(6) if i not in missing])
    # A hexagon seen turned by 10 deg (perspective, attitude), shrunk, shifted, shuffled.
    angles = HEXAGON[seen_lights] + np.radians(10)
    pixels = np.column_stack([np.cos(angles), -np.sin(angles)]) * 30 + [250, 180]
    order = np.random.default_rng(len(missing)).permutation(len(seen_lights))
    ring_order = np.argsort(np.arctan2(-np.sin(HEXAGON), np.cos(HEXAGON)))
    candidates = ring_labelings(pixels[order], ring_order)
    k = len(seen_lights)
    assert len(candidates) == math.comb(6, k) * k
    truth = seen_lights[order]
    assert sum(np.array_equal(c, truth) for c in candidates) == 1
    assert all(len(set(c.tolist())) == k for c in candidates)


def test_ring_initialises_with_a_light_hidden_and_labels_it():
    frames, cal = _render_sequence(RING_ID)
    front_end = LampArrayFrontEnd(cal)
    for k, (obs, true_px, _) in enumerate(frames[:6]):
        image = _paint_out(obs["image"], true_px[[4]]) if k < 3 else obs["image"]
        out = front_end(dict(obs, image=image), {})
        assert front_end.initialised
        expected = np.ones(6, np.int8)
        if k < 3:
            expected[4] = 0
        np.testing.assert_array_equal(out["visible"], expected)
        errors = np.linalg.norm(front_end.tracks.pixels - true_px, axis=1)
        assert errors.max() <= 1.5, errors  # light 4 predicted by the array, then detected


# --------------------------------------------------------------------------- filters


def test_blob_ekf_jacobian_matches_finite_differences():
    x = np.array([100.0, 50.0, 3.0, -2.0, 6.5, 0.4])
    _, H = BlobEKF.measure(x)
    eps = 1e-6
    numeric = np.column_stack([
        (BlobEKF.measure(x + eps * e)[0] - BlobEKF.measure(x - eps * e)[0]) / (2 * eps)
        for e in np.eye(6)
    ])
    np.testing.assert_allclose(H, numeric, atol=1e-6)


def test_blob_ekf_position_update_is_the_kalman_update():
    P = np.diag([4.0, 9.0, 1.0, 1.0, 1.0, 1.0])
    P[0, 2] = P[2, 0] = 0.5
    ekf = BlobEKF([10.0, 20.0, 1.0, 0.0, 5.0, 0.0], P)
    R = np.diag([1.0, 2.0])
    ekf.update_position(np.array([12.0, 17.0]), R)
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 1] = 1.0
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    x = np.array([10.0, 20.0, 1.0, 0.0, 5.0, 0.0]) + K @ np.array([2.0, -3.0])
    np.testing.assert_allclose(ekf.x, x, atol=1e-12)
    np.testing.assert_allclose(ekf.P, (np.eye(6) - K @ H) @ P, atol=1e-12)


def test_kalman_gain_broadcasts_over_a_bank_of_filters():
    """The shared gain (BlobEKF, CameraPositionFilter, the docking EKF) on a stack of filters
    equals the gain of each filter alone, ``P H^T (H P H^T + R)^-1``."""
    rng = np.random.default_rng(4)
    a = rng.normal(size=(5, 6, 6))
    P = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(6)
    H = rng.normal(size=(5, 2, 6))
    R = np.diag([1.0, 2.0])
    K = kalman_gain(P, H, R)
    assert K.shape == (5, 6, 2)
    for i in range(5):
        expected = P[i] @ H[i].T @ np.linalg.inv(H[i] @ P[i] @ H[i].T + R)
        np.testing.assert_allclose(K[i], expected, rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(kalman_gain(P[i], H[i], R), K[i])


def test_blob_ekf_predict_moves_with_constant_velocity():
    F, Q = BlobEKF.transition(0.1, 100.0, 10.0)
    ekf = BlobEKF([0.0, 0.0, 20.0, -10.0, 4.0, 1.0], np.eye(6))
    ekf.predict(F, Q)
    np.testing.assert_allclose(ekf.x, [2.0, -1.0, 20.0, -10.0, 4.1, 1.0])
    assert np.all(np.diag(ekf.P) > 1.0)


def test_camera_position_filter_recovers_the_camera_from_labelled_lamps():
    k = CameraIntrinsics.from_fovy(640, 480, 45.0)
    cam = np.array([-3.0, 0.4, 1.0])
    body_to_cv = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    rot = rotation_from_euler(0.02, math.radians(20), -0.1, np) @ body_to_cv
    pixels, _ = project(k, points_in_camera(L_LAYOUT, cam, rot))
    pose = CameraPositionFilter(k, L_LAYOUT)
    pose.set_rotation(rot)
    assert pose.fit_residual(np.arange(4), pixels) < 1e-6
    assert pose.fit_residual(np.array([2, 1, 0, 3]), pixels) > 5.0  # A and C swapped
    residual = pose.initialise(np.arange(4), pixels, sigma=0.5)
    assert residual < 1e-6
    np.testing.assert_allclose(pose.t, cam, atol=1e-6)
    # Two lamps suffice once the rotation is known.
    pose.initialise(np.array([0, 3]), pixels[[0, 3]], sigma=0.5)
    np.testing.assert_allclose(pose.t, cam, atol=1e-6)
    # A predicted offset is pulled back by the update.
    pose.predict(np.array([0.2, 0.0, 0.0]), sigma=0.3)
    pose.update([np.array([i]) for i in range(4)], pixels, np.full(4, 0.5))
    assert np.linalg.norm(pose.t - cam) < 0.01


# --------------------------------------------------------------------------- bad input


@pytest.fixture(scope="module")
def lamp_front_end():
    env = gym.make(LAMP_ID, obs_mode="image", image_size=(64, 48))
    try:
        yield LampArrayFrontEnd.from_env(env), env.observation_space.sample()
    finally:
        env.close()


@pytest.mark.parametrize(
    "change, error, match",
    [
        (lambda o: o["image"], TypeError, "dict"),
        (lambda o: {"image": o["image"]}, KeyError, "velocity"),
        (lambda o: dict(o, image=o["image"].astype(np.float32)), ValueError, "uint8"),
        (lambda o: dict(o, image=o["image"][:10]), ValueError, "shape"),
        (lambda o: dict(o, attitude=np.array([0.0, np.nan, 0.0])), ValueError, "finite"),
        (lambda o: dict(o, velocity=np.zeros(3)), ValueError, r"\(4,\)"),
    ],
)
def test_bad_observations_raise(lamp_front_end, change, error, match):
    front_end, obs = lamp_front_end
    with pytest.raises(error, match=match):
        front_end(change(obs), {})


def test_front_end_needs_an_image_env():
    env = gym.make(LAMP_ID, obs_mode="features")
    try:
        with pytest.raises(ValueError, match="image"):
            LampArrayFrontEnd.from_env(env)
    finally:
        env.close()


def test_bad_configuration_raises(lamp_front_end):
    cal = gym.make(RING_ID, obs_mode="state").unwrapped.calibration
    with pytest.raises(ValueError, match="identity"):
        LampArrayFrontEnd(cal, identity="nearest")
    with pytest.raises(ValueError, match="four lamps"):
        LampArrayFrontEnd(cal, identity="l-shape")
    with pytest.raises(ValueError, match="odd"):
        SegmentationParams(block_size=30)
    for bad in (math.nan, math.inf, "25"):
        with pytest.raises(ValueError, match="offset"):
            SegmentationParams(offset=bad)
    with pytest.raises(ValueError, match="gate_px"):
        LampTrackerParams(gate_px=math.inf)
    with pytest.raises(ValueError, match="lost_after"):
        LampTrackerParams(lost_after=0)


def test_bad_segmentation_and_identity_input_raises():
    with pytest.raises(ValueError, match="uint8"):
        segment_lamps(np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="four"):
        identify_l_shape(np.zeros((3, 2)), L_LAYOUT)
    with pytest.raises(ValueError, match="layout"):
        identify_l_shape(np.zeros((4, 2)), L_LAYOUT[:, :2])
    with pytest.raises(ValueError, match="finite"):
        ring_labelings(np.full((6, 2), np.nan), np.arange(6))
    with pytest.raises(ValueError, match="centres"):
        ring_labelings(np.zeros((2, 2)), np.arange(6))


# --------------------------------------------------------------------------- registry


@pytest.mark.parametrize("name", ["ofnmpc-ekf-image", "ofnmpc-mhe-image"])
def test_image_agents_are_registered_behind_the_front_end(name):
    spec = agent_spec(name)
    assert spec.obs_mode == "image"
    assert all(spec.applies_to(env_id) for env_id in DOCKING_IDS)
    env = gym.make(RING_ID, obs_mode="image", image_size=(64, 48))
    try:
        # agent_spec loaded every builtin module, so the inner OFNMPC agent is registered.
        agent = make_agent(name, env)
        assert isinstance(agent, FrontEndAgent)
        assert isinstance(agent.front_end, LampArrayFrontEnd)
    finally:
        env.close()
