"""The batched environments (and the docking plant) on MJX against the CPU ones, in the same run.

Two tables, each with its reference timed in the same run, so the ratios
compare them on this machine:

* **environment**: ``features`` (acoustic: ``measurements``) env-steps per second of a
  family's batched JAX environment (:class:`auv_envs.batched.functional.FunctionalEnv`
  with the family's JAX task: ``--family docking``, ``lars`` or ``acoustic``) against its CPU
  environment through Gymnasium's ``SyncVectorEnv`` of 8 (target:
  >= 10x at the best batch size). Two ways to drive the batch: through
  ``gym.make_vec`` of the batched id (NumPy in and out every step, as a Python
  learner uses it) and fused, ``steps`` steps in one compiled ``jax.lax.scan``
  (as a compiled learner uses it). The action is held (docking: surge 0.3;
  LARS: shoulder 0.3, elbow -0.2 of the torque limits; acoustic: the estimate at the
  tank's centre); episodes that end reset themselves.
* **plant**: the batched docking plant
  (:class:`auv_envs.tasks.docking.mjx_plant.DockingPlantMJX`,
  :func:`auv_envs.core.plant.hull_advance` on JAX since ``-v2``) one control period
  (0.1 s, RK4 with the hull wrench at every stage) per compiled call against MuJoCo's
  staged RK4 with the hull wrench at every stage (``env.integrator``, the ``-v1`` plant),
  one vehicle at a time.

    python benchmarks/batched_speed.py [--family docking|lars|acoustic]
        [--batches 1 64 256 1024 4096]
        [--steps 50] [--difficulty easy|paper|hard]

Runs unchanged on a GPU (JAX picks it): ``pip install -e ".[jax]"`` with a
CUDA build of jaxlib.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

import auv_envs  # noqa: F401
from auv_envs.batched.functional import FunctionalEnv
from auv_envs.core.difficulty import LEVELS
from auv_envs.tasks.docking.mjx_plant import DockingPlantMJX

ENV_ID = "auv_envs/DockingStation-v2"
#: Per family: the CPU id, the batched id, the held action, the observation mode timed.
FAMILIES = {
    "docking": (ENV_ID, "auv_envs/DockingStationMJX-v2", (0.3, 0.0, 0.0, 0.0), "features"),
    "lars": ("auv_envs/LARSCapture-v0", "auv_envs/LARSCaptureMJX-v0", (0.0, 0.3, -0.2),
             "features"),
    "acoustic": ("auv_envs/AcousticTracking-v2", "auv_envs/AcousticTrackingMJX-v2",
                 (150.0, 150.0, -15.0), "measurements"),
}
FAMILY = "docking"


def vector_rate(envs, steps: int, repeats: int) -> float:
    """Env-steps per second of a ``VectorEnv`` under the held action (best of ``repeats``)."""
    actions = np.tile(np.array(FAMILIES[FAMILY][2], np.float32), (envs.num_envs, 1))
    envs.reset(seed=0)
    envs.step(actions)  # compiles a JAX env
    best = 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            envs.step(actions)
        best = max(best, envs.num_envs * steps / (time.perf_counter() - start))
    envs.close()
    return best


def sync_vector_rate(num_envs: int, steps: int, repeats: int, difficulty: str = "easy") -> float:
    """Env-steps per second of the CPU env through ``SyncVectorEnv``."""
    return vector_rate(gym.make_vec(FAMILIES[FAMILY][0], num_envs=num_envs,
                                    vectorization_mode="sync", obs_mode=FAMILIES[FAMILY][3],
                                    difficulty=difficulty), steps, repeats)


def make_vec_rate(batch: int, steps: int, repeats: int, difficulty: str = "easy") -> float:
    """Env-steps per second through ``gym.make_vec`` (NumPy every step)."""
    return vector_rate(gym.make_vec(FAMILIES[FAMILY][1], num_envs=batch,
                                    obs_mode=FAMILIES[FAMILY][3], difficulty=difficulty),
                       steps, repeats)


def fused_rate(env, batch: int, steps: int, repeats: int) -> float:
    """Env-steps per second, ``steps`` steps fused in one compiled scan."""
    action = jnp.tile(jnp.asarray(FAMILIES[FAMILY][2], jnp.float32), (batch, 1))
    step = env.step_batch

    @jax.jit
    def rollout(state):
        return jax.lax.scan(lambda s, _: (step(s, action), None), state, None, length=steps)[0]

    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))
    jax.block_until_ready(rollout(state))  # compile
    best = 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        state = jax.block_until_ready(rollout(state))
        best = max(best, batch * steps / (time.perf_counter() - start))
    return best


def cpu_plant_rate(env, steps: int, repeats: int) -> float:
    """Control periods per second of the CPU plant (one vehicle, thrust held)."""
    hull = env.hull
    hull.command((20.0, 5.0, -3.0, 0.0, 0.0, 2.0), (0.1, 0.0, 0.0))
    best = 0.0
    for _ in range(repeats):
        env.reset(seed=0)
        start = time.perf_counter()
        for _ in range(steps):
            env.integrator.step(1)
        best = max(best, steps / (time.perf_counter() - start))
    return best


def batched_plant_rate(plant: DockingPlantMJX, env, batch: int, steps: int, repeats: int) -> float:
    """Vehicle control periods per second of the batched plant at ``batch`` vehicles."""
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
    parser.add_argument("--family", default="docking", choices=tuple(FAMILIES))
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 256, 1024, 4096])
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-plant", action="store_true", help="skip the plant table")
    parser.add_argument("--difficulty", default="easy", choices=LEVELS,
                        help="the level of the environment table (the plant has none)")
    args = parser.parse_args(argv)
    global FAMILY
    FAMILY = args.family
    print(f"JAX backend: {jax.default_backend()} ({jax.devices()[0]})")
    print(f"family: {FAMILY}, level: {args.difficulty}")
    batched = FunctionalEnv(FAMILIES[FAMILY][0], obs_mode=FAMILIES[FAMILY][3],
                            difficulty=args.difficulty)
    print("\n| batch | make_vec env-steps/s | fused scan env-steps/s | SyncVectorEnv env-steps/s "
          "(same run) | ratio make_vec | ratio fused |")
    print("|---|---|---|---|---|---|")
    for batch in args.batches:
        via_numpy = make_vec_rate(batch, args.steps, args.repeats, args.difficulty)
        fused = fused_rate(batched, batch, args.steps, args.repeats)
        reference = sync_vector_rate(8, max(50, args.steps * 2), args.repeats, args.difficulty)
        print(f"| {batch} | {via_numpy:,.0f} | {fused:,.0f} | {reference:,.0f} | "
              f"{via_numpy / reference:.2f} | {fused / reference:.2f} |", flush=True)
    if args.no_plant or FAMILY != "docking":
        return
    env = gym.make(ENV_ID).unwrapped
    plant = DockingPlantMJX(env.setup)
    print()
    print("| batch | batched plant vehicle-steps/s | CPU staged plant steps/s (same run) "
          "| ratio |")
    print("|---|---|---|---|")
    for batch in args.batches:
        rate = batched_plant_rate(plant, env, batch, args.steps, args.repeats)
        reference = cpu_plant_rate(env, max(200, args.steps * 4), args.repeats)
        print(f"| {batch} | {rate:,.0f} | {reference:,.0f} | {rate / reference:.2f} |")
    env.close()


if __name__ == "__main__":
    main()
