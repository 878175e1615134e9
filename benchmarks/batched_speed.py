"""Batched docking plant on MJX against the CPU plant, in the same run.

The MJX plant (:class:`auv_envs.batched.docking.DockingPlantMJX`) steps a batch
of vehicles one control period (0.1 s, RK4 with the hull wrench at every
stage) per compiled call; the reference is the CPU environment's plant, the
same physics through MuJoCo's ``mj_step`` with the passive-force callback, one
vehicle at a time. Both are timed here, so their ratio compares them on this
machine. This is the plant alone: the batched environment's observations,
rewards and episode logic are not built yet, so this is not issue 21's
``features`` target (batched env >= 3x ``SyncVectorEnv``).

    python benchmarks/batched_speed.py [--batches 1 64 256 1024 4096] [--steps 50]

Runs unchanged on a GPU (JAX picks it): ``pip install -e ".[jax]"`` with a
CUDA build of jaxlib.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import jax
import jax.numpy as jnp

import auv_envs  # noqa: F401
from auv_envs.batched.docking import DockingPlantMJX
from auv_envs.core import passive


def cpu_plant_rate(env, steps: int, repeats: int) -> float:
    """Control periods per second of the CPU plant (one vehicle, thrust held)."""
    physics, hull = env.physics, env.hull
    hull.command((20.0, 5.0, -3.0, 0.0, 0.0, 2.0), (0.1, 0.0, 0.0))
    best = 0.0
    for _ in range(repeats):
        env.reset(seed=0)
        start = time.perf_counter()
        for _ in range(steps):
            passive.step(physics.model, physics.data, hull.passive_force, 1)
        best = max(best, steps / (time.perf_counter() - start))
    return best


def mjx_plant_rate(plant: DockingPlantMJX, env, batch: int, steps: int, repeats: int) -> float:
    """Vehicle control periods per second of the MJX plant at ``batch`` vehicles."""
    env.reset(seed=0)
    qpos = jnp.tile(jnp.asarray(env.physics.data.qpos, jnp.float32), (batch, 1))
    qvel = jnp.zeros((batch, 6), jnp.float32)
    tau = jnp.tile(jnp.array([20.0, 5.0, -3.0, 0.0, 0.0, 2.0], jnp.float32), (batch, 1))
    current = jnp.tile(jnp.array([0.1, 0.0, 0.0], jnp.float32), (batch, 1))
    jax.block_until_ready(plant.step(qpos, qvel, tau, current))  # compile
    best = 0.0
    for _ in range(repeats):
        q, v = qpos, qvel
        start = time.perf_counter()
        for _ in range(steps):
            q, v = plant.step(q, v, tau, current)
        jax.block_until_ready(q)
        best = max(best, batch * steps / (time.perf_counter() - start))
    return best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 256, 1024, 4096])
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    env = gym.make("auv_envs/DockingStation-v1").unwrapped
    plant = DockingPlantMJX(env)
    print(f"JAX backend: {jax.default_backend()} ({jax.devices()[0]})")
    print("| batch | MJX plant vehicle-steps/s | CPU plant steps/s (same run) | ratio |")
    print("|---|---|---|---|")
    for batch in args.batches:
        rate = mjx_plant_rate(plant, env, batch, args.steps, args.repeats)
        reference = cpu_plant_rate(env, max(200, args.steps * 4), args.repeats)
        print(f"| {batch} | {rate:,.0f} | {reference:,.0f} | {rate / reference:.2f} |")
    env.close()


if __name__ == "__main__":
    main()
