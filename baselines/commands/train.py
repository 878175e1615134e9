"""Train a Stable-Baselines3 agent on an ``auv_envs`` environment.

    python train.py --algo ppo --env DockingStation-v2 [--obs-mode state] [--seed 0]
                    [--n-envs N] [--n-timesteps N] [--set KEY=VALUE ...]
                    [--run-dir DIR] [--no-progress-bar] [--export-policy NAME]
    python train.py --resume RUN_DIR [--n-timesteps N] [--set learning_rate=VALUE]
    python train.py --export RUN_DIR --export-policy NAME
    python train.py --algo ppo --env DockingStation-v2 --sweep-dir DIR --seeds 0 1 2
                    [--grid KEY=V1,V2 ...] [--ray-address ADDR] [--cpus-per-run N]

Hyperparameters come from ``baselines/rl/hyperparams/<algo>.yml`` (the env's
entry over ``default``); ``--set`` overrides any key (dotted keys reach into
mappings, e.g. ``--set policy_kwargs.net_arch=[64,64]``). Ctrl-C or SIGTERM
writes a checkpoint at the next safe point and exits with 128 + the signal
number; ``--resume`` continues exactly where it stopped. ``--export-policy``
copies the finished run to ``assets/policies/NAME`` as a registered agent.
See :mod:`baselines.rl.training` for the run directory layout.

Every hyperparameter is checked against its range before anything is built
(:data:`baselines.rl.config.RANGES`): a bad value exits with 2 and a message
naming the key, the value and the range. A run whose parameters or losses
become non-finite stops at once, keeps its last good checkpoint and exits with
3; ``--resume RUN_DIR --set learning_rate=...`` continues from that checkpoint
with a smaller learning rate (``--resume`` may change only
:data:`baselines.rl.config.RESUMABLE`).

``--algo cppo`` is PPO compiled in JAX on the batched envs of every family
(:mod:`baselines.rl.compiled`, ``pip install -e ".[jax]"``), from
``cppo.yml``: the same run directory, minutes instead of tens of minutes.
Ctrl-C writes its policy so far; it cannot be resumed (the same seed trains
the same policy again). ``--n-envs`` sets its batch (``num_envs``); ``--devices N``
splits it over N local devices (default: all that split it evenly).

``--sweep-dir DIR`` trains every seed of ``--seeds`` with every combination of the
``--grid`` values as Ray tasks, each run a run directory ``DIR/<run>``, with a summary
table at the end; the same command again continues an unfinished sweep
(:mod:`baselines.rl.sweep`, ``pip install -e ".[ray]"``).
"""

from __future__ import annotations

import argparse
import contextlib
import shlex
import sys
from pathlib import Path

from auv_envs.extras import one_line_errors, require
from baselines.rl.checkpoint import CheckpointError
from baselines.rl.config import (
    COMPILED,
    TRAIN_EVAL_SEED_BASE,
    TRAINERS,
    ConfigError,
    TrainConfig,
    algo_arguments,
    parse_overrides,
    read_config,
    resolve_config,
    schedule_initial_value,
)

#: The exit status of a run that diverged (2: a usage error, 128 + n: stopped by signal n).
DIVERGED = 3


def _env_id(name: str) -> str:
    return name if "/" in name else f"auv_envs/{name}"


def _default_run_dir(algo: str, env_id: str, obs_mode: str, seed: int) -> Path:
    base = Path("runs") / f"{algo}-{env_id.split('/')[-1]}-{obs_mode}-s{seed}"
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}-{n}")
    return path


