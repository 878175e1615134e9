"""``privileged=True`` on every batched family: Playground's asymmetric-critic observation.

Every row of the family table (:data:`auv_envs.families.FAMILIES`) built with
``privileged=True`` observes ``{"state": ..., "privileged_state": ...}``. Checked here,
from the same key and actions over an auto-reset:

* the episode is the one without it: ``obs["state"]``, the rewards, the ends and
  ``info["final_obs"]`` bit-identical to the plain env's (the privileged state draws
  nothing);
* ``obs["privileged_state"]`` is the family's ``obs_mode="state"`` observation: equal to
  ``obs["state"]`` in that mode, and in the family's other mode equal to what the
  state-mode env observes on the same episode (a trajectory the observation's draws do
  not move, each transition drawing them after the plant's);
* the observation, ``info["final_obs"]`` and the restarted episode's first observation
  are dicts of those two keys that ``observation_space`` contains, under Gymnasium's
  conventions and under Playground's (:func:`auv_envs.batched.load`: the ``"state"``
  entry flattened, ``observation_size`` the shapes by key);
* a ``privileged`` that is not a bool is refused.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

import auv_envs.batched  # noqa: E402
from auv_envs.batched.functional import PRIVILEGED_KEY, FunctionalEnv  # noqa: E402
from auv_envs.families import FAMILIES  # noqa: E402

#: Steps of each rollout; the episode is cut at ``LENGTH`` steps, so the last steps cross
#: an auto-reset.
STEPS, LENGTH = 4, 3
#: Each family's observation mode other than ``state`` (the first one its table lists).
OTHER_MODE = {entry.env_id: next(mode for mode in entry.batched_modes if mode != "state")
              for entry in FAMILIES}


def build(env_id: str, obs_mode: str, **kwargs):
    """The family's batched env (Gymnasium's conventions, auto-reset), its episodes cut at
    ``LENGTH`` steps."""
    env = FunctionalEnv(env_id, obs_mode=obs_mode, **kwargs)
    env.max_episode_steps = LENGTH
    return env


def run_together(envs, actions) -> list[list]:
    """Each env's states from the same key's reset on under ``actions`` (NumPy). One
    compiled call runs them all, the resets and the steps together: one compilation
    instead of one an env (the acoustic family's take a minute each on 2 cores)."""
    def run(key, actions):
        def one(env):
            def step(state, action):
                state = env.step(state, action)
                return state, state

            first = env.reset(key)
            return first, jax.lax.scan(step, first, actions)[1]
        return [one(env) for env in envs]

    runs = jax.tree_util.tree_map(np.asarray, jax.jit(run)(jax.random.PRNGKey(7), actions))
    return [[first, *(jax.tree_util.tree_map(lambda leaf, k=k: leaf[k], stepped)
                      for k in range(len(actions)))] for first, stepped in runs]


def actions_for(env) -> np.ndarray:
    space = env.action_space
    return np.random.default_rng(3).uniform(space.low, space.high,
                                            (STEPS, *space.shape)).astype(np.float32)


def assert_same(a, b) -> None:
    """Two observations (arrays or dicts of them) equal bit for bit."""
    leaves_a, tree_a = jax.tree_util.tree_flatten(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b, strict=True):
        assert x.dtype == y.dtype
        np.testing.assert_array_equal(x, y)


@pytest.fixture(scope="module", params=list(OTHER_MODE), ids=lambda env_id: env_id.split("/")[1])
def rollouts(request):
    """One family's rollouts from one key and the same actions: its other mode plain and
    privileged, and its ``state`` mode privileged."""
    env_id = request.param
    mode = OTHER_MODE[env_id]
    plain = build(env_id, mode)
    privileged = build(env_id, mode, privileged=True)
    state_mode = build(env_id, "state", privileged=True)
    runs = run_together((plain, privileged, state_mode), actions_for(plain))
    return {"plain": runs[0], "privileged": runs[1], "privileged_env": privileged,
            "state_mode": runs[2], "state_env": state_mode}


def test_the_episode_is_the_plain_envs(rollouts):
    ended = False
    for plain, privileged in zip(rollouts["plain"], rollouts["privileged"], strict=True):
        assert set(privileged.obs) == {"state", "privileged_state"}
        assert_same(privileged.obs["state"], plain.obs)
        assert_same(privileged.info["final_obs"]["state"], plain.info["final_obs"])
        np.testing.assert_array_equal(privileged.reward, plain.reward)
        np.testing.assert_array_equal(privileged.done, plain.done)
        np.testing.assert_array_equal(privileged.info["terminated"], plain.info["terminated"])
        assert_same(privileged.data, plain.data)
        ended |= bool(plain.done)
    assert ended  # the rollout crossed an auto-reset


def test_the_privileged_state_is_the_state_mode_observation(rollouts):
    for state, other in zip(rollouts["state_mode"], rollouts["privileged"], strict=True):
        # In state mode the privileged state is the observation itself ...
        assert_same(state.obs[PRIVILEGED_KEY], state.obs["state"])
        assert_same(state.info["final_obs"][PRIVILEGED_KEY], state.info["final_obs"]["state"])
        # ... and in the other mode the state-mode observation of the same episode.
        assert_same(other.obs[PRIVILEGED_KEY], state.obs["state"])
        assert_same(other.info["final_obs"][PRIVILEGED_KEY], state.info["final_obs"]["state"])
    # A sharp check: the vector moves from step to step.
    first, second = (s.obs[PRIVILEGED_KEY] for s in rollouts["privileged"][:2])
    assert np.abs(first - second).max() > 0.0


def test_an_auto_reset_restarts_the_whole_dict(rollouts):
    for name in ("privileged", "state_mode"):
        states = rollouts[name]
        k = next(k for k, state in enumerate(states) if k and state.done)
        state = states[k]
        # The step that ended the episode returns the next one's first observation, both
        # entries (the test above: each the plain env's, the state-mode env's) ...
        np.testing.assert_array_equal(state.data["episode"].steps, 0)
        assert set(state.obs) == set(state.info["final_obs"]) == {"state", "privileged_state"}
        # ... and final_obs the one that ended the episode, both entries.
        assert np.abs(state.info["final_obs"][PRIVILEGED_KEY]
                      - state.obs[PRIVILEGED_KEY]).max() > 0.0


def test_observations_lie_in_the_dict_space(rollouts):
    for name in ("privileged_env", "state_env"):
        env = rollouts[name]
        space = env.observation_space
        assert isinstance(space, gym.spaces.Dict)
        assert set(space.spaces) == {"state", "privileged_state"}
        assert space["state"] == env.task.observation_space
        privileged_space = space[PRIVILEGED_KEY]
        assert isinstance(privileged_space, gym.spaces.Box)
        assert privileged_space.dtype == np.float32
    # The privileged state's space is the CPU state-mode env's.
    assert (rollouts["privileged_env"].observation_space[PRIVILEGED_KEY]
            == rollouts["state_env"].task.observation_space)
    space = rollouts["privileged_env"].observation_space
    for state in rollouts["privileged"]:
        for obs in (state.obs, state.info["final_obs"]):
            assert obs[PRIVILEGED_KEY].dtype == np.float32
            assert space.contains(obs), obs


@pytest.mark.parametrize("env_id", list(OTHER_MODE), ids=lambda env_id: env_id.split("/")[1])
def test_load_gives_brax_the_two_flat_entries(env_id):
    mode = OTHER_MODE[env_id]
    env = auv_envs.batched.load(env_id, obs_mode=mode, privileged=True)
    flat = auv_envs.batched.load(env_id, obs_mode=mode)
    state_size = gym.spaces.flatdim(env.task.observation_space)
    privileged_size = env.observation_space[PRIVILEGED_KEY].shape[0]
    assert env.observation_space["state"] == flat.observation_space
    assert env.observation_size == {"state": (state_size,),
                                    "privileged_state": (privileged_size,)}
    obs = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs
    for key, shape in env.observation_size.items():
        assert obs[key].shape == shape and obs[key].dtype == np.float32


@pytest.mark.parametrize("bad", ["yes", 1, None, np.array([True])])
def test_privileged_must_be_a_bool(bad):
    with pytest.raises(TypeError, match="privileged must be True or False"):
        auv_envs.batched.load("auv_envs/AcousticTracking-v2", privileged=bad)
