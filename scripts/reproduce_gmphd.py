"""Reproduce [GMPHD]'s tables with the shipped agents (static positioning, RMSE/TFC, TCFE).

    PYTHONPATH=. python scripts/reproduce_gmphd.py [--difficulty paper] [--seeds 20]
        [--first-seed 5000] [--time-limit 20] [--sections static,dynamic,variants,tcfe]
        [--json PATH]

Every section runs the environment at ``--difficulty`` (default ``paper``, the
level calibrated to [GMPHD]'s tank; ``easy`` is the released model) on
seeds ``--first-seed``, ``--first-seed + 1``, ...; every figure is printed
with its 95 % interval (percentile bootstrap of the mean over episodes) and,
with ``--json``, written under the same names as the tables.

1. ``static``: [GMPHD]'s five points (Table 1), ``--seeds`` episodes
   spread over them: mean Euclidean error of the per-detection fixes of the
   fused, TDOA-only and DOA-only least squares (the detection origin in
   ``info`` is used only to score the source's detections; the solvers never
   see it). Paper: fused 0.11 m on average.
2. ``dynamic``: dynamic tracking at medium current, ``--seeds`` episodes per
   agent: RMSE (mean and max over episodes), its systematic part
   (``error_bias``, the norm of the episode's mean error), TFC and maximum
   error. Paper: ``gmphd-gci`` 0.18 m average RMSE, 0.45 m max, TFC 2.
3. ``variants``: the same episodes with the agents on the raw TDOAs
   (``clock_calibration=False``, the paper's pipeline), and with the
   hydrophone clock offsets switched off (``clock_offset_std = 0``).
4. ``tcfe``: TCFE at low / medium / high current: ``tcfe`` ([GMPHD]'s
   definition, the entropy of the estimate's consecutive differences) and
   ``tcfe_fluctuation`` (the same on second differences, 0 for the true
   motion), with the level's flow noise and in calm water (flow noise off).
   Every agent sees the same episodes; the ``truth`` row scores the
   noise-free true position given as the estimate.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

import gymnasium as gym
import numpy as np

import auv_envs  # noqa: F401
from auv_envs.core.acoustics import AcousticConfig
from auv_envs.core.difficulty import LEVELS as DIFFICULTIES
from auv_envs.tasks.acoustic.env import AcousticTrackingTask
from auv_envs.tasks.acoustic.transition import TCFE_BIN_WIDTH
from baselines.acoustic.perception.positioning import METHODS, LeastSquaresPositioner
from baselines.evaluation import run_episode, write_figures
from baselines.registry import agent_spec
from baselines.stats import bootstrap_interval

ENV_ID = "auv_envs/AcousticTracking-v2"
AGENTS = ("gmphd-gci", "gmphd-single", "ls-kf")
LEVELS = ("low", "medium", "high")
SECTIONS = ("static", "dynamic", "variants", "tcfe")


def acoustic_model(difficulty: str) -> AcousticConfig:
    """The measurement model of a difficulty level (``easy``: the released default)."""
    return AcousticTrackingTask.difficulty_presets[difficulty].get("acoustic", AcousticConfig())


def static_errors(acoustic: AcousticConfig, seeds: range,
                  steps: int = 200) -> dict[str, list[float]]:
    """Per episode (seed ``s`` at [GMPHD]'s point ``1 + s % 5``): mean fix error per method."""
    out = {m: [] for m in METHODS}
    for seed in seeds:
        point = 1 + seed % 5
        env = gym.make(ENV_ID, trajectory="static", static_point=point,
                       time_limit=steps / 100.0 + 1, acoustic=acoustic)
        cal = env.unwrapped.calibration
        solvers = {m: LeastSquaresPositioner(cal, m) for m in METHODS}
        errors = {m: [] for m in METHODS}
        try:
            obs, info = env.reset(seed=seed)
            for _ in range(steps):
                source = info["detection_origin"] == 0
                for m, solver in solvers.items():
                    fix = solver.solve(obs["tdoa"], obs["azimuth"], obs["elevation"],
                                       obs["mask"], nodes=obs.get("node_mask"))
                    use = source & fix.valid
                    errors[m].extend(np.linalg.norm(fix.position[use] - info["true_position"],
                                                    axis=-1))
                obs, _, _, _, info = env.step(info["true_position"])
        finally:
            env.close()
        for m in METHODS:
            out[m].append(float(np.mean(errors[m])))
    return out


def episode(name: str, seed: int, disturbance: str, time_limit: float,
            acoustic: AcousticConfig | None = None, clock_calibration: bool = True) -> dict:
    env = gym.make(ENV_ID, disturbance=disturbance, time_limit=time_limit, acoustic=acoustic)
    try:
        # The registered factories take the agents' keyword arguments.
        agent = agent_spec(name).factory(env.unwrapped, clock_calibration=clock_calibration)
        return run_episode(env, agent, seed, ENV_ID, name).metrics
    finally:
        env.close()


def truth_episode(seed: int, disturbance: str, time_limit: float) -> dict:
    """Episode metrics of the noise-free truth given as the estimate (what the metric
    scores of the motion itself; the route and current match ``episode``'s seed, and
    the flow noise, which acts only on the measurements, does not change them)."""
    env = gym.make(ENV_ID, obs_mode="state", disturbance=disturbance, time_limit=time_limit)
    try:
        _, info = env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(info["true_position"])
            done = terminated or truncated
        return info["episode_metrics"]
    finally:
        env.close()


def interval_text(values) -> str:
    mean = float(np.mean(values))
    low, high = bootstrap_interval(values)
    return f"{mean:.3f} [{low:.3f}, {high:.3f}]" if math.isfinite(low) else f"{mean:.3f}"


def figure(values) -> dict:
    """A figure for ``--json``: mean, 95 % interval (bootstrap of the mean), n, max."""
    low, high = bootstrap_interval(values)
    return {"mean": float(np.mean(values)), "ci95": [low, high], "n": len(values),
            "max": float(np.max(values))}


def static_section(acoustic: AcousticConfig, seeds: range) -> dict:
    errs = static_errors(acoustic, seeds)
    print("| method | mean fix error (m), 95 % interval | worst episode (m) |\n|---|---|---|")
    for m in METHODS:
        print(f"| {m} | {interval_text(errs[m])} | {np.max(errs[m]):.3f} |")
    return {m: figure(errs[m]) for m in METHODS}


def dynamic_table(runs: dict[str, list[dict]]) -> dict:
    """RMSE (mean with interval, max over episodes), its bias, TFC, max error."""
    print("| agent | RMSE (m), 95 % interval | max RMSE (m) | bias (m) | TFC | max error (m) |"
          "\n|---|---|---|---|---|---|")
    out = {}
    for a, r in runs.items():
        rmse = [x["rmse"] for x in r]
        bias = [x["error_bias"] for x in r]
        tfc = [x["tfc"] for x in r]
        max_error = [x["max_error"] for x in r]
        print(f"| {a} | {interval_text(rmse)} | {np.max(rmse):.3f} | {interval_text(bias)} | "
              f"{interval_text(tfc)} | {np.max(max_error):.3f} |")
        out[a] = {"rmse": figure(rmse), "error_bias": figure(bias), "tfc": figure(tfc),
                  "max_error": figure(max_error)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--difficulty", choices=DIFFICULTIES, default="paper")
    parser.add_argument("--seeds", type=int, default=20, help="episodes per case")
    parser.add_argument("--first-seed", type=int, default=5000,
                        help="episodes use seeds N, N+1, ... (default %(default)s)")
    parser.add_argument("--time-limit", type=float, default=20.0)
    parser.add_argument("--sections", default=",".join(SECTIONS),
                        help=f"comma-separated subset of {', '.join(SECTIONS)}")
    parser.add_argument("--json", metavar="PATH", help="write the figures here")
    args = parser.parse_args()
    sections = args.sections.split(",")
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        parser.error(f"unknown sections {sorted(unknown)}; choose from {SECTIONS}")
    if args.seeds < 1:
        parser.error("--seeds must be at least 1")
    acoustic = acoustic_model(args.difficulty)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    figures: dict = {"difficulty": args.difficulty, "first_seed": args.first_seed,
                     "episodes": args.seeds, "time_limit": args.time_limit}
    print(f"# [GMPHD] reproduction, difficulty {args.difficulty!r}, seeds "
          f"{seeds.start}-{seeds.stop - 1}")

    if "static" in sections:
        print(f"\n## Static positioning error (m), [GMPHD] Table 1, {args.seeds} episodes of "
              "200 steps over its five points (paper fused: 0.11 average)")
        figures["static"] = static_section(acoustic, seeds)

    def runs_at(level: str, model: AcousticConfig, **kwargs) -> dict:
        return {a: [episode(a, s, level, args.time_limit, model, **kwargs) for s in seeds]
                for a in AGENTS}

    medium = None
    if "dynamic" in sections or "tcfe" in sections:
        medium = runs_at("medium", acoustic)
    if "dynamic" in sections:
        print(f"\n## Dynamic tracking, medium current ({args.seeds} episodes x "
              f"{args.time_limit:g} s; paper gmphd-gci: 0.18 average RMSE, 0.45 max, TFC 2)")
        figures["dynamic"] = dynamic_table(medium)
    if "variants" in sections:
        print("\n## The same episodes on the raw TDOAs (clock_calibration=False, as the paper)")
        figures["raw_tdoa"] = dynamic_table(runs_at("medium", acoustic,
                                                    clock_calibration=False))
        print("\n## The same episodes without clock offsets (clock_offset_std = 0)")
        figures["no_clock_offsets"] = dynamic_table(
            runs_at("medium", dataclasses.replace(acoustic, clock_offset_std=0.0)))
    if "tcfe" in sections:
        truth = {lvl: [truth_episode(s, lvl, args.time_limit) for s in seeds] for lvl in LEVELS}
        flowing = {(a, lvl): (medium[a] if lvl == "medium" else
                              [episode(a, s, lvl, args.time_limit, acoustic) for s in seeds])
                   for a in AGENTS for lvl in LEVELS}
        figures["tcfe"] = tcfe_tables(flowing, truth, "the level's flow noise")
        if acoustic.flow_noise_level is not None:
            calm = dataclasses.replace(acoustic, flow_noise_level=None)
            calm_runs = {(a, lvl): [episode(a, s, lvl, args.time_limit, calm) for s in seeds]
                         for a in AGENTS for lvl in LEVELS}
            figures["tcfe_calm"] = tcfe_tables(calm_runs, truth, "calm water")
    if args.json:
        write_figures(args.json, figures)


def tcfe_tables(runs: dict, truth: dict, what_water: str) -> dict:
    """TCFE on first and second differences per agent and current level, with the truth."""
    rows = {**{a: [runs[a, lvl] for lvl in LEVELS] for a in AGENTS},
            "truth": [truth[lvl] for lvl in LEVELS]}
    out: dict = {}
    for key, what in (("tcfe", "first differences, [GMPHD]'s definition"),
                      ("tcfe_fluctuation", "second differences, 0 for the true motion")):
        print(f"\n## {key}, {what_water} (nats; {what}; {100 * TCFE_BIN_WIDTH:g} cm bins) "
              f"by current level (paper gmphd-gci: 0.05 / 0.07 / 0.09)")
        print("| agent | " + " | ".join(LEVELS) + " |\n|---|---|---|---|")
        for a, per_level in rows.items():
            values = [[x[key] for x in r] for r in per_level]
            print(f"| {a} | " + " | ".join(interval_text(v) for v in values) + " |")
            out.setdefault(key, {})[a] = {lvl: figure(v)
                                          for lvl, v in zip(LEVELS, values, strict=True)}
    return out


if __name__ == "__main__":
    main()
