"""LARS capture env: contract, episode end (capture, collision, workspace), bad input."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from auv_envs.core.env import TaskEnv
from auv_envs.datasets.lars import tracking_action
from auv_envs.tasks.lars.env import LARSCaptureTask


def _capture_action(env, info, height):
    """Privileged: put the capture tip ``height`` m above the capture point."""
    cal = env.calibration
    target = info["end_position"] + info["capture_offset"] + (0.0, 0.0, height)
    q = cal.arm.inverse_kinematics(target)
    lo, hi = cal.joint_limits[:, 0], cal.joint_limits[:, 1]
    return ((2 * q - lo - hi) / (hi - lo)).astype(np.float32)


def test_contract_attributes_and_info_keys():
    env = TaskEnv(LARSCaptureTask, obs_mode="features")
    assert env.obs_modes == ("state", "features", "stereo")
    assert "is_success" in env.metric_keys
    _, info = env.reset(seed=0)
    assert set(env.metric_keys) <= set(info)
    _, reward, *_, info = env.step(np.zeros(3, dtype=np.float32))
    assert set(env.metric_keys) <= set(info)
    terms = [info[f"reward_{t}"] for t in env.reward_terms]
    assert reward == sum(terms)
    assert np.linalg.norm(info["relative_position"]) < 1.0 + 1e-9 or info["time"] > 0


@pytest.mark.parametrize("seed", range(5))
def test_start_within_one_metre_and_marker_in_view(seed):
    env = TaskEnv(LARSCaptureTask, obs_mode="features")
    obs, info = env.reset(seed=seed)
    assert np.linalg.norm(info["relative_position"]) <= 1.0
    assert obs["visible"].all()
    assert 0.7 < info["end_position"][2] - info["true_corners"][:, 2].max() < 1.0


def test_features_are_noisy_masked_truth():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", pixel_noise_std=1.0)
    obs, info = env.reset(seed=3)
    err = obs["pixels"] - info["true_pixels"]
    assert 0.1 < np.abs(err).mean() < 3.0
    quiet = TaskEnv(LARSCaptureTask, obs_mode="features", pixel_noise_std=0.0)
    obs, info = quiet.reset(seed=3)
    np.testing.assert_allclose(obs["pixels"], info["true_pixels"], atol=1e-4)


def test_privileged_capture_succeeds():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", control="position")
    _, info = env.reset(seed=1)
    for k in range(750):
        # Track 0.3 m above, then descend to the capture point.
        height = max(0.0, 0.3 - 0.004 * max(0, k - 50))
        _, reward, terminated, truncated, info = env.step(_capture_action(env, info, height))
        if terminated or truncated:
            break
    assert terminated and info["is_success"]
    assert info["reward_success"] == 10.0
    metrics = info["episode_metrics"]
    assert metrics["success"] and metrics["final_capture_error"] <= 0.05


def test_ramming_the_hull_is_a_hard_collision():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", control="position")
    _, info = env.reset(seed=2)
    for _ in range(200):
        # Aim 0.4 m forward of the capture point, 0.15 m into the hull.
        target = info["end_position"] + info["capture_offset"] + (0.4, 0.0, -0.15)
        q = env.calibration.arm.inverse_kinematics(target)
        lo, hi = env.calibration.joint_limits.T
        _, _, terminated, truncated, info = env.step((2 * q - lo - hi) / (hi - lo))
        if terminated or truncated:
            break
    assert terminated and info["collision"] and not info["is_success"]
    assert info["episode_metrics"]["failure_reason"] == "collision"
    assert info["reward_failure"] == -10.0


def test_falling_arm_leaves_the_workspace():
    env = TaskEnv(LARSCaptureTask, obs_mode="state")
    env.reset(seed=0)
    for _ in range(200):
        _, _, terminated, truncated, info = env.step(np.array([0.0, -1.0, -1.0]))
        if terminated or truncated:
            break
    assert terminated and info["violation_workspace"]
    assert info["episode_metrics"]["failure_reason"] == "workspace"
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3))


def test_time_limit_truncates_with_metrics():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", control="position", time_limit=1.0)
    _, info = env.reset(seed=0)
    for _ in range(30):
        _, _, terminated, truncated, info = env.step(tracking_action(env, info))
        if terminated or truncated:
            break
    assert truncated and not terminated
    assert info["episode_metrics"]["failure_reason"] == "time_limit"
    assert info["episode_metrics"]["steps"] == 25


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        ({"obs_mode": "image"}, ValueError, "'state', 'features', 'stereo'"),
        ({"sea_state": "storm"}, ValueError, "'calm', 'severe'"),
        ({"control": "velocity"}, ValueError, "'torque', 'position'"),
        ({"image_size": (4, 4)}, ValueError, "image_size"),
        ({"baseline": -0.1}, ValueError, "baseline"),
        ({"focal_length": 0.0}, ValueError, "focal_length"),
        ({"pixel_noise_std": float("nan")}, ValueError, "pixel_noise_std"),
        ({"time_limit": 0.0}, ValueError, "time_limit"),
        ({"colour": "red"}, TypeError, "sea_state"),
    ],
)
def test_bad_arguments(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        TaskEnv(LARSCaptureTask, **kwargs)


def test_bad_actions():
    env = TaskEnv(LARSCaptureTask)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(4))
    other = TaskEnv(LARSCaptureTask)
    other.reset(seed=0)
    o1, *_ = env.step(np.array([5.0, -3.0, 0.5]))
    o2, *_ = other.step(np.array([1.0, -1.0, 0.5]))
    np.testing.assert_array_equal(o1, o2)


def test_focal_length_and_baseline_reach_the_calibration():
    env = TaskEnv(LARSCaptureTask, image_size=(1280, 960), focal_length=1000.0, baseline=0.2)
    cal = env.calibration
    assert cal.stereo.left.fx == pytest.approx(1000.0)
    assert (cal.stereo.left.width, cal.stereo.left.height) == (1280, 960)
    assert cal.stereo.baseline == 0.2
    np.testing.assert_allclose(cal.right_in_end[:3, 3] - cal.left_in_end[:3, 3], [0.2, 0, 0])


def test_calibration_is_read_only():
    cal = TaskEnv(LARSCaptureTask).calibration
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.control_period = 1.0
    for array in (cal.left_in_end, cal.right_in_end, cal.torque_limits, cal.joint_limits,
                  cal.marker.corners, cal.workspace, cal.capture_point_body):
        with pytest.raises(ValueError):
            array[0] = 1.0


@pytest.mark.parametrize("sea_state", ["calm", "severe"])
def test_pickle_mid_episode_continues_identically(sea_state):
    env = TaskEnv(LARSCaptureTask, obs_mode="features", sea_state=sea_state, control="position")
    _, info = env.reset(seed=6)
    for _ in range(40):
        _, _, _, _, info = env.step(tracking_action(env, info))
    clone = pickle.loads(pickle.dumps(env))
    info2 = dict(info)
    for _ in range(60):
        o1, r1, t1, u1, info = env.step(tracking_action(env, info))
        o2, r2, t2, u2, info2 = clone.step(tracking_action(clone, info2))
        for key in o1:
            np.testing.assert_array_equal(o1[key], o2[key])
        assert (r1, t1, u1) == (r2, t2, u2)


def test_state_and_stereo_observations():
    env = TaskEnv(LARSCaptureTask, obs_mode="state")
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(obs[12:15], info["relative_position"], rtol=1e-6)
    stereo = TaskEnv(LARSCaptureTask,
                     obs_mode="stereo", image_size=(64, 48), render_mode="rgb_array",
                            render_camera="stereo", render_size=(64, 48))
    try:
        obs, _ = stereo.reset(seed=0)
        assert set(obs) == {"left", "right", "joint_position", "joint_velocity"}
        assert obs["left"].shape == (48, 64, 3) and obs["left"].std() > 5
        assert not np.array_equal(obs["left"], obs["right"])  # parallax
        frame = stereo.render()
        np.testing.assert_array_equal(frame[:, :64], obs["left"])
    finally:
        stereo.close()
