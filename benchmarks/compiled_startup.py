"""Where the compiled PPO's start-up time goes, part by part.

Builds the batched ``DockingStation-v2`` environment at ``paper`` and a
:class:`baselines.rl.compiled.Trainer` with the default settings, then times
(seconds, wall clock): building the environment, the first reset, tracing and
compiling one iteration, running it twice, and compiling and running the
batched evaluation. With ``--compilation-cache DIR`` JAX's persistent cache
is used: run it twice with the same directory to see a warm start.

    python benchmarks/compiled_startup.py [--compilation-cache DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--compilation-cache", type=Path, metavar="DIR")
    args = parser.parse_args(argv)
    from baselines.rl.compiled import DEFAULT_SETTINGS, Trainer, use_compilation_cache

    if args.compilation_cache is not None:
        use_compilation_cache(args.compilation_cache)
    from auv_envs.batched.docking_env import DockingMJX

    rows = []
    clock = [time.perf_counter()]

    def lap(label: str) -> None:
        now = time.perf_counter()
        rows.append((label, now - clock[0]))
        clock[0] = now

    start = clock[0]
    env = DockingMJX("auv_envs/DockingStation-v2", obs_mode="features", difficulty="paper")
    trainer = Trainer(env, DEFAULT_SETTINGS, 100)
    lap("build the batched env and trainer")
    state = jax.block_until_ready(trainer.init(jax.random.PRNGKey(0)))
    lap(f"first reset of {DEFAULT_SETTINGS.num_envs} envs")
    lowered = trainer.iteration.lower(*state)
    lap("trace one iteration")
    iteration = lowered.compile()
    lap("compile it")
    out = jax.block_until_ready(iteration(*state))
    lap("run it (first)")
    out = jax.block_until_ready(iteration(*out[:5]))
    lap("run it (second)")
    jax.block_until_ready(trainer.evaluate(out[0], out[2], 64, env.max_episode_steps))
    lap("trace, compile and run the evaluation")
    jax.block_until_ready(trainer.evaluate(out[0], out[2], 64, env.max_episode_steps))
    lap("run the evaluation again")
    print(f"device: {jax.devices()[0]}; cache: {args.compilation_cache or 'none'}\n")
    print("| part | s |\n|---|---|")
    for label, seconds in rows:
        print(f"| {label} | {seconds:.1f} |")
    print(f"| all | {time.perf_counter() - start:.1f} |")


if __name__ == "__main__":
    main()
