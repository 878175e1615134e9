"""Every family's transition keeps one protocol (:mod:`auv_envs.core.task`), and what it
returns is never changed afterwards."""

import copy

import gymnasium as gym
import numpy as np
import pytest

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

import auv_envs  # noqa: E402,F401
from auv_envs.batched.functional import FunctionalEnv  # noqa: E402
from auv_envs.core import task  # noqa: E402
from auv_envs.core.ops import FLOATS, jax_ops  # noqa: E402
from auv_envs.tasks.acoustic import transition as acoustic  # noqa: E402
from auv_envs.tasks.acoustic.transition import Trail  # noqa: E402
from auv_envs.tasks.docking import transition as docking  # noqa: E402
from auv_envs.tasks.lars import transition as lars  # noqa: E402
from tests.conftest import JAX_TASKS  # noqa: E402

TRANSITIONS = {"auv_envs/DockingStation-v2": docking, "auv_envs/LARSCapture-v0": lars,
               "auv_envs/AcousticTracking-v2": acoustic}


@pytest.mark.parametrize("env_id", TRANSITIONS)
def test_every_transition_returns_a_transition(env_id):
    """``reset`` and ``step`` of each family return :class:`Transition` s whose judgement
    holds the family's reward terms in order; the Gymnasium env's reward is their sum."""
    module = TRANSITIONS[env_id]
    env = gym.make(env_id).unwrapped
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    first = module.reset(env.params, env._backend(rng))
    assert isinstance(first, task.Transition) and first.judged is None
    assert first.plant is env.physics.data  # the CPU plant's state: MuJoCo's data
    env.reset(seed=3)
    action = env.action_space.sample()
    _, reward, terminated, _, info = env.step(action)
    judged = env._episode.judged
    assert tuple(judged.terms) == module.REWARD_TERMS == env.reward_terms
    assert reward == task.reward(judged.terms)
    assert terminated == judged.terminated
    assert all(info[f"reward_{term}"] == judged.terms[term] for term in module.REWARD_TERMS)
    env.close()


def test_the_end_of_a_step_on_both_backends():
    assert task.reward({"a": 1.5, "b": -0.25, "c": 2.0}) == 3.25
    assert task.truncated(False, 10, 10, FLOATS) is True
    assert task.truncated(True, 10, 10, FLOATS) is False
    assert task.truncated(False, 9, 10, FLOATS) is False
    flags = task.truncated(jnp.array([False, True, False]), jnp.array([10, 10, 9]), 10,
                           jax_ops())
    assert flags.tolist() == [True, False, False]


def test_a_trail_is_persistent():
    """Appending never changes a trail already made, even when one is appended to twice
    (a state stepped on two branches)."""
    empty = Trail.empty(5, 2, 2)
    one = empty.append([1.0, 1.0], [-1.0, -1.0])
    two = one.append([2.0, 2.0], [-2.0, -2.0])
    branch = one.append([9.0, 9.0], [-9.0, -9.0])  # one grown again: must not touch two's
    assert empty.series(0).shape == (0, 2)
    np.testing.assert_array_equal(one.series(0), [[1.0, 1.0]])
    np.testing.assert_array_equal(two.series(0), [[1.0, 1.0], [2.0, 2.0]])
    np.testing.assert_array_equal(two.series(1), [[-1.0, -1.0], [-2.0, -2.0]])
    np.testing.assert_array_equal(branch.series(0), [[1.0, 1.0], [9.0, 9.0]])
    np.testing.assert_array_equal(two.append([3.0, 3.0], [0.0, 0.0]).series(0)[-1], [3.0, 3.0])
    np.testing.assert_array_equal(two.series(0), [[1.0, 1.0], [2.0, 2.0]])
    with pytest.raises(ValueError):
        two.series(0)[0, 0] = 5.0  # read-only


def test_an_acoustic_state_stays_as_it_was():
    """A copy of an episode's state, stepped again from, gives the same summary as the
    original; the original's record is unchanged by the copy's steps."""
    env = gym.make("auv_envs/AcousticTracking-v2", obs_mode="state").unwrapped
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.array([100.0, 100.0, -5.0]))
    kept = env._episode.state
    rows = kept.estimates.copy()
    snapshot = copy.deepcopy(env._get_runtime_state())
    for _ in range(5):
        env.step(np.array([50.0, 50.0, -5.0]))
    np.testing.assert_array_equal(kept.estimates, rows)
    env._set_runtime_state(snapshot)
    for _ in range(5):
        env.step(np.array([60.0, 60.0, -5.0]))
    np.testing.assert_array_equal(kept.estimates, rows)
    assert env._episode.state.estimates.shape == (25, 3)
    np.testing.assert_array_equal(env._episode.state.estimates[20:], [[60.0, 60.0, -5.0]] * 5)
    env.close()


@pytest.mark.parametrize("env_id", JAX_TASKS)
def test_a_batched_step_is_a_function_of_its_state(env_id):
    """The same state and action give the same next state twice; the state given is not
    changed (frozen: only ``replace`` makes another)."""
    batched = FunctionalEnv(env_id)
    state = batched.reset(jax.random.PRNGKey(1))
    before = jax.tree_util.tree_map(np.asarray, state)
    action = np.zeros(batched.action_size, np.float32)
    step = jax.jit(batched.step)
    one, two = step(state, action), step(state, action)
    jax.tree_util.tree_map(np.testing.assert_array_equal, one, two)
    jax.tree_util.tree_map(np.testing.assert_array_equal, before, state)
    with pytest.raises(AttributeError):
        state.reward = 1.0
