"""The batched auto-reset per env-step against once per batch, alternately in one process.

``jax.vmap(env.step)`` computes a reset for every environment at every step (selected
away where no episode ended); :meth:`auv_envs.batched.functional.FunctionalEnv.step_batch`
resets the batch only on a step where an episode ended. Prints the env-steps per second
of a fused rollout of ``--steps`` steps under each (best of ``--repeats``, alternating)
and how many episodes ended in the rollout (held actions as in
``benchmarks/batched_speed.py``).

    python benchmarks/batched_reset.py [--family acoustic|lars|docking] [--batch 256]
        [--steps 20] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from batched_speed import FAMILIES  # noqa: E402  (the same envs and held actions)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--family", default="acoustic", choices=tuple(FAMILIES))
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    _, _, make, held, obs_mode = FAMILIES[args.family]
    env = make(obs_mode=obs_mode)
    action = jnp.tile(jnp.asarray(held, jnp.float32), (args.batch, 1))
    start = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), args.batch))

    def rollout_of(step):
        def body(state, _):
            state = step(state, action)
            return state, jnp.sum(state.done)
        return jax.jit(lambda state: jax.lax.scan(body, state, None, length=args.steps))

    rollouts = {"jax.vmap(step)": rollout_of(jax.vmap(env.step)),
                "step_batch": rollout_of(env.step_batch)}
    ended = {name: int(jax.block_until_ready(run(start))[1].sum())
             for name, run in rollouts.items()}  # compiles
    best = dict.fromkeys(rollouts, 0.0)
    for _ in range(args.repeats):
        for name, run in rollouts.items():
            t0 = time.perf_counter()
            jax.block_until_ready(run(start))
            best[name] = max(best[name], args.batch * args.steps / (time.perf_counter() - t0))
    print(f"{args.family} {obs_mode}, batch {args.batch}, {args.steps} steps "
          f"({jax.devices()[0]}); episodes ended in the rollout: {ended}")
    for name, rate in best.items():
        print(f"  {name}: {rate:,.0f} env-steps/s")
    print(f"  ratio step_batch / vmap(step): {best['step_batch'] / best['jax.vmap(step)']:.2f}")


if __name__ == "__main__":
    main()
