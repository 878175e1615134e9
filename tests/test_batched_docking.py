"""The docking plant on MJX (auv_envs.tasks.docking.mjx_plant) against the CPU environment's plant.

Skipped without JAX and MuJoCo MJX (the ``jax`` extra; ``.[test]`` includes it).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

import jax.numpy as jnp  # noqa: E402

import auv_envs  # noqa: E402, F401
from auv_envs.tasks.docking.mjx_plant import DockingPlantMJX  # noqa: E402
from baselines.registry import make_agent  # noqa: E402

SECONDS = 20.0
_PLANTS: dict = {}


def _plant(env) -> DockingPlantMJX:
    """One compiled plant per environment id (compiling costs seconds; the model of an id
    is fixed)."""
    key = env.spec.id
    if key not in _PLANTS:
        _PLANTS[key] = DockingPlantMJX(env.setup)
    return _PLANTS[key]


def _cpu_episode(env_id: str, seed: int, **kwargs):
    """The pd-state agent for 20 s on the CPU env: start state, per-step (tau, current)
    and the hull's qpos/qvel after each step."""
    env = gym.make(env_id, obs_mode="state", **kwargs)
    u = env.unwrapped
    agent = make_agent("pd-state", env)
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    start = (u.physics.data.qpos.copy(), u.physics.data.qvel.copy())
    limits = np.array(u.vehicle.thrust_limits)
    inputs, states = [], []
    for _ in range(round(SECONDS / u.dt)):
        action = np.clip(agent.act(obs, info), -1.0, 1.0)
        obs, _, terminated, truncated, info = env.step(action)
        x, y, z, n = action * limits
        inputs.append((np.array([x, y, z, 0.0, 0.0, n]), info["current"]))
        states.append((u.physics.data.qpos.copy(), u.physics.data.qvel.copy()))
        if terminated or truncated:
            break
    return u, start, inputs, states


@pytest.mark.parametrize("env_id, kwargs", [
    ("auv_envs/DockingStation-v2", {"scenario": "current", "current_direction": 60.0}),
    ("auv_envs/LampArrayDocking-v2", {}),
])
def test_float32_plant_follows_the_cpu_plant_for_20_s(env_id, kwargs):
    """Same start, same forces and current: positions within 1 cm (the target is 1 cm
    in float32 over 20 s; the two agree to micrometres)."""
    env, (qpos, qvel), inputs, states = _cpu_episode(env_id, seed=4, **kwargs)
    plant = _plant(env)
    q, v = jnp.asarray(qpos[None], jnp.float32), jnp.asarray(qvel[None], jnp.float32)
    assert q.dtype == jnp.float32
    errors = []
    for (tau, current), (cpu_qpos, _) in zip(inputs, states, strict=True):
        q, v = plant.step(q, v, jnp.asarray(tau[None], jnp.float32),
                          jnp.asarray(current[None], jnp.float32))
        errors.append(np.linalg.norm(np.asarray(q[0, :3]) - cpu_qpos[:3]))
    assert len(errors) == round(SECONDS / env.dt)  # the whole 20 s, no early end
    assert max(errors) < 0.01
    np.testing.assert_allclose(np.asarray(v[0]), states[-1][1], atol=1e-3)
    moved = np.linalg.norm(states[-1][0][:3] - qpos[:3])
    assert moved > 1.0  # the vehicle travelled: the comparison is not of a body at rest
    env.close()


def test_a_batch_steps_each_vehicle_as_alone():
    env = gym.make("auv_envs/DockingStation-v2").unwrapped
    plant = _plant(env)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    base = env.physics.data.qpos.copy()
    qpos = np.tile(base, (3, 1))
    qpos[:, :3] += rng.normal(size=(3, 3))
    quat = rng.normal(size=(3, 4))
    qpos[:, 3:] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    qvel = rng.normal(size=(3, 6)) * 0.2
    tau = rng.normal(size=(3, 6)) * 30.0
    current = rng.normal(size=(3, 3)) * 0.2
    batch = plant.step(*(jnp.asarray(a, jnp.float32) for a in (qpos, qvel, tau, current)))
    for k in range(3):
        one = plant.step(*(jnp.asarray(a[k:k + 1], jnp.float32)
                           for a in (qpos, qvel, tau, current)))
        for got, alone in zip(batch, one, strict=True):
            np.testing.assert_allclose(np.asarray(got[k]), np.asarray(alone[0]), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(batch[0][:, 3:]), axis=1), 1.0,
                               atol=1e-6)
    env.close()


def test_the_euler_plant_is_refused():
    env = gym.make("auv_envs/DockingStation-v0").unwrapped
    with pytest.raises(ValueError, match="rk4"):
        DockingPlantMJX(env.setup)
    env.close()
