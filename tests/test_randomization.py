"""Domain randomisation: each world of a batch simulates its own physics, drawn once, through
MuJoCo Playground's own wrapper and through ``gym.make_vec(..., randomize=...)``.

Brax's PPO training with the randomiser is in ``tests/test_brax_dropin.py``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("mujoco_playground")
import gymnasium as gym  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from mujoco_playground import wrapper  # noqa: E402

import auv_envs.batched  # noqa: E402
from auv_envs.core.vehicle import PlantPerturbation  # noqa: E402
from auv_envs.tasks.docking.randomization import PHYSICS, DockingRandomization  # noqa: E402

WORLDS, STEPS = 3, 12
#: A randomiser whose every range is zero: it draws the nominal world.
NOMINAL = DockingRandomization(vehicle=PlantPerturbation(), thrust=0.0, current=0.0)


def rollout(env, randomization_fn=None):
    """``STEPS`` full-surge steps of ``WORLDS`` environments that start alike (one key),
    through Playground's training wrapper; the observations (WORLDS, STEPS, n)."""
    wrapped = wrapper.wrap_for_brax_training(env, episode_length=1000,
                                             randomization_fn=randomization_fn)
    state = jax.jit(wrapped.reset)(jnp.stack([jax.random.PRNGKey(5)] * WORLDS))
    step = jax.jit(wrapped.step)
    action = jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.3]), (WORLDS, 1))
    out = []
    for _ in range(STEPS):
        state = step(state, action)
        out.append(np.asarray(state.obs))
    return np.stack(out, axis=1)


@pytest.fixture(scope="module")
def docking():
    return auv_envs.batched.load("auv_envs/DockingStation-v2", obs_mode="state")


def test_playgrounds_wrapper_gives_each_world_its_own_physics(docking):
    keys = jax.random.split(jax.random.PRNGKey(0), WORLDS)
    plain = rollout(docking)
    randomized = rollout(docking, functools.partial(docking.randomize, rng=keys))
    nominal = rollout(docking, functools.partial(NOMINAL, rng=keys))
    # Without a randomiser the worlds are alike; the nominal randomiser changes nothing.
    np.testing.assert_array_equal(plain[0], plain[1])
    np.testing.assert_allclose(nominal, plain, atol=1e-6)
    # Randomised, the same start and the same commands end in different places.
    position = randomized[:, -1, :3]
    assert np.linalg.norm(position[0] - position[1]) > 1e-3
    assert np.linalg.norm(position[1] - position[2]) > 1e-3
    assert np.abs(randomized[:, 0] - plain[:, 0]).max() > 0.0
    # The env is back in the nominal world after the wrapper's calls.
    assert docking.mjx_model.physics is None


def test_the_shipped_ranges_are_drawn_uniformly_per_world(docking):
    worlds, in_axes = docking.randomize(docking.mjx_model,
                                        jax.random.split(jax.random.PRNGKey(1), 400))
    physics = {name: np.asarray(value) for name, value in worlds.physics.items()}
    assert set(physics) == set(PHYSICS) and in_axes.mjx is None
    shipped = DockingRandomization()
    assert shipped.vehicle.mass == 0.1 and shipped.thrust == 0.15
    for name, half in (("mass_scale", 0.1), ("thrust_scale", 0.15)):
        assert physics[name].shape == (400,)
        assert np.all(np.abs(physics[name] - 1.0) <= half)
        assert np.ptp(physics[name]) > 1.5 * half  # spread over the range
    assert physics["damping_scale"].shape == (400, 12)
    assert np.all(np.abs(physics["damping_scale"] - 1.0) <= 0.3)
    assert np.all(np.abs(physics["buoyancy_offset"]) <= 5.0)
    speed = np.linalg.norm(physics["current"], axis=1)
    assert np.all(speed <= 0.1 + 1e-6) and np.all(physics["current"][:, 2] == 0.0)
    assert speed.max() > 0.08


def test_make_vec_draws_its_worlds_from_the_reset_seed():
    envs = gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs=2, obs_mode="state",
                        randomize=True)
    plain = gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs=2, obs_mode="state")
    first, _ = envs.reset(seed=3)
    thrust = np.asarray(envs.worlds.physics["thrust_scale"])
    assert thrust[0] != thrust[1]
    envs.reset(seed=3)
    np.testing.assert_array_equal(np.asarray(envs.worlds.physics["thrust_scale"]), thrust)
    envs.reset(seed=4)
    assert not np.array_equal(np.asarray(envs.worlds.physics["thrust_scale"]), thrust)
    # The episodes' own draws are the seed's, as without randomisation.
    np.testing.assert_array_equal(first, plain.reset(seed=3)[0])
    assert plain.worlds is None
    envs.reset(seed=3)
    actions = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)).astype(np.float32)
    for _ in range(10):
        obs, *_ = envs.step(actions)
        plain_obs, *_ = plain.step(actions)
    assert np.abs(obs - plain_obs).max() > 1e-3


def test_randomisation_refuses_bad_input():
    with pytest.raises(ValueError, match="thrust"):
        DockingRandomization(thrust=1.5)
    with pytest.raises(ValueError, match="current"):
        DockingRandomization(current=-0.1)
    with pytest.raises(TypeError, match="PlantPerturbation"):
        DockingRandomization(vehicle=0.1)
    with pytest.raises(TypeError, match="randomize"):
        gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs=2, randomize="yes")
    with pytest.raises(TypeError, match="DockingRandomization"):
        auv_envs.batched.load("auv_envs/DockingStation-v2", randomization={"thrust": 0.1})
