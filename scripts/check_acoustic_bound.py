"""Check the acoustic tracking bound against every acoustic agent on fresh seeds.

    PYTHONPATH=. python scripts/check_acoustic_bound.py [--levels easy,paper,hard]
        [--seeds 20] [--first-seed 913000] [--time-limit 30] [--agents a,b,...]
        [--workers 1] [--cache DIR] [--json PATH]

Per difficulty level, on seeds ``--first-seed`` ... (keep them clear of the
leaderboard's frozen seeds, from 100000, and of the calibration runs that
``docs/difficulty.md`` lists), with the leaderboard's episode length (30 s):

* the bound, ``env.unwrapped.trajectory_bound()`` (the leaderboard's ``pcrb``
  row: the posterior Cramér–Rao bound with the motion known,
  :mod:`auv_envs.tasks.acoustic.bound`), and for comparison the model-based
  white-jerk bound (``MotionPrior(jerk_scale=1)``, not a guaranteed limit);
* every acoustic agent's mean squared error and RMSE per episode (the
  environment's ``rmse`` metric);

each as mean [95 % interval] over the episodes (percentile bootstrap of the
mean, :func:`baselines.stats.bootstrap_interval`, as the leaderboard), and
whether an agent's mean squared error is below the bound's (the inequality
the bound guarantees) and in how many episodes its RMSE is (paired by seed;
a single episode may, by chance, without contradicting the bound). Agents
with the privileged ``state`` observation see the true position: the bound
does not apply to them (they are listed, marked).
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # the PPO agents: one thread per episode

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import auv_envs  # noqa: E402, F401
from auv_envs.core.difficulty import LEVELS  # noqa: E402
from auv_envs.tasks.acoustic.bound import MotionPrior, bound_rmse  # noqa: E402
from baselines.evaluation import evaluate_all  # noqa: E402
from baselines.registry import agent_names, agent_spec  # noqa: E402
from baselines.stats import bootstrap_interval  # noqa: E402

ENV_ID = "auv_envs/AcousticTracking-v2"


def acoustic_agents() -> list[str]:
    """Every registered agent that applies to the acoustic environment."""
    return [name for name in agent_names()
            if ENV_ID in (agent_spec(name).env_ids or (ENV_ID,))]


def bounds(level: str, seeds, time_limit: float) -> dict[str, list[float]]:
    """Per seed, the bound's RMSE (m): ``pcrb`` (known motion) and ``white-jerk``."""
    env = gym.make(ENV_ID, difficulty=level, time_limit=time_limit)
    array = env.unwrapped.calibration.array
    out: dict[str, list[float]] = {"pcrb": [], "white-jerk": []}
    for seed in seeds:
        env.reset(seed=seed)
        record = env.unwrapped.episode_record()
        out["pcrb"].append(bound_rmse(array, record))
        out["white-jerk"].append(bound_rmse(array, record, MotionPrior(jerk_scale=1.0)))
    env.close()
    return out


def stat(values) -> dict:
    values = np.asarray(values, dtype=float)
    return {"mean": float(values.mean()), "ci": list(bootstrap_interval(values)),
            "n": int(values.size)}


def check_level(level: str, seeds, time_limit: float, agents, workers: int,
                cache: str | None) -> dict:
    """The bound and the agents' errors at one level (module docstring)."""
    reference = bounds(level, seeds, time_limit)
    run = evaluate_all([ENV_ID], agents, seeds,
                       env_kwargs=({ENV_ID: {"difficulty": level, "time_limit": time_limit}},),
                       cache_dir=cache, workers=workers)
    bound_mse = np.square(reference["pcrb"])
    result = {"level": level, "seeds": list(seeds), "time_limit": time_limit,
              "bounds": {name: {"rmse": stat(v), "mse": stat(np.square(v))}
                         for name, v in reference.items()}, "agents": {}}
    by_seed = dict(zip(seeds, reference["pcrb"], strict=True))
    for name in agents:
        rows = [r for r in run.rows if r.agent == name]
        if not rows:
            continue
        ok = [r for r in rows if r.status == "ok"]
        rmse = np.array([r.metrics["rmse"] for r in ok])
        privileged = rows[0].obs_mode == "state"
        result["agents"][name] = {
            "obs_mode": rows[0].obs_mode, "privileged": privileged,
            "failed": len(rows) - len(ok),
            "rmse": stat(rmse), "mse": stat(np.square(rmse)),
            "mean_mse_below_bound": bool(np.mean(np.square(rmse)) < bound_mse.mean()),
            "episodes_below_bound": int(sum(r.metrics["rmse"] < by_seed[r.seed] for r in ok)),
        }
    return result


def _cell(s: dict, scale: float, digits: int = 3) -> str:
    low, high = (float("nan") if c is None else c * scale for c in s["ci"])
    return f"{s['mean'] * scale:.{digits}g} [{low:.{digits}g}, {high:.{digits}g}]"


def report(result: dict) -> str:
    seeds = result["seeds"]
    lines = [f"## {result['level']}: seeds {seeds[0]}-{seeds[-1]} ({len(seeds)}), "
             f"{result['time_limit']:g} s episodes", "",
             "| row | MSE mm^2 | RMSE mm | mean MSE below pcrb | episodes with RMSE below |",
             "|---|---|---|---|---|"]
    for name, b in result["bounds"].items():
        label = ("pcrb (known motion: the leaderboard's bound)" if name == "pcrb"
                 else "white-jerk PCRB (a model, for comparison)")
        lines.append(f"| {label} | {_cell(b['mse'], 1e6)} | {_cell(b['rmse'], 1e3)} | – | – |")
    for name, a in result["agents"].items():
        mark = " (privileged state: the bound does not apply)" if a["privileged"] else ""
        failed = f", {a['failed']} failed" if a["failed"] else ""
        lines.append(f"| {name}{mark}{failed} | {_cell(a['mse'], 1e6)} | "
                     f"{_cell(a['rmse'], 1e3)} | {'YES' if a['mean_mse_below_bound'] else 'no'} | "
                     f"{a['episodes_below_bound']}/{a['rmse']['n']} |")
    below = [n for n, a in result["agents"].items()
             if not a["privileged"] and a["mean_mse_below_bound"]]
    lines += ["", "trackers below the bound: " + (", ".join(below) if below else "none"), ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", default=",".join(LEVELS))
    parser.add_argument("--seeds", type=int, default=20, help="episodes per level")
    parser.add_argument("--first-seed", type=int, default=913000)
    parser.add_argument("--time-limit", type=float, default=30.0)
    parser.add_argument("--agents", help="comma-separated (default: every acoustic agent)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--cache", metavar="DIR", help="episode cache (reruns read it)")
    parser.add_argument("--json", metavar="PATH", help="write the figures here")
    args = parser.parse_args()
    levels = args.levels.split(",")
    for level in levels:
        if level not in LEVELS:
            parser.error(f"unknown level {level!r}; choose from {', '.join(LEVELS)}")
    agents = args.agents.split(",") if args.agents else acoustic_agents()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    results = []
    for level in levels:
        results.append(check_level(level, seeds, args.time_limit, agents, args.workers,
                                   args.cache))
        print(report(results[-1]), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
