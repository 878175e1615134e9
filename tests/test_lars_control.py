"""Quintic trajectories, inverse kinematics, computed-torque PD and the capture strategy."""

import math

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from baselines.lars.control.arm import (
    FOLLOW,
    STRIKE,
    TRACK,
    CaptureStrategy,
    ComputedTorquePD,
    QuinticSegment,
    SampledTrajectory,
    joint_reference,
)


@pytest.fixture(scope="module")
def env():
    env = gym.make("auv_envs/LARSCapture-v0", obs_mode="features", time_limit=5.0)
    yield env
    env.close()


def test_quintic_boundary_conditions_at_both_ends():
    rng = np.random.default_rng(0)
    start = rng.normal(size=(3, 3))
    end = rng.normal(size=(3, 3))
    seg = QuinticSegment.between(1.5, 2.7, start, end)
    for t, expected in ((1.5, start), (2.7, end)):
        for got, want in zip(seg.evaluate(t), expected, strict=True):
            np.testing.assert_allclose(got, want, atol=1e-10)


def test_quintic_derivatives_are_consistent():
    seg = QuinticSegment.between(0.0, 2.0, ([0.0], [1.0], [0.5]), ([3.0], [-1.0], [0.0]))
    h = 1e-5
    for t in (0.3, 1.0, 1.7):
        p_lo, v_lo, _ = seg.evaluate(t - h)
        p_hi, v_hi, _ = seg.evaluate(t + h)
        _, v, a = seg.evaluate(t)
        np.testing.assert_allclose((p_hi - p_lo) / (2 * h), v, atol=1e-6)
        np.testing.assert_allclose((v_hi - v_lo) / (2 * h), a, atol=1e-6)
    # clamped outside [t0, t1]
    np.testing.assert_allclose(seg.evaluate(5.0)[0], [3.0])
    np.testing.assert_allclose(seg.evaluate(-1.0)[0], [0.0])


def test_quintic_rest_to_rest_is_the_textbook_profile():
    seg = QuinticSegment.between(0.0, 1.0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    for s in (0.25, 0.5, 0.8):
        assert seg.evaluate(s)[0][0] == pytest.approx(10 * s**3 - 15 * s**4 + 6 * s**5)


def test_quintic_bad_input_raises():
    with pytest.raises(ValueError, match="t1 > t0"):
        QuinticSegment.between(1.0, 1.0, (0, 0, 0), (1, 0, 0))
    with pytest.raises(ValueError, match="finite"):
        QuinticSegment.between(0.0, 1.0, (0, np.nan, 0), (1, 0, 0))


def test_sampled_trajectory_is_continuous_across_replans():
    traj = SampledTrajectory()
    with pytest.raises(RuntimeError):
        traj.reference(0.0)
    zero = np.zeros(3)
    traj.replan(0.0, (zero, zero, zero), 0.4, (np.array([1.0, 0.0, 0.0]), zero, zero))
    before = traj.reference(0.2)
    traj.replan(0.2, (zero, zero, zero), 0.6, (np.array([0.0, 2.0, 1.0]), np.ones(3), zero))
    after = traj.reference(0.2)
    for b, a in zip(before, after, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_inverse_kinematics_round_trip(env):
    arm = env.unwrapped.calibration.arm
    p = np.array([0.3, 1.8, 0.9])
    v = np.array([0.1, -0.05, 0.2])
    a = np.array([0.0, 0.1, -0.3])
    q, qd, qdd = joint_reference(arm, p, v, a)
    np.testing.assert_allclose(arm.forward_kinematics(q), p, atol=1e-12)
    np.testing.assert_allclose(arm.jacobian(q) @ qd, v, atol=1e-12)
    # the joint path of p + v t + a t^2 / 2 has rate qd and acceleration qdd at t = 0
    h = 1e-4
    path = [arm.inverse_kinematics(p + v * t + 0.5 * a * t * t) for t in (-h, 0.0, h)]
    np.testing.assert_allclose((path[2] - path[0]) / (2 * h), qd, atol=1e-6)
    np.testing.assert_allclose((path[2] - 2 * path[1] + path[0]) / h**2, qdd, atol=1e-4)
    with pytest.raises(ValueError, match="reach"):
        joint_reference(arm, np.array([0.0, 9.0, 0.0]), v, a)


def test_computed_torque_equals_inverse_dynamics_of_the_pd_acceleration(env):
    cal = env.unwrapped.calibration
    pd = ComputedTorquePD(cal.arm, cal.torque_limits, *cal.position_gains)
    q, qd = np.array([0.1, 0.2, -1.4]), np.array([0.05, -0.1, 0.2])
    q_ref, qd_ref, qdd_ref = q + 0.01, np.zeros(3), np.array([0.1, 0.0, -0.1])
    accel = qdd_ref + 20.0 * (qd_ref - qd) + 160.0 * (q_ref - q)
    np.testing.assert_allclose(pd.torque(q, qd, q_ref, qd_ref, qdd_ref),
                               cal.arm.inverse_dynamics(q, qd, accel))
    action = pd.action(q, qd, q_ref, qd_ref, qdd_ref)
    assert np.all(np.abs(action) <= 1.0)
    with pytest.raises(ValueError, match="gains"):
        ComputedTorquePD(cal.arm, cal.torque_limits, kp=0.0, kd=cal.position_gains[1])


def test_pd_tracks_a_quintic_move_in_the_simulator(env):
    """The arm end follows a 0.3 m quintic move in MuJoCo through IK + PD (torques)."""
    unwrapped = env.unwrapped
    cal = unwrapped.calibration
    pd = ComputedTorquePD(cal.arm, cal.torque_limits, *cal.position_gains)
    obs, _ = env.reset(seed=0)
    q0 = obs["joint_position"].astype(float)
    p0 = cal.arm.forward_kinematics(q0)
    zero = np.zeros(3)
    p1 = p0 + np.array([0.2, 0.15, -0.15])
    seg = QuinticSegment.between(0.0, 1.5, (p0, zero, zero), (p1, zero, zero))
    dt = cal.control_period
    worst = 0.0
    for k in range(60):
        t = k * dt
        q, qd = obs["joint_position"].astype(float), obs["joint_velocity"].astype(float)
        obs, _, terminated, truncated, info = env.step(
            pd.action(q, qd, *joint_reference(cal.arm, *seg.evaluate(t))))
        assert not (terminated or truncated)
        worst = max(worst, float(np.linalg.norm(info["end_position"] - seg.evaluate(t + dt)[0])))
    assert np.linalg.norm(info["end_position"] - p1) < 1e-3
    assert worst < 5e-3


def test_capture_strategy_phases():
    s = CaptureStrategy(strike_duration=1.0, follow_timeout=0.5)
    assert s.update(0.0, 0.1, ready=False) == TRACK
    assert s.update(0.1, -0.1, ready=False) == TRACK  # crest while not ready: no strike
    assert s.update(0.2, 0.1, ready=True) == TRACK  # rising
    assert s.update(0.3, -0.01, ready=True) == STRIKE  # starts to sink
    assert s.strike_end == pytest.approx(1.3) and s.strikes == 1
    assert s.update(1.2, 0.1, ready=True) == STRIKE
    assert s.update(1.3, 0.1, ready=True) == FOLLOW
    assert s.update(1.81, -0.1, ready=True) == TRACK  # timed out: wait for the next crest
    s.reset()
    assert (s.phase, s.strikes, math.isnan(s.strike_end)) == (TRACK, 0, True)
    with pytest.raises(ValueError, match="hover_height"):
        CaptureStrategy(hover_height=-1.0)
