"""The batched acoustic tracking environment: the CPU transition on JAX under ``vmap``.

Equivalence with ``auv_envs/AcousticTracking-v2`` as for the other families: the same
plan and estimates give the same source positions (within 1 cm over 20 s, float32),
currents and rewards; the episode ends and resets itself at the time limit.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

from auv_envs.batched.functional import FunctionalEnv  # noqa: E402
from auv_envs.tasks.acoustic.transition import STEP_METRICS  # noqa: E402

ENV_ID = "auv_envs/AcousticTracking-v2"
TIME_LIMIT = 20.0
KWARGS = {"difficulty": "paper", "disturbance": "high", "time_limit": TIME_LIMIT}


@pytest.fixture(scope="module")
def batched():
    env = FunctionalEnv(ENV_ID, obs_mode="state", **KWARGS)

    def run(state, actions):
        def one(state, action):
            state = env.step(state, action)
            return state, (state.obs, state.reward, state.done,
                           state.metrics["episode_rmse"])

        return jax.lax.scan(one, state, actions)

    return env, jax.jit(env.reset_to), jax.jit(run)


@pytest.mark.parametrize("seed", [61001, 61002])
def test_same_plan_same_episode(batched, seed):
    env, reset_to, run = batched
    cpu = gym.make("auv_envs/AcousticTracking-v2", obs_mode="state", **KWARGS)
    obs, _ = cpu.reset(seed=seed)
    state = reset_to(cpu.unwrapped._episode.state.plan, jax.random.key(seed))
    np.testing.assert_allclose(np.asarray(state.obs), obs, atol=1e-4)
    steps = env.max_episode_steps
    rng = np.random.default_rng(seed)
    estimates = (obs[:3] + rng.normal(0.0, 2.0, (steps, 3))).astype(np.float32)
    cpu_obs, cpu_reward = [], []
    for action in estimates:
        o, r, terminated, truncated, info = cpu.step(action)
        cpu_obs.append(o)
        cpu_reward.append(r)
    assert truncated and not terminated
    _, (obs_b, reward_b, done_b, rmse_b) = run(state, jnp.asarray(estimates))
    obs_b, cpu_obs = np.asarray(obs_b), np.array(cpu_obs)
    # The last step resets the batched episode (its obs is the new episode's).
    assert np.asarray(done_b).tolist() == [False] * (steps - 1) + [True]
    position_error = np.abs(obs_b[:-1, :3] - cpu_obs[:-1, :3]).max()
    assert position_error < 0.01, position_error
    np.testing.assert_allclose(obs_b[:-1, 3:6], cpu_obs[:-1, 3:6], atol=0.01)
    np.testing.assert_allclose(obs_b[:-1, 6:], cpu_obs[:-1, 6:], atol=1e-5)
    np.testing.assert_allclose(np.asarray(reward_b), cpu_reward, atol=1e-3)
    np.testing.assert_allclose(float(rmse_b[-1]), info["episode_metrics"]["rmse"], rtol=1e-3)
    cpu.close()


def test_batched_reset_and_step_shapes(batched):
    env, _, _ = batched
    keys = jax.random.split(jax.random.key(61003), 8)
    states = jax.jit(jax.vmap(env.reset))(keys)
    assert states.obs.shape == (8, 9) and states.obs.dtype == jnp.float32
    assert env.observation_space.shape == (9,) and env.action_size == 3
    states = jax.jit(jax.vmap(env.step))(states, states.obs[:, :3])
    assert set(STEP_METRICS) <= set(states.metrics)
    # Estimating the position just observed scores the error to the true one (none).
    np.testing.assert_allclose(np.asarray(states.metrics["estimate_error"]), 0.0, atol=1e-4)
    assert np.all(np.asarray(states.reward) > -1e-4)
    # Episodes differ across keys: their starts are drawn.
    assert len({tuple(np.round(np.asarray(o[:3]), 3)) for o in states.obs}) == 8


def test_measurements_as_the_cpu_env_draws_them():
    """``hard`` (multipath, clutter, dropouts, propagation delay) through
    ``gym.make_vec("auv_envs/AcousticTrackingMJX-v2")``: the batched detection sets
    have the CPU env's shapes, per band the share of filled slots and the share of
    working nodes agree with the CPU env's within five standard errors (8 episodes of
    99 periods each; the model's draws themselves: ``tests/test_acoustics_jax.py``),
    and the episodes end at the time limit with their summary."""
    kwargs = {"difficulty": "hard", "time_limit": 1.0}
    envs = gym.make_vec("auv_envs/AcousticTrackingMJX-v2", num_envs=8,
                        obs_mode="measurements", **kwargs)
    space = envs.single_observation_space
    obs, _ = envs.reset(seed=61004)
    assert {k: v.shape[1:] for k, v in obs.items()} == {
        k: v.shape for k, v in space.spaces.items()}
    batched = []
    for step in range(100):
        obs, reward, terminated, truncated, info = envs.step(np.full((8, 3), 150.0))
        assert not terminated.any() and truncated.all() == (step == 99)
        if step < 99:
            batched.append((obs["mask"].mean(axis=(0, 2)), obs["node_mask"].mean()))
    assert info["_episode_metrics"].all() and info["episode_metrics"]["steps"].tolist() == [100] * 8
    assert np.all(info["episode_metrics"]["rmse"] > 0)
    envs.close()
    cpu = gym.make("auv_envs/AcousticTracking-v2", obs_mode="measurements", **kwargs)
    on_cpu = []
    for seed in range(61010, 61018):
        obs, _ = cpu.reset(seed=seed)
        for _ in range(99):
            obs, *_ = cpu.step(np.full(3, 150.0, np.float32))
            assert all(space[k].contains(obs[k]) for k in obs)
            on_cpu.append((obs["mask"].mean(axis=1), obs["node_mask"].mean()))
    cpu.close()
    for index in (0, 1):
        a = np.array([row[index] for row in batched])
        b = np.array([row[index] for row in on_cpu])
        # Periods within an episode are correlated: one standard error per episode.
        error = np.sqrt(a.var(axis=0) / 8 + b.var(axis=0) / 8) + 0.02
        assert np.all(np.abs(a.mean(axis=0) - b.mean(axis=0)) < 5 * error), (
            a.mean(axis=0), b.mean(axis=0))


def test_refusals():
    with pytest.raises(ValueError, match="obs_mode"):
        FunctionalEnv(ENV_ID, obs_mode="pixels")
    with pytest.raises(ValueError, match="planner"):
        FunctionalEnv(ENV_ID, obs_mode="state", planner="tabulated")
