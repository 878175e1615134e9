"""Every family's task as Gymnasium's functional environment (``auv_envs.batched.funcenv``),
driven by Gymnasium's own ``FunctionalJaxEnv``, batched by ``transform(jax.vmap)``, with
the world as its explicit parameters."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

from gymnasium.envs.functional_jax_env import FunctionalJaxEnv  # noqa: E402

from auv_envs.batched.funcenv import TaskFuncEnv  # noqa: E402
from auv_envs.families import FAMILIES  # noqa: E402

#: One id per task family (the lamp array and the mission are the docking task's).
IDS = [entry.env_id for entry in FAMILIES
       if entry.env_id not in ("auv_envs/LampArrayDocking-v2", "auv_envs/DockingMission-v0")]


def _numpy(tree):
    return jax.tree_util.tree_map(np.asarray, tree)


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasiums_functional_jax_env_runs_every_family(env_id):
    func = TaskFuncEnv(env_id)
    func.transform(jax.jit)
    env = FunctionalJaxEnv(func)
    env.action_space.seed(0)
    obs, _ = env.reset(seed=7)
    assert env.observation_space.contains(_numpy(obs))
    first = env.state
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(_numpy(obs))
        assert np.isfinite(reward) and not truncated
        assert reward == pytest.approx(float(env.state.reward))
        assert set(func.shell.STEP_METRICS) <= set(info)
    assert int(env.state.episode.steps) == 5
    # The same seed, the same episode.
    env.reset(seed=7)
    assert np.array_equal(np.asarray(jax.tree_util.tree_leaves(env.state.obs)[0]),
                          np.asarray(jax.tree_util.tree_leaves(first.obs)[0]))


def test_the_world_is_an_explicit_parameter_and_vmap_batches_the_task():
    func = TaskFuncEnv("auv_envs/DockingStation-v2", obs_mode="state")
    shell = func.shell
    keys = jax.random.split(jax.random.PRNGKey(1), 4)
    worlds, in_axes = shell.randomize(func.default_params, jax.random.split(
        jax.random.PRNGKey(2), 4))
    initial = jax.jit(jax.vmap(func.initial))
    transition = jax.jit(jax.vmap(func.transition, in_axes=(0, 0, 0, in_axes)))
    nominal = jax.jit(jax.vmap(func.transition))
    states = initial(keys)
    action = np.tile(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (4, 1))
    step_keys = jax.random.split(jax.random.PRNGKey(3), 4)
    varied = transition(states, action, step_keys, worlds)
    plain = nominal(states, action, step_keys)
    # The default parameters are the nominal world; the drawn worlds move the vehicles.
    again = jax.jit(jax.vmap(lambda s, a, k: func.transition(s, a, k, func.default_params)))(
        states, action, step_keys)
    assert np.array_equal(np.asarray(again.obs), np.asarray(plain.obs))
    assert not np.allclose(np.asarray(varied.obs), np.asarray(plain.obs))
    # Each batch entry is the task's own step of its own state.
    one = jax.jit(func.transition)(jax.tree_util.tree_map(lambda x: x[2], states), action[2],
                                   step_keys[2])
    np.testing.assert_allclose(np.asarray(one.obs), np.asarray(plain.obs)[2], rtol=1e-5,
                               atol=1e-6)