def parse_args(argv=None, prog: str | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", choices=sorted(TRAINERS))
    parser.add_argument("--env", help="environment id (the auv_envs/ prefix is optional)")
    parser.add_argument("--obs-mode", help="observation mode (default: from the YAML file)")
    parser.add_argument("--seed", type=int, default=0,
                        help=f"training seed (training seeds stay below {TRAIN_EVAL_SEED_BASE})")
    parser.add_argument("--n-envs", type=int, help="parallel environments (DummyVecEnv)")
    parser.add_argument("--n-timesteps", type=int, help="training budget in env steps")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="override a hyperparameter (repeatable); "
                        "with --resume alone: learning_rate, max_grad_norm, clip_range")
    parser.add_argument("--hyperparams-dir", type=Path, help="directory of <algo>.yml files")
    parser.add_argument("--run-dir", type=Path, help="default: runs/<algo>-<env>-<mode>-s<seed>")
    parser.add_argument("--resume", type=Path, metavar="RUN_DIR",
                        help="continue RUN_DIR from its latest checkpoint")
    parser.add_argument("--export", type=Path, metavar="RUN_DIR",
                        help="only export the finished RUN_DIR (with --export-policy)")
    parser.add_argument("--export-policy", metavar="NAME",
                        help="after training, ship the policy as assets/policies/NAME")
    parser.add_argument("--export-group", metavar="GROUP",
                        help="with --export-policy: the agent this policy is a training seed of "
                             "(the leaderboard pools a group's seeds into one row)")
    parser.add_argument("--policies-dir", type=Path, help="default: assets/policies")
    parser.add_argument("--no-progress-bar", action="store_true")
    parser.add_argument("--compilation-cache", type=Path, metavar="DIR",
                        help="cppo: JAX's persistent compilation cache; a later run of "
                             "the same shapes loads its programs instead of compiling them "
                             "(default: ~/.cache/auv_envs/jax/<host> on a GPU or TPU, none on the "
                             "CPU, where jaxlib can crash loading a large program)")
    parser.add_argument("--no-compilation-cache", action="store_true",
                        help="cppo: compile everything afresh, write no cache")
    sweep = parser.add_argument_group("sweeps (Ray)")
    sweep.add_argument("--sweep-dir", type=Path, metavar="DIR",
                       help="train --seeds x --grid as a sweep of runs, DIR/<run> each")
    sweep.add_argument("--seeds", type=int, nargs="+", metavar="SEED",
                       help="the sweep's training seeds")
    sweep.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2",
                       help="a setting the sweep varies (repeatable: every combination)")
    sweep.add_argument("--ray-address", metavar="ADDR",
                       help="the sweep's Ray cluster (default: a local Ray for the sweep)")
    sweep.add_argument("--cpus-per-run", type=float, default=1.0, metavar="N",
                       help="CPUs Ray reserves for each run of the sweep (default 1)")
    parser.add_argument("--devices", type=int, metavar="N",
                        help="cppo: split the environments over the first N local devices "
                             "(GPUs, TPU cores; default: all that split the batch evenly)")
    args = parser.parse_args(argv)
    if args.export is None and args.resume is None and (args.algo is None or args.env is None):
        parser.error("--algo and --env are required (unless --resume or --export)")
    if args.export is not None and args.export_policy is None:
        parser.error("--export needs --export-policy NAME")
    if args.sweep_dir is None:
        for name in ("seeds", "grid", "ray_address"):
            if getattr(args, name):
                parser.error(f"--{name.replace('_', '-')} belongs to a sweep (--sweep-dir)")
    else:
        if args.seeds is None:
            parser.error("--sweep-dir needs --seeds")
        for name in ("run_dir", "resume", "export", "export_policy"):
            if getattr(args, name) is not None:
                parser.error(f"--{name.replace('_', '-')} does not go with --sweep-dir")
        if "--seed" in (argv or sys.argv[1:]):
            parser.error("a sweep takes --seeds, not --seed")
        if args.cpus_per_run <= 0:
            parser.error("--cpus-per-run must be positive")
    return args


def main(argv=None, prog: str = "python train.py") -> int:
    """The command line; ``prog`` is how the user ran it (recorded in the run directory).
    A missing optional dependency is one line naming its extra."""
    with one_line_errors(prog):
        return _main(argv, prog)


