"""LARS arm model: kinematics round trips, eq. 29 dynamics, gravity hold, position loop."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from auv_envs.core.env import TaskEnv
from auv_envs.core.ops import FLOATS
from auv_envs.tasks.lars.env import LARSCaptureTask


@pytest.fixture(scope="module")
def env():
    e = TaskEnv(LARSCaptureTask, obs_mode="features")
    yield e
    e.close()


def _random_q(rng, arm, n):
    lo, hi = arm.joint_limits[:, 0], arm.joint_limits[:, 1]
    qs = rng.uniform(lo, hi, size=(n, 3))
    return qs[qs[:, 2] < -0.05]  # away from the straight-arm singularity


def test_forward_kinematics_matches_mujoco(env):
    arm = env.calibration.arm
    model = env.physics.model
    data = mujoco.MjData(model)
    for q in _random_q(np.random.default_rng(0), arm, 20):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(arm.forward_kinematics(q), data.site("tip").xpos, atol=1e-12)


def test_inverse_kinematics_round_trips(env):
    arm = env.calibration.arm
    for q in _random_q(np.random.default_rng(1), arm, 50):
        p = arm.forward_kinematics(q)
        q_ik = arm.inverse_kinematics(p)
        np.testing.assert_allclose(q_ik, q, atol=1e-9)
        np.testing.assert_allclose(arm.forward_kinematics(q_ik), p, atol=1e-12)


def test_inverse_kinematics_out_of_reach_raises(env):
    arm = env.calibration.arm
    with pytest.raises(ValueError, match="reach"):
        arm.inverse_kinematics(arm.shoulder + (0.0, 10.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        arm.inverse_kinematics([np.nan, 1.0, 1.0])


def test_jacobian_matches_finite_differences(env):
    arm = env.calibration.arm
    q = np.array([0.3, 0.2, -1.2])
    eps = 1e-6
    numeric = np.stack(
        [(arm.forward_kinematics(q + eps * e) - arm.forward_kinematics(q - eps * e)) / (2 * eps)
         for e in np.eye(3)], axis=1,
    )
    np.testing.assert_allclose(arm.jacobian(q), numeric, atol=1e-7)
    qd = np.array([0.1, -0.3, 0.4])
    np.testing.assert_allclose(arm.end_state(q, qd, FLOATS)[3:], arm.jacobian(q) @ qd, atol=1e-12)


def test_dynamics_terms_are_nontrivial_and_consistent(env):
    arm = env.calibration.arm
    q, qd = np.array([0.2, 0.3, -1.4]), np.array([0.4, -0.3, 0.6])
    m = arm.mass_matrix(q)
    np.testing.assert_allclose(m, m.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(m) > 0)
    # M depends on q (the elbow couples the links), G and C are not zero.
    assert not np.allclose(m, arm.mass_matrix(q + (0.0, 0.0, 0.8)))
    assert abs(arm.gravity(q)[1]) > 500.0
    assert np.linalg.norm(arm.coriolis(q, qd)) > 1.0
    np.testing.assert_allclose(arm.coriolis(q, np.zeros(3)), 0.0, atol=1e-12)
    # C(q, qd) qd is quadratic in qd.
    np.testing.assert_allclose(arm.coriolis(q, 2 * qd), 4 * arm.coriolis(q, qd), rtol=1e-9)


def test_inverse_dynamics_reproduces_simulated_acceleration(env):
    arm = env.calibration.arm
    model = env.physics.model
    data = mujoco.MjData(model)
    data.qpos[:] = [0.1, 0.2, -1.3]
    data.qvel[:] = [0.3, -0.2, 0.5]
    data.ctrl[:] = [0.2, 0.3, -0.1]
    mujoco.mj_forward(model, data)
    tau = arm.inverse_dynamics(data.qpos, data.qvel, data.qacc)
    np.testing.assert_allclose(tau, data.ctrl * arm.torque_limits, rtol=1e-9, atol=1e-9)


def test_gravity_torque_holds_the_arm_still():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", time_limit=100.0)
    obs, _ = env.reset(seed=4)
    cal = env.calibration
    q0 = env.physics.data.qpos.copy()
    hold = (cal.arm.gravity(q0) / cal.torque_limits).astype(np.float64)
    for _ in range(50):
        obs, *_ = env.unwrapped.step(hold)
    np.testing.assert_allclose(env.physics.data.qpos, q0, atol=1e-9)
    # Without it the arm falls.
    env.reset(seed=4)
    for _ in range(5):
        env.step(np.zeros(3, dtype=np.float32))
    assert np.abs(env.physics.data.qpos - q0).max() > 1e-2


def test_position_control_tracks_a_target():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", control="position")
    _, info = env.reset(seed=1)
    cal = env.calibration
    target = cal.arm.inverse_kinematics(info["end_position"] + (0.3, -0.2, 0.2))
    lo, hi = cal.joint_limits[:, 0], cal.joint_limits[:, 1]
    action = ((2 * target - lo - hi) / (hi - lo)).astype(np.float32)
    for _ in range(75):  # 3 s
        obs, *_ = env.step(action)
    np.testing.assert_allclose(obs["joint_position"], target, atol=2e-3)
    assert np.abs(obs["joint_velocity"]).max() < 0.02
