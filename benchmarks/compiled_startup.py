"""Where the compiled PPO's start-up time goes, part by part.

Builds the batched environment of ``--env`` (``DockingStation-v2`` by default) and a
:class:`baselines.rl.compiled.Trainer` as ``cppo.yml``'s recipe for it sets them up
(observation mode, front end, settings; the docking recipe is the default settings at
``paper``), then times
(seconds, wall clock): building the environment, the first reset, tracing and
compiling one iteration, running it twice, and compiling and running the
batched evaluation. With ``--compilation-cache DIR`` JAX's persistent cache
is used: run it twice with the same directory to see a warm start.

    python benchmarks/compiled_startup.py [--env AcousticTracking-v2] [--compilation-cache DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="DockingStation-v2", help="an id cppo trains")
    parser.add_argument("--compilation-cache", type=Path, metavar="DIR")
    args = parser.parse_args(argv)
    from baselines.rl.compiled import Settings, Trainer, make_env, use_compilation_cache
    from baselines.rl.config import resolve_config

    if args.compilation_cache is not None:
        use_compilation_cache(args.compilation_cache)
    env_id = args.env if "/" in args.env else f"auv_envs/{args.env}"
    recipe = resolve_config("cppo", env_id, 0)
    settings = Settings(**recipe.hyperparams)

    rows = []
    clock = [time.perf_counter()]

    def lap(label: str) -> None:
        now = time.perf_counter()
        rows.append((label, now - clock[0]))
        clock[0] = now

    start = clock[0]
    run = recipe.run
    env = make_env(env_id, run["obs_mode"], run["env_kwargs"], run["marker_track"],
                   run["detection_fixes"])
    trainer = Trainer(env, settings, 100)
    lap("build the batched env and trainer")
    state = jax.block_until_ready(trainer.init(jax.random.PRNGKey(0)))
    lap(f"first reset of {settings.num_envs} envs")
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
    print(f"{env_id}; device: {jax.devices()[0]}; cache: {args.compilation_cache or 'none'}\n")
    print("| part | s |\n|---|---|")
    for label, seconds in rows:
        print(f"| {label} | {seconds:.1f} |")
    print(f"| all | {time.perf_counter() - start:.1f} |")


if __name__ == "__main__":
    main()
