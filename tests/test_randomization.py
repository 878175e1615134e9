"""Domain randomisation: each world of a batch simulates its own physics, drawn once, through
MuJoCo Playground's own wrapper (every family) and through ``gym.make_vec(...,
randomize=...)``.

Brax's PPO training with the randomiser is in ``tests/test_brax_dropin.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("mujoco_playground")
import gymnasium as gym  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from mujoco_playground import wrapper  # noqa: E402

import auv_envs.batched  # noqa: E402
from auv_envs.core.vehicle import PlantPerturbation  # noqa: E402
from auv_envs.tasks.acoustic.randomization import AcousticRandomization  # noqa: E402
from auv_envs.tasks.docking.randomization import PHYSICS, DockingRandomization  # noqa: E402
from auv_envs.tasks.lars.randomization import LARSRandomization  # noqa: E402
from tests.conftest import JAX_TASKS as SHELLS  # noqa: E402

WORLDS, STEPS = 3, 12


def nominal(randomization):
    """``randomization`` with every range zero: it draws the nominal world."""
    return dataclasses.replace(randomization, **{
        field.name: PlantPerturbation() if isinstance(getattr(randomization, field.name),
                                                      PlantPerturbation) else 0.0
        for field in dataclasses.fields(randomization)})


def rollout(env, randomization_fn=None):
    """``STEPS`` steps of ``WORLDS`` environments that start alike (one key) under one
    constant action, through Playground's training wrapper; the observations
    (WORLDS, STEPS, n)."""
    wrapped = wrapper.wrap_for_brax_training(env, episode_length=1000,
                                             randomization_fn=randomization_fn)
    state = jax.jit(wrapped.reset)(jnp.stack([jax.random.PRNGKey(5)] * WORLDS))
    step = jax.jit(wrapped.step)
    action = jnp.tile(jnp.linspace(1.0, -0.5, env.action_size), (WORLDS, 1))
    out = []
    for _ in range(STEPS):
        state = step(state, action)
        out.append(np.asarray(state.obs))
    return np.stack(out, axis=1)


@pytest.fixture(scope="module")
def docking():
    return auv_envs.batched.load("auv_envs/DockingStation-v2", obs_mode="state")


@pytest.mark.parametrize("env_id", SHELLS)
def test_playgrounds_wrapper_gives_each_world_its_own_physics(env_id):
    """World 0 drawn by the shipped randomiser with its ranges zero (the nominal world),
    worlds 1 and 2 by the shipped one: the first follows the env without randomisation,
    the others, from the same start under the same commands, go elsewhere."""
    env = auv_envs.batched.load(env_id, obs_mode="state")
    keys = jax.random.split(jax.random.PRNGKey(0), WORLDS)

    def randomize(model, rng):
        still, in_axes = nominal(env.randomization)(model, rng)
        drawn, _ = env.randomize(model, rng)
        # The drawn fields (batched) from the nominal draw in world 0; the shared as they are.
        return jax.tree.map(lambda a, b: a if a is b else jnp.concatenate([a[:1], b[1:]]),
                            still, drawn), in_axes

    plain = rollout(env)
    randomized = rollout(env, functools.partial(randomize, rng=keys))
    np.testing.assert_array_equal(plain[0], plain[1])  # no randomiser: the worlds alike
    np.testing.assert_allclose(randomized[0], plain[0], rtol=1e-5, atol=1e-5)
    for k in (1, 2):
        assert np.abs(randomized[k] - plain[k]).max() > 1e-3
    assert np.abs(randomized[1] - randomized[2]).max() > 1e-3
    assert env.mjx_model.physics is None  # back in the nominal world


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
    with pytest.raises(ValueError, match="servo"):
        AcousticRandomization(servo=0.95)
    with pytest.raises(ValueError, match="link_mass"):
        LARSRandomization(link_mass=math.nan)