def _main(argv, prog: str) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv, prog)
    command = " ".join([prog, shlex.join(argv)]).strip()
    from baselines.rl import export, training  # heavy imports after argument errors

    try:
        if args.export is not None:
            path = export.export_policy(args.export, args.export_policy, args.policies_dir,
                                        args.export_group)
            print(f"exported {args.export} -> {path}")
            return 0
        if args.sweep_dir is not None:
            return _sweep(args)
        expected = None
        if args.algo is not None and args.env is not None:
            overrides = parse_overrides(args.overrides)
            batch = "num_envs" if args.algo == COMPILED else "n_envs"
            for key, value in (("obs_mode", args.obs_mode), (batch, args.n_envs),
                               ("n_timesteps", args.n_timesteps)):
                if value is not None:
                    overrides[key] = value
            expected = resolve_config(args.algo, _env_id(args.env), args.seed, overrides,
                                      args.hyperparams_dir)
        elif args.overrides and args.resume is None:
            raise ConfigError("--set needs --algo and --env, or --resume")
        if args.devices is not None and (expected is None or expected.algo != COMPILED):
            raise ConfigError("--devices splits a new --algo cppo run's environments over "
                              "local devices; the other trainers run on one")
        progress = not args.no_progress_bar
        if args.resume is not None:
            overrides = parse_overrides(args.overrides) if expected is None else None
            result = training.resume(args.resume, command, args.n_timesteps, expected,
                                     progress_bar=progress, overrides=overrides)
        else:
            run_dir = args.run_dir or _default_run_dir(
                expected.algo, expected.env_id, expected.run["obs_mode"], expected.seed)
            print(f"run directory: {run_dir}", flush=True)
            if expected.algo == COMPILED:
                result = _train_compiled(expected, run_dir, command, args)
            else:
                result = training.train(expected, run_dir, command, progress_bar=progress)
    except (ConfigError, CheckpointError, ValueError, FileNotFoundError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except training.TrainingDiverged as exc:
        print(f"{prog}: error: {exc}{_after_divergence(exc, expected, prog)}", file=sys.stderr)
        return DIVERGED
    curve = write_curve(result.run_dir)
    if curve is None:
        print(f"no learning curve: nothing was evaluated during the run (cppo's evals: 0); "
              f"rank the policy with evaluate.py --policy {result.run_dir}")
    else:
        print(f"learning curve: {curve} (data: eval_curve.csv, train_episodes.csv)")
    if not result.finished:
        if result.checkpoint is None:  # a compiled run
            print(f"stopped by {result.stopped_by} at step {result.steps}; the policy so far "
                  f"is in {result.run_dir / 'final'}")
        else:
            print(f"stopped by {result.stopped_by} at step {result.steps}; checkpoint "
                  f"{result.checkpoint}; continue with: {prog} --resume {result.run_dir}")
        import signal

        return 128 + int(signal.Signals[result.stopped_by])
    print(f"finished {result.steps} steps in {result.wall_time_s:.0f} s: {result.run_dir}")
    if args.export_policy:
        path = export.export_policy(result.run_dir, args.export_policy, args.policies_dir,
                                    args.export_group)
        print(f"exported -> {path}")
    return 0


def _after_divergence(exc, config: TrainConfig | None, prog: str) -> str:
    """What to run next: the same run resumed (or, for ``cppo``, trained again) with a
    learning rate ten times smaller."""
    from baselines.rl.training import RunDirectory

    if exc.run_dir is not None:
        with contextlib.suppress(ConfigError):
            config = read_config(RunDirectory(exc.run_dir).config)  # what the run last used
    if config is None:
        return ""
    rate = config.hyperparams.get("learning_rate",
                                  algo_arguments(config.algo)["learning_rate"].default)
    if isinstance(rate, str):
        smaller = f"lin_{schedule_initial_value('learning_rate', rate) / 10:.1e}"
    else:
        smaller = f"{rate / 10:.1e}"
    if config.algo == COMPILED:
        return (f". A cppo run cannot be resumed: train again with a smaller learning rate "
                f"(--set learning_rate={smaller}) into another --run-dir")
    return (f" with a smaller learning rate, e.g. {prog} --resume {exc.run_dir} "
            f"--set learning_rate={smaller}")


def _train_compiled(config, run_dir: Path, command: str, args: argparse.Namespace):
    """``--algo cppo``: :func:`baselines.rl.compiled.train_run`, with JAX's compilation
    cache (``--compilation-cache``, else the default on this backend,
    :func:`auv_envs.batched.compile_cache.cache_for`) unless ``--no-compilation-cache``."""
    require("auv_envs.batched", "jax", "--algo cppo")
    from baselines.rl import compiled
    cache = None if args.no_compilation_cache else (
        args.compilation_cache or compiled.cache_for())
    return compiled.train_run(config, run_dir, command, cache, args.devices)


def _sweep(args: argparse.Namespace) -> int:
    """``--sweep-dir``: every run's config checked first, then the runs as Ray tasks
    (:mod:`baselines.rl.sweep`); 0 when every run finished."""
    from baselines.rl import sweep

    common = ["--algo", args.algo, "--env", args.env]
    for flag, value in (("--obs-mode", args.obs_mode), ("--n-envs", args.n_envs),
                        ("--n-timesteps", args.n_timesteps), ("--devices", args.devices),
                        ("--compilation-cache", args.compilation_cache)):
        if value is not None:
            common += [flag, str(value)]
    if args.no_compilation_cache:
        common.append("--no-compilation-cache")
    if args.hyperparams_dir is not None:  # relative to the working tree, which travels
        path, root = args.hyperparams_dir.resolve(), Path(__file__).resolve().parents[2]
        common += ["--hyperparams-dir",
                   str(path.relative_to(root) if path.is_relative_to(root) else path)]
    common += [arg for item in args.overrides for arg in ("--set", item)]
    runs = sweep.plan(args.seeds, sweep.parse_grid(args.grid), common)
    batch = "num_envs" if args.algo == COMPILED else "n_envs"
    for run in runs:  # a bad value stops the sweep before anything runs
        overrides = parse_overrides([*args.overrides, *(f"{k}={v}" for k, v in run.variant)])
        for key, value in ((batch, args.n_envs), ("n_timesteps", args.n_timesteps),
                           ("obs_mode", args.obs_mode)):
            if value is not None:
                overrides[key] = value
        resolve_config(args.algo, _env_id(args.env), run.seed, overrides, args.hyperparams_dir)
    print(f"sweep: {len(runs)} runs into {args.sweep_dir}", flush=True)
    rows = sweep.sweep(runs, args.sweep_dir, args.algo, args.ray_address, args.cpus_per_run)
    print(sweep.table(rows))
    failed = [row["run"] for row in rows if row["status"] != sweep.FINISHED]
    print(f"summary: {args.sweep_dir / 'summary.csv'}; "
          + (f"not finished: {', '.join(failed)}" if failed else "every run finished"))
    return 1 if failed else 0


def write_curve(run_dir: Path) -> Path | None:
    """``RUN_DIR/curve.png``: held-out success and return, and training returns, against steps
    (the data is the run's ``eval_curve.csv`` and ``train_episodes.csv``); None, and no
    file, when the run recorded neither."""
    from baselines.rl.export import plot_curve, read_csv
    from baselines.rl.training import RunDirectory

    run = RunDirectory(run_dir)
    if not (read_csv(run.eval_curve) or read_csv(run.train_episodes)):
        return None
    path = run.path / "curve.png"
    plot_curve(run, path, run.path.name)
    return path


def console() -> int:
    """The installed ``auv-train`` command."""
    return main(prog="auv-train")


if __name__ == "__main__":
    sys.exit(main())
