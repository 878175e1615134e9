"""[LTAT]'s marker geometry and the ``ckf-pd`` agent on LARSCapture-v0."""

import math

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from auv_envs.tasks.lars.scene import auv_rotation
from baselines.evaluation import run_episode
from baselines.lars.agents import CKFPDAgent
from baselines.lars.perception.marker import MarkerLocaliser, marker_attitude
from baselines.registry import agent_names, agent_spec, make_agent

ENV_ID = "auv_envs/LARSCapture-v0"
SET_ANGLES = [(15, 0), (20, 0), (30, 0), (0, -30), (0, 0), (0, 30), (3, -12)]


def make(**kwargs):
    kwargs.setdefault("obs_mode", "features")
    return gym.make(ENV_ID, **kwargs)


def pinned(pitch_deg, yaw_deg):
    return {"motion": {"pitch": math.radians(pitch_deg), "yaw": math.radians(yaw_deg)}}


@pytest.fixture(scope="module")
def noise_free():
    env = make(pixel_noise_std=0.0)
    yield env
    env.close()


def test_registered():
    assert "ckf-pd" in agent_names()
    spec = agent_spec("ckf-pd")
    assert spec.obs_mode == "features" and spec.applies_to(ENV_ID)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_triangulation_exact_on_noise_free_pixels(noise_free, seed):
    obs, info = noise_free.reset(seed=seed)
    loc = MarkerLocaliser(noise_free.unwrapped.calibration)
    fix = loc.locate(obs["pixels"], obs["visible"], obs["joint_position"])
    assert fix.valid.all()
    # float32 joint angles and pixels in the observation: exact to ~1e-5 m
    np.testing.assert_allclose(fix.corners, info["true_corners"], atol=2e-5)
    exact = loc.locate(info["true_pixels"], info["true_visible"],
                       noise_free.unwrapped.calibration.arm.inverse_kinematics(
                           info["end_position"]))
    np.testing.assert_allclose(exact.corners, info["true_corners"], atol=1e-9)


@pytest.mark.parametrize("pitch,yaw", SET_ANGLES)
def test_pitch_yaw_from_noise_free_corners_equal_truth(noise_free, pitch, yaw):
    _, info = noise_free.reset(seed=5, options=pinned(pitch, yaw))
    depth = noise_free.unwrapped.calibration.marker.depth_offset
    est = marker_attitude(info["true_corners"], depth)
    np.testing.assert_allclose(np.degrees(est), [pitch, yaw], atol=1e-9)
    # eqs. 4-6 as printed put D along the world vertical: right when level only
    literal = np.degrees(marker_attitude(info["true_corners"], depth, refine=False))
    assert literal[1] == pytest.approx(yaw, abs=1e-9)
    assert abs(literal[0] - pitch) < 1.0
    if pitch == 0:
        assert literal[0] == pytest.approx(0.0, abs=1e-9)


def test_auv_position_from_all_or_some_corners(noise_free):
    _, info = noise_free.reset(seed=3, options=pinned(2, 20))
    cal = noise_free.unwrapped.calibration
    loc = MarkerLocaliser(cal)
    q = cal.arm.inverse_kinematics(info["end_position"])
    fix = loc.locate(info["true_pixels"], info["true_visible"], q)
    rot = auv_rotation(info["true_pitch"], info["true_yaw"], np)
    cg, cov = loc.auv_position(fix, rot)
    np.testing.assert_allclose(cg, info["true_position"], atol=1e-9)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    visible = info["true_visible"].copy()
    visible[:, [0, 2]] = False  # only A2 seen
    partial = loc.locate(info["true_pixels"], visible, q)
    assert partial.count == 1 and partial.pitch is None
    cg1, cov1 = loc.auv_position(partial, rot)
    np.testing.assert_allclose(cg1, info["true_position"], atol=1e-9)
    assert np.trace(cov1) > np.trace(cov)  # one corner is worth less than three
    np.testing.assert_allclose(loc.capture_point(cg, rot),
                               info["true_position"] + info["capture_offset"]
                               + info["end_position"] - info["true_position"]
                               + cal.capture_tip_in_end, atol=1e-9)


def run(agent, env, seed, check=None, options=None):
    obs, info = env.reset(seed=seed, options=options)
    agent.reset(seed)
    actions, done = [], False
    while not done:
        action = agent.act(obs, info)
        if check is not None:
            check(agent, info)
        actions.append(action)
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    return info, np.array(actions)


def test_calm_episode_captures_the_auv():
    env = make(time_limit=15.0)
    errors = []

    def check(agent, info):
        est = agent.position_estimate()
        errors.append(np.abs(est - info["true_position"]))

    try:
        agent = make_agent("ckf-pd", env)
        info, _ = run(agent, env, seed=11, check=check)
    finally:
        env.close()
    metrics = info["episode_metrics"]
    assert metrics["success"], metrics
    assert metrics["final_capture_error"] <= 0.05
    assert agent.stats()["strikes"] == 1
    errors = np.array(errors[25:])  # after the first second
    assert errors.max() < 0.03 and errors.mean() < 0.01, errors.max(axis=0)


