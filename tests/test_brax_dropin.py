"""Every batched family is a drop-in for MuJoCo Playground's and Brax's training code.

``auv_envs.batched.load`` gives the functional env; Playground's
``wrap_for_brax_training`` (Brax's ``VmapWrapper``, ``EpisodeWrapper`` and Playground's
``BraxAutoResetWrapper``) wraps it as it wraps Playground's own environments, and Brax's
PPO trains on it with its default networks, with no adapter in between. Checked here,
with the libraries themselves:

* the wrappers' semantics: Brax counts the steps (the env does not count them again), an
  episode that reaches ``episode_length`` ends with ``info["truncation"] == 1`` and float
  ``done``, the auto-reset (to the cached first state, Playground's default) restarts the
  whole episode (its step count and running scores) and the metrics and info keys the
  wrappers add survive a step;
* ``brax.training.agents.ppo.train`` runs training iterations on docking and its
  evaluation returns finite rewards (``scripts/brax_ppo.py`` shows the reward rising over a
  longer run);
* with ``load(..., privileged=True)`` it trains an asymmetric critic on each family, as on
  Playground's tasks (``make_ppo_networks(..., policy_obs_key="state",
  value_obs_key="privileged_state")``): the policy reads the flat observation that
  ``load`` gives without ``privileged`` (so this is the plain drop-in's training too), the
  value network the family's state vector. These runs skip Brax's evaluation, which the
  docking run checks: compiling it again for each family would double the test's time.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("brax")
pytest.importorskip("mujoco_playground")
import jax.numpy as jnp  # noqa: E402
from brax.training.agents.ppo import networks as ppo_networks  # noqa: E402
from brax.training.agents.ppo import train as ppo  # noqa: E402
from mujoco_playground import wrapper  # noqa: E402

import auv_envs.batched  # noqa: E402
from tests.conftest import JAX_TASKS  # noqa: E402

#: One id per batched class of the family table, in its default mode (dict modes, which
#: Brax's networks need flat).
SHELLS = [(env_id, auv_envs.family(env_id).batched_mode) for env_id in JAX_TASKS]


def test_load_takes_every_family_and_refuses_the_rest():
    with pytest.raises(ValueError, match="no batched environment"):
        auv_envs.batched.load("auv_envs/DockingStation-v1")
    with pytest.raises(ValueError, match="no batched environment"):
        auv_envs.batched.load("HalfCheetah-v5")
    env = auv_envs.batched.load("auv_envs/AcousticTrackingMJX-v2", obs_mode="measurements")
    # Flat float32 observations (10 x 8 x 8 azimuths and elevations, 10 x 8 masks, 10 x 8 x 7
    # TDOAs) and actions in [-1, 1] mapped onto the tank.
    assert env.observation_size == 10 * 8 * 8 * 2 + 10 * 8 + 10 * 8 * 7
    assert env.action_size == 3 and env.episode_length == env.task.max_episode_steps
    np.testing.assert_allclose(np.asarray(env._action(jnp.array([-1.0, 1.0, 0.0]))),
                               [0.0, 300.0, -15.0])
    np.testing.assert_allclose(np.asarray(env._action(jnp.array([-7.0, 2.0, 0.0]))),
                               [0.0, 300.0, -15.0])


def test_docking_under_playground_wrappers_counts_truncates_and_restarts():
    env = auv_envs.batched.load("auv_envs/DockingStation-v2", obs_mode="features")
    length, batch = 6, 3
    wrapped = wrapper.wrap_for_brax_training(env, episode_length=length)
    reset, step = jax.jit(wrapped.reset), jax.jit(wrapped.step)
    state = reset(jax.random.split(jax.random.PRNGKey(3), batch))
    first_obs = np.asarray(state.obs)
    assert first_obs.shape == (batch, env.observation_size) and first_obs.dtype == np.float32
    state.metrics["reward"] = state.reward  # as Brax's EvalWrapper adds it
    state.info["user_key"] = jnp.arange(batch, dtype=jnp.float32)
    action = jnp.zeros((batch, env.action_size))
    first_rewards = []
    for k in range(1, length + 1):
        state = step(state, action)
        first_rewards.append(np.asarray(state.reward))
        assert state.done.dtype == jnp.float32 and state.info["truncation"].dtype == jnp.float32
        assert "reward" in state.metrics and "user_key" in state.info
        if k < length:  # Brax's count, one a step; the env's own count agrees
            np.testing.assert_array_equal(np.asarray(state.info["steps"]), k)
            np.testing.assert_array_equal(np.asarray(state.data["episode"].steps), k)
            assert not np.asarray(state.done).any()
    # Holding still, no episode docks or fails in 0.6 s: all end by the time limit.
    np.testing.assert_array_equal(np.asarray(state.done), 1.0)
    np.testing.assert_array_equal(np.asarray(state.info["truncation"]), 1.0)
    # Playground's auto-reset restored the first state: the whole episode, not its plant alone.
    np.testing.assert_array_equal(np.asarray(state.data["episode"].steps), 0)
    np.testing.assert_allclose(np.asarray(state.obs), first_obs)
    state = step(state, action)
    np.testing.assert_array_equal(np.asarray(state.info["steps"]), 1)
    np.testing.assert_array_equal(np.asarray(state.data["episode"].steps), 1)
    assert not np.asarray(state.done).any()
    # No stale info: the restarted episode's first reward is the first episode's (the
    # progress term measured from the episode's own start, not from where the last ended).
    np.testing.assert_allclose(np.asarray(state.reward), first_rewards[0], atol=1e-5)
    assert np.abs(first_rewards[-1] - first_rewards[0]).max() > 0.0


def train_briefly(env, run_evals: bool = True, **train_kwargs):
    """A few iterations of Brax's PPO on ``env`` through Playground's wrappers: checks that
    they ran, that the evaluations (with ``run_evals``) and the parameters are finite and
    that training moved the policy; returns the parameters (normaliser, policy, value)."""
    progress, first = [], []
    _, params, metrics = ppo.train(
        environment=env, num_timesteps=240, episode_length=30,
        wrap_env_fn=wrapper.wrap_for_brax_training, num_envs=4, batch_size=4,
        num_minibatches=1, unroll_length=5, num_updates_per_batch=1, num_evals=2,
        num_eval_envs=2, seed=0, run_evals=run_evals,
        progress_fn=lambda steps, m: progress.append((steps, m.get("eval/episode_reward"))),
        policy_params_fn=lambda steps, make_policy, params: first.append(params) or None,
        **train_kwargs)
    assert progress and progress[-1][0] >= 240
    if run_evals:
        assert progress[0][0] == 0
        assert all(np.isfinite(float(reward)) for _, reward in progress)
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree_util.tree_leaves(params))
    # The policy trained: its parameters moved from those at the first report.
    start, end = (jax.tree_util.tree_leaves(p[1]) for p in (first[0], params))
    assert max(float(np.abs(np.asarray(a) - np.asarray(b)).max())
               for a, b in zip(start, end, strict=True)) > 0.0
    return params


def test_brax_ppo_trains_on_docking_and_evaluates():
    env_id, obs_mode = SHELLS[0]
    train_briefly(auv_envs.batched.load(env_id, obs_mode=obs_mode))


@pytest.mark.parametrize(("env_id", "obs_mode"), SHELLS)
def test_brax_ppo_trains_an_asymmetric_critic_on_each_family(env_id, obs_mode):
    env = auv_envs.batched.load(env_id, obs_mode=obs_mode, privileged=True)
    sizes = {key: shape[0] for key, shape in env.observation_size.items()}
    assert sizes["state"] == auv_envs.batched.load(env_id, obs_mode=obs_mode).observation_size
    _, policy, value = train_briefly(env, run_evals=False, network_factory=functools.partial(
        ppo_networks.make_ppo_networks, policy_obs_key="state",
        value_obs_key="privileged_state"))
    # Each network's first layer reads its own entry (the two sizes differ for docking
    # and acoustic; LARS's features flatten to as many entries as its state).
    assert policy["params"]["hidden_0"]["kernel"].shape[0] == sizes["state"]
    assert value["params"]["hidden_0"]["kernel"].shape[0] == sizes["privileged_state"]


def test_brax_ppo_trains_through_the_shipped_domain_randomiser():
    """``ppo.train(..., randomization_fn=env.randomize)``: Brax draws one world per training
    environment and Playground's wrapper maps the env over them
    (``tests/test_randomization.py`` shows the worlds differ)."""
    env = auv_envs.batched.load("auv_envs/DockingStation-v2", obs_mode="features")
    train_briefly(env, run_evals=False, randomization_fn=env.randomize)
