"""The privileged homing teacher as one pure law: the NumPy agents (``homing-pd-state``,
``pd-state``) act exactly as :func:`homing_action` / :func:`pd_action` on NumPy, and the same
functions under ``jax.jit(jax.vmap(...))`` agree within float32 precision, the hand-over
latch included."""

from __future__ import annotations

import functools
import math

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the ids)
from baselines.docking.agents import DockingPDAgent, HomingPDAgent
from baselines.docking.control.homing import HomingGains, homing_action, homing_force
from baselines.docking.control.pd import PDGains, pd_action, pd_force

MISSION = "auv_envs/DockingMission-v0"
STATION = "auv_envs/DockingStation-v2"
#: JAX (float32) against NumPy (float64), on actions in [-1, 1].
ACTION_ATOL = 1e-5


def rollout(env_id: str, agent_type, seed: int, steps: int):
    """``steps`` state observations of an episode flown by the agent, the agent's actions and
    its latch before each step (None for an agent without one)."""
    env = gym.make(env_id, obs_mode="state", difficulty="paper")
    agent = agent_type(env.unwrapped)
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    observations, actions, latches = [], [], []
    for _ in range(steps):
        latches.append(getattr(agent, "docking", None))
        action = agent.act(obs, info)
        observations.append(obs)
        actions.append(action)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    return env.unwrapped, np.array(observations), np.array(actions), latches


def state_observation(position, yaw, velocity, yaw_rate, size: int = 16) -> np.ndarray:
    """A ``state`` observation with the entries the privileged controllers read."""
    obs = np.zeros(size, dtype=np.float32)
    obs[0:3] = position
    obs[5:7] = math.cos(yaw), math.sin(yaw)
    obs[7:10] = velocity
    obs[12] = yaw_rate
    return obs


def pass_by_staging(gains: HomingGains) -> np.ndarray:
    """Observations of a vehicle that passes the staging point along the axis (heading near 0)
    and leaves it again: the latch switches on the way in and stays set on the way out."""
    staging = np.asarray(gains.staging_point)
    path = np.concatenate([np.linspace(-6.0, 0.3, 40), np.linspace(0.3, -6.0, 20)])
    return np.array([
        state_observation(staging + [dx, 0.2, -0.1], 0.1, (0.5, 0.05, -0.02), 0.01)
        for dx in path
    ])


def scattered_states(gains: HomingGains, rng: np.random.Generator, n: int) -> np.ndarray:
    """States beside, behind and in front of the station and near the staging point: every
    branch of the waypoint and the capture test, with headings all round."""
    staging = np.asarray(gains.staging_point)
    far = rng.uniform([-40.0, -25.0, -8.0], [8.0, 25.0, 8.0], size=(n, 3))
    near = staging + rng.uniform(-2.5, 2.5, size=(n, 3))
    positions = np.concatenate([far, near])
    return np.array([
        state_observation(p, rng.uniform(-math.pi, math.pi), rng.normal(0.0, 0.5, 3),
                          rng.normal(0.0, 0.2))
        for p in positions
    ])


def act_through(agent: HomingPDAgent, observations: np.ndarray):
    """The agent's actions on a sequence of observations and its latch before each."""
    agent.reset()
    latches, actions = [], []
    for obs in observations:
        latches.append(agent.docking)
        actions.append(agent.act(obs, {}))
    return np.array(actions), np.array(latches)


def numpy_teacher(gains: HomingGains, observations: np.ndarray, latches) -> tuple:
    """:func:`homing_action` on NumPy, one observation at a time from the given latches."""
    out = [homing_action(gains, obs, latch, np) for obs, latch in
           zip(observations, latches, strict=True)]
    return (np.array([a for a, _ in out]).astype(np.float32),
            np.array([bool(d) for _, d in out]))


def test_homing_agent_is_the_pure_law_on_numpy():
    env, observations, actions, latches = rollout(MISSION, HomingPDAgent, seed=2, steps=200)
    assert len(actions) == 200
    gains = HomingGains.from_calibration(env.calibration)
    expected, _ = numpy_teacher(gains, observations, latches)
    np.testing.assert_array_equal(actions, expected)


def test_pd_agent_is_the_pure_law_on_numpy():
    env, observations, actions, _ = rollout(STATION, DockingPDAgent, seed=0, steps=200)
    gains = PDGains.from_calibration(env.calibration)
    expected = np.array([pd_action(gains, obs, np) for obs in observations]).astype(np.float32)
    np.testing.assert_array_equal(actions, expected)


def test_latch_switches_at_the_staging_point_and_holds():
    env = gym.make(MISSION, obs_mode="state", difficulty="paper").unwrapped
    agent = HomingPDAgent(env)
    observations = pass_by_staging(agent.gains)
    actions, latches = act_through(agent, observations)
    staging = np.asarray(agent.gains.staging_point)
    inside = np.linalg.norm(observations[:, :3] - staging, axis=1) < agent.gains.capture
    first = int(np.argmax(inside))
    after = np.append(latches[1:], agent.docking)  # the latch after each step
    assert not after[:first].any() and after[first:].all()
    assert not inside[-1]  # it left the capture circle and kept the terminal law
    expected, _ = numpy_teacher(agent.gains, observations, latches)
    np.testing.assert_array_equal(actions, expected)
    # From the hand-over on, the action is pd-state's.
    pd = PDGains.from_calibration(env.calibration)
    np.testing.assert_array_equal(
        actions[first:],
        np.array([pd_action(pd, obs, np) for obs in observations[first:]]).astype(np.float32))


