"""Ablations of the compiled learners on one batched task: memory or none, a privileged or
a symmetric critic, distillation or PPO from scratch, each row trained and judged alike.

Each row is a ``cppo`` recipe (``--hyperparams-dir``, default
``baselines/rl/hyperparams/memory``) with ``--set`` overrides, trained in this process by
:class:`baselines.rl.compiled.Trainer` for ``--steps`` and then run deterministically on
``--episodes`` batched episodes from one fixed key (the same episodes for every row):

    python scripts/memory_ablation.py --env DockingMission-v0 --steps 10000000 \\
        --row filter: --row none:nav_filter=false \\
        --row ppo:teacher=,n_epochs=5,learning_rate=3.0e-4 \\
        --row ppo-privileged:teacher=,privileged_critic=true,n_epochs=5,learning_rate=3.0e-4

A row is ``NAME:KEY=VALUE,KEY=VALUE`` (cppo settings; ``teacher=`` clears the recipe's
teacher, so the row learns by PPO). It prints, per row: the wall time, the training
curve's last imitation error (distillation), and for docking the success rate with its
Wilson 95 % interval, the failure codes, the hand-overs and the final distance's
percentiles; for acoustic tracking the episodes' RMSE (median and mean, with the 10th and
90th percentiles). These are batched episodes (JAX's draws), not the leaderboard's; rank
shipped agents with ``evaluate.py``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import binomtest

import auv_envs  # noqa: F401  (registers the environments)
from auv_envs.tasks.docking.rules import FAILURE_REASONS
from baselines.parsing import parse_value
from baselines.rl import compiled
from baselines.rl.config import resolve_config

DEFAULT_DIR = Path(__file__).resolve().parents[1] / "baselines" / "rl" / "hyperparams" / "memory"


def parse_row(text: str) -> tuple[str, dict]:
    """``NAME:KEY=VALUE,...`` as ``(name, overrides)``."""
    name, _, rest = text.partition(":")
    overrides = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        overrides[key] = parse_value(value) if value else ""
    return name, overrides


def train_row(env_id: str, overrides: dict, steps: int, hyperparams_dir: Path, seed: int):
    """Train one row; returns ``(trainer, params, normalizer, wall seconds, last stats)``."""
    config = resolve_config("cppo", env_id, seed, {**overrides, "n_timesteps": steps},
                            hyperparams_dir=hyperparams_dir)
    settings = compiled.Settings(**config.hyperparams)
    run = config.run
    env = compiled.make_env(env_id, run["obs_mode"], run["env_kwargs"],
                            privileged=settings.privileged_critic or bool(settings.teacher),
                            **{name: run[name] for name in compiled.BATCHED_FRONT_ENDS})
    iterations = max(1, math.ceil(steps / (settings.num_envs * settings.n_steps)))
    trainer = compiled.Trainer(env, settings, iterations)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(seed))
    start = time.perf_counter()
    stats = {}
    for i in range(iterations):
        params, opt_state, normalizer, rollout, key, stats = trainer.iteration(
            params, opt_state, normalizer, rollout, key)
        if i % max(1, iterations // 10) == 0:
            extra = (f" imitation error {float(stats['imitation_error']):.4g}"
                     if "imitation_error" in stats else "")
            print(f"  iteration {i}/{iterations}{extra} "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)
    return trainer, params, normalizer, time.perf_counter() - start, stats


def judge(trainer, params, normalizer, episodes: int) -> dict:
    """Deterministic episodes from one fixed key: each episode's summary at its end."""
    env = trainer.env
    rollout = trainer._fresh_rollout(trainer._reset(jax.random.split(jax.random.PRNGKey(99),
                                                                     episodes)))
    keys = tuple(k[len("episode_"):] for k in rollout.env.metrics if k.startswith("episode_"))

    @jax.jit
    def run(rollout):
        def act(carry, _):
            rollout, done, summary = carry
            mean, _, rollout = trainer.policy_step(params, normalizer, rollout)
            nxt = env.step_batch(rollout.env, jnp.clip(mean, -1.0, 1.0))
            ended = nxt.done & ~done
            summary = {k: jnp.where(ended, jnp.asarray(nxt.metrics[f"episode_{k}"],
                                                       jnp.float32), summary[k])
                       for k in keys}
            return (rollout._replace(env=nxt, starts=nxt.done), done | nxt.done, summary), None

        zeros = {k: jnp.full(episodes, jnp.nan) for k in keys}
        (_, done, summary), _ = jax.lax.scan(act, (rollout, jnp.zeros(episodes, bool), zeros),
                                             None, length=env.max_episode_steps)
        return done, summary

    done, summary = run(rollout)
    return {"ended": np.asarray(done), **{k: np.asarray(v) for k, v in summary.items()}}


def report(name: str, wall: float, stats: dict, result: dict) -> None:
    line = [f"{name}: {wall:.0f} s"]
    if "imitation_error" in stats:
        line.append(f"imitation error {float(stats['imitation_error']):.4g}")
    if "failure" in result:  # docking
        success = result["success"] > 0.5
        n, k = success.size, int(success.sum())
        low, high = binomtest(k, n).proportion_ci(0.95, method="wilson")
        codes = np.bincount(np.nan_to_num(result["failure"]).astype(int),
                            minlength=len(FAILURE_REASONS) + 1)
        failures = {reason: int(c) for reason, c in zip(("time_limit", *FAILURE_REASONS),
                                                         codes, strict=True) if c}
        failures["time_limit"] = failures.get("time_limit", 0) - k  # code 0: success too
        failures = {reason: c for reason, c in failures.items() if c}
        line.append(f"success {100 * k / n:.0f} % [{100 * low:.0f}, {100 * high:.0f}] of {n}")
        line.append(f"failures {failures}")
        if "handover_range" in result:
            line.append(f"hand-overs {100 * np.isfinite(result['handover_range']).mean():.0f} %")
        line.append("final distance p10/p50/p90 "
                    + "/".join(f"{v:.1f}" for v in np.nanpercentile(result["final_distance"],
                                                                    [10, 50, 90])) + " m")
    else:  # acoustic tracking
        rmse = result["rmse"]
        line.append(f"episode RMSE median {np.nanmedian(rmse):.3f} m, mean "
                    f"{np.nanmean(rmse):.3f} m, p10/p90 "
                    + "/".join(f"{v:.3f}" for v in np.nanpercentile(rmse, [10, 90])) + " m")
    print(" | ".join(line), flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True, help="e.g. DockingMission-v0")
    parser.add_argument("--steps", type=int, default=10_000_000)
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--hyperparams-dir", type=Path, default=DEFAULT_DIR)
    parser.add_argument("--row", action="append", required=True, help="NAME:KEY=VALUE,...")
    args = parser.parse_args(argv)
    env_id = args.env if "/" in args.env else f"auv_envs/{args.env}"
    for text in args.row:
        name, overrides = parse_row(text)
        print(f"{name}: {overrides}", flush=True)
        trainer, params, normalizer, wall, stats = train_row(
            env_id, overrides, args.steps, args.hyperparams_dir, args.seed)
        report(name, wall, stats, judge(trainer, params, normalizer, args.episodes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
