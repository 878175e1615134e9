"""What AcousticTracking-v1 changed: the split physics step, the kept detections' noise
drawn last, the detections drawn only when observed or rendered."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from auv_envs.core.acoustics import ORIGIN_TARGET, AcousticConfig, HydrophoneArray
from auv_envs.tasks.acoustic.env import INTEGRATORS, AcousticPhysics, build_tank_model

ENV_ID = "auv_envs/AcousticTracking-v1"


@pytest.mark.parametrize("integrator", sorted(INTEGRATORS))
@pytest.mark.parametrize("substeps", [1, 2])
def test_follow_is_mj_step(integrator, substeps):
    """``follow`` (mj_step1 / mj_step2, the source read from the next step's first half)
    gives the positions and velocities of the plain loop it replaced, to the bit:
    ``mj_step`` with the period's references and current, then the kinematics and the
    site Jacobian; over two calls, as two blocks."""
    rng = np.random.default_rng(7)
    count = 30
    refs = (rng.uniform(40, 60, (2 * count, 4)), rng.uniform(-0.5, 0.5, (2 * count, 4)),
            0.3 * rng.standard_normal((2 * count, 6)))
    current = rng.uniform(-0.4, 0.4, (2 * count, 3))
    current[:, 2] = 0.0
    plants = [AcousticPhysics(build_tank_model()) for _ in range(2)]
    for plant in plants:
        plant.model.opt.integrator = INTEGRATORS[integrator]
        plant.model.opt.timestep = 0.01 / substeps
        plant.substeps = substeps
        plant.place(refs[0][0], refs[2][0])
    ours = [plants[0].follow(plants[0].data, *(r[rows] for r in refs),
                             current[np.maximum(rows - 1, 0)], start)[1:]
            for start, rows in ((0, np.arange(count)), (count, np.arange(count, 2 * count)))]
    reference = plants[1]
    model, data = reference.model, reference.data
    jac = np.zeros((3, model.nv))
    positions, velocities = [], []
    for k in range(2 * count):
        if k:
            data.ctrl[reference.carrier_pos_act] = refs[0][k]
            data.ctrl[reference.carrier_vel_act] = refs[1][k]
            data.ctrl[reference.arm_act] = refs[2][k]
            model.opt.wind[:] = current[k - 1]
            mujoco.mj_step(model, data, substeps)
            mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jac, None, reference.source_site)
        positions.append(data.site_xpos[reference.source_site].copy())
        velocities.append(jac @ data.qvel)
    assert np.array_equal(np.concatenate([p for p, _ in ours]), np.array(positions))
    assert np.array_equal(np.concatenate([v for _, v in ours]), np.array(velocities))
    assert np.ptp(np.array(positions), axis=0).max() > 0.1  # it moved


def test_state_mode_draws_no_detections_unless_asked():
    """In ``state`` mode the detections are not drawn: nothing the agent sees or is scored
    on depends on them, so asking for them (``draw_detections=True``) changes no
    observation or reward, only adds ``detection_origin`` to ``info``."""
    plain = gym.make(ENV_ID, obs_mode="state", difficulty="hard", time_limit=1.5)
    drawn = gym.make(ENV_ID, obs_mode="state", difficulty="hard", time_limit=1.5,
                     draw_detections=True)
    (obs_a, info_a), (obs_b, info_b) = plain.reset(seed=41), drawn.reset(seed=41)
    assert "detection_origin" not in info_a and info_b["detection_origin"].shape == (10, 8)
    rng = np.random.default_rng(0)
    while True:
        np.testing.assert_array_equal(obs_a, obs_b)
        action = (info_a["true_position"] + rng.normal(0, 0.5, 3)).astype(np.float32)
        obs_a, reward_a, _, done, info_a = plain.step(action)
        obs_b, reward_b, _, _, info_b = drawn.step(action)
        assert reward_a == reward_b and "nodes_working" not in info_a
        assert "nodes_working" in info_b
        if done:
            break
    assert info_a["episode_metrics"] == info_b["episode_metrics"]
    with pytest.raises(RuntimeError, match="draw_detections=True"):
        plain.reset(seed=1)
        plain.unwrapped.episode_record()
    drawn.reset(seed=1)
    assert drawn.unwrapped.trajectory_bound() > 0
    with pytest.raises(TypeError, match="draw_detections"):
        gym.make(ENV_ID, draw_detections="yes")


def _direct_path_errors(noise_draws: str, seed: int) -> np.ndarray:
    """The TDOA errors (s) of the source's own detections at a fixed point, 400 periods."""
    h = np.array([[0, 0, -29.0], [300, 0, -29], [300, 300, -29], [0, 300, -29],
                  [0, 0, -1], [300, 0, -1], [300, 300, -1], [0, 300, -1.0]])
    config = AcousticConfig(clock_offset_std=0.0, clutter_rate=2.0, source_level=106.0)
    array = HydrophoneArray(h, 0.0, -30.0, config)
    point = np.array([120.0, 180.0, -12.0])
    m = array.measure(np.random.default_rng(seed), np.broadcast_to(point, (400, 3)),
                      np.zeros(8), noise_draws=noise_draws, xp=np)
    exact = array.noise_free(point, np)[0]
    own = m.origin == ORIGIN_TARGET
    return (m.tdoa[own] - exact), own.any(axis=2).mean(axis=0)


def test_kept_and_all_draws_are_the_same_model():
    """``noise_draws="kept"`` (v1) and ``"all"`` (v0) differ in the order of the draws,
    not in the model: per band the source's detection rate and its TDOA errors'
    spread agree within sampling error (400 periods, 10 bands, quiet source)."""
    kept, rate_kept = _direct_path_errors("kept", 3)
    every, rate_all = _direct_path_errors("all", 4)
    assert 0.3 < rate_kept.mean() < 0.97  # some bands miss: the detections matter
    np.testing.assert_allclose(rate_kept, rate_all, atol=0.08)
    spread = np.std(kept, axis=0), np.std(every, axis=0)
    np.testing.assert_allclose(spread[0], spread[1], rtol=0.15)
    assert np.all(np.abs(kept.mean(axis=0)) < 0.2 * spread[0])


def test_measurements_keep_one_array_with_views():
    """``Measurements.values`` holds the TDOAs, azimuths and elevations; the three
    named fields are views of it, and an observation's three are views of one copy."""
    env = gym.make(ENV_ID, difficulty="paper")
    obs, _ = env.reset(seed=2)
    m = env.unwrapped._episode.state.block.measurements
    assert m.values.shape[-1] == 3 * 8 - 1 and m.n_nodes == 8
    for part in (m.tdoa, m.azimuth, m.elevation):
        assert np.shares_memory(part, m.values)
    assert obs["tdoa"].base is obs["azimuth"].base is obs["elevation"].base
    assert not np.shares_memory(obs["tdoa"], m.values)
    np.testing.assert_array_equal(obs["elevation"], m.elevation[0])