def test_latch_waits_for_the_heading():
    env = gym.make(MISSION, obs_mode="state", difficulty="paper").unwrapped
    gains = HomingGains.from_calibration(env.calibration)
    position = np.asarray(gains.staging_point)
    for yaw, latched in ((0.45, True), (-0.45, True), (0.6, False), (2.0 * math.pi, True)):
        _, docking = homing_force(gains, position, yaw, np.zeros(3), 0.0, False, np)
        assert bool(docking) is latched
    _, docking = homing_force(gains, position, 1.0, np.zeros(3), 0.0, True, np)
    assert bool(docking)  # never cleared


def test_terminal_force_matches_the_pd_law():
    env = gym.make(MISSION, obs_mode="state", difficulty="paper").unwrapped
    gains = HomingGains.from_calibration(env.calibration)
    args = (np.array([-4.0, 0.3, -0.2]), 0.2, np.array([0.4, 0.0, 0.1]), 0.05)
    force, _ = homing_force(gains, *args, True, np)
    np.testing.assert_array_equal(force, pd_force(gains.terminal, *args, np))


def test_jax_teacher_matches_numpy_batched():
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    env, observations, _, latches = rollout(MISSION, HomingPDAgent, seed=2, steps=200)
    agent = HomingPDAgent(env)
    gains = agent.gains
    handmade = np.concatenate([pass_by_staging(gains),
                               scattered_states(gains, np.random.default_rng(5), 100)])
    _, handmade_latches = act_through(agent, handmade)
    batch = np.concatenate([observations, handmade])
    before = np.concatenate([np.array(latches, dtype=bool), handmade_latches])
    expected, expected_latch = numpy_teacher(gains, batch, before)
    assert expected_latch.any() and not expected_latch.all()
    assert (expected_latch & ~before).any()  # the batch holds hand-overs

    teacher = jax.jit(jax.vmap(functools.partial(homing_action, gains, xp=jnp)))
    actions, docking = teacher(jnp.asarray(batch), jnp.asarray(before))
    np.testing.assert_array_equal(np.asarray(docking), expected_latch)
    np.testing.assert_allclose(np.asarray(actions), expected, rtol=0.0, atol=ACTION_ATOL)

    # The gains may also travel as a pytree argument.
    teacher = jax.jit(jax.vmap(functools.partial(homing_action, xp=jnp),
                               in_axes=(None, 0, 0)))
    actions, _ = teacher(gains, jnp.asarray(batch), jnp.asarray(before))
    np.testing.assert_allclose(np.asarray(actions), expected, rtol=0.0, atol=ACTION_ATOL)


def test_jax_pd_matches_numpy_batched():
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    env, observations, actions, _ = rollout(STATION, DockingPDAgent, seed=0, steps=200)
    gains = PDGains.from_calibration(env.calibration)
    batched = jax.jit(jax.vmap(functools.partial(pd_action, gains, xp=jnp)))(
        jnp.asarray(observations))
    np.testing.assert_allclose(np.asarray(batched), actions, rtol=0.0, atol=ACTION_ATOL)


def test_the_corridor_is_the_approach_from_staging_into_the_funnel():
    """The state-decided hand-over: inside from the staging point's capture distance to
    CORRIDOR_BEYOND past the docking point, near the axis, heading along it except within
    STATION_ZONE of the docking point; the latch's own condition lies in it."""
    from baselines.docking.control.homing import CORRIDOR_BEYOND, STATION_ZONE, in_corridor

    env = gym.make(MISSION, obs_mode="state", difficulty="paper").unwrapped
    gains = HomingGains.from_calibration(env.calibration)
    staging, target = np.asarray(gains.staging_point), np.asarray(gains.target)

    def inside(offset, yaw=0.0, base=staging):
        return bool(in_corridor(gains, base + np.asarray(offset), yaw, 3.0, np))

    assert inside([0, 0, 0]) and inside([gains.capture * 0.9, 0.5, -0.5])
    assert inside([0, 0, 0], base=target) and inside([-1.0, 2.9, 0.0], base=target)
    assert inside([CORRIDOR_BEYOND - 0.05, 0.4, 0], base=target)  # the nose in the funnel
    assert not inside([-gains.capture - 0.1, 0, 0])  # before the staging point
    assert not inside([CORRIDOR_BEYOND + 0.05, 0, 0], base=target)  # past the funnel
    assert not inside([0, 3.1, 0]) and not inside([0, 0, -3.1])  # off the axis
    assert not inside([0, 0, 0], yaw=0.6)  # heading off the axis, far from the station
    assert not inside([-STATION_ZONE - 0.05, 0, 0], yaw=0.6, base=target)
    # Near the station any heading is in: homing's turn there would pin the hull.
    assert inside([-STATION_ZONE + 0.05, 0, 0], yaw=1.3, base=target)
    assert inside([0.0, -0.45, 0], yaw=-1.2, base=target)


def test_the_corridor_teacher_docks_where_it_used_to_pin_the_hull():
    """A CPU episode (paper, seed 700011) in which the corridor, when it ended at the
    docking point, handed a hull 0.46 m off the axis at the entrance back to homing, whose
    turn pinned it on the funnel until the time limit: the corridor through the funnel
    docks it."""
    from baselines.docking.control.homing import corridor_action

    env = gym.make(MISSION, obs_mode="state", difficulty="paper")
    gains = HomingGains.from_calibration(env.unwrapped.calibration)
    obs, info = env.reset(seed=700011)
    while True:
        obs, _, terminated, truncated, info = env.step(corridor_action(gains, obs, np))
        if terminated or truncated:
            break
    assert info["is_success"], info["failure_reason"]