def test_episode_through_run_episode_is_deterministic():
    env = make(time_limit=3.0)
    try:
        agent = make_agent("ckf-pd", env)
        a = run_episode(env, agent, 4, ENV_ID, "ckf-pd")
        b = run_episode(env, agent, 4, ENV_ID, "ckf-pd")
    finally:
        env.close()
    assert a.metrics == b.metrics and a.episode_return == b.episode_return


def test_severe_sea_bridges_the_hidden_marker():
    env = make(sea_state="severe", time_limit=8.0)
    hidden_errors = []

    def check(agent, info):
        if info["marker_visible"] == 0 and agent.position_estimate() is not None:
            hidden_errors.append(np.linalg.norm(agent.position_estimate()
                                                - info["true_position"]))

    try:
        agent = CKFPDAgent(env.unwrapped, strike=False)
        run(agent, env, seed=0, check=check)
    finally:
        env.close()
    stats = agent.stats()
    assert stats["bridged"] > 0 and len(hidden_errors) > 0
    assert max(hidden_errors) < 0.03


def test_outliers_from_a_front_end_are_gated():
    """A front end that mismatches corners: the gate keeps them out of the estimate."""
    env = make(time_limit=4.0)
    rng = np.random.default_rng(0)
    errors = []
    try:
        agent = CKFPDAgent(env.unwrapped, strike=False)
        obs, info = env.reset(seed=2)
        agent.reset(2)
        for k in range(100):
            if k > 40 and k % 7 == 0:
                obs = dict(obs, pixels=obs["pixels"].copy())
                obs["pixels"][0, :, 0] += rng.uniform(20, 30)  # a wrong left box: depth off
            obs, _, _, _, info_next = env.step(agent.act(obs, info))
            errors.append(np.linalg.norm(agent.position_estimate() - info["true_position"]))
            info = info_next
    finally:
        env.close()
    assert agent.stats()["gated"] >= 7
    assert max(errors[40:]) < 0.03


def test_assumed_pixel_noise_rises_to_the_measured_noise():
    """Features noisier than the agent assumes (3 px vs 1 px): the rows reveal it."""
    env = make(pixel_noise_std=3.0, time_limit=3.0)
    errors = []

    def check(agent, info):
        errors.append(np.linalg.norm(agent.position_estimate() - info["true_position"]))

    try:
        agent = CKFPDAgent(env.unwrapped, pixel_std=1.0, strike=False)
        run(agent, env, seed=6, check=check)
        fixed = CKFPDAgent(env.unwrapped, pixel_std=1.0, strike=False, adapt_pixel_noise=False)
        run(fixed, env, seed=6)
    finally:
        env.close()
    assert agent.localiser.nominal_pixel_std == 1.0
    assert 2.5 < agent.stats()["pixel_std"] < 3.5
    assert agent.stats()["gated"] <= 2
    assert max(errors[25:]) < 0.04
    # without it the gate, tuned for 1 px, throws away a large share of the fixes
    assert fixed.stats()["pixel_std"] == 1.0 and fixed.stats()["gated"] >= 10


def test_mismatched_corner_is_dropped():
    env = make()
    try:
        agent = CKFPDAgent(env.unwrapped)
        obs, info = env.reset(seed=1)
        agent.reset(1)
        obs, _, _, _, info = env.step(agent.act(obs, info))
        obs["pixels"][1, 2, 0] = obs["pixels"][0, 2, 0] + 5.0  # right of left: negative disparity
        agent.act(obs, info)
    finally:
        env.close()
    stats = agent.stats()
    assert stats["mismatched_corners"] == 1
    assert stats["partial_fixes"] == 1 and stats["fixes"] == 1  # the other two corners used


def test_bad_input_raises():
    env = make(control="position")
    with pytest.raises(ValueError, match="control='torque'"):
        make_agent("ckf-pd", env)
    env.close()
    env = make()
    try:
        agent = make_agent("ckf-pd", env)
        obs, info = env.reset(seed=0)
        agent.reset(0)
        with pytest.raises(ValueError, match="features"):
            agent.act({"pixels": obs["pixels"]}, info)
        with pytest.raises(ValueError, match="finite"):
            agent.act(dict(obs, joint_velocity=np.full(3, np.nan, np.float32)), info)
        bad = dict(obs, pixels=obs["pixels"].copy())
        bad["pixels"][0, 0] = np.nan
        with pytest.raises(ValueError, match="finite"):
            agent.act(bad, info)
        with pytest.raises(ValueError, match="sample_period"):
            CKFPDAgent(env.unwrapped, sample_period=0.01)
    finally:
        env.close()
