"""Reproduce seed 004's tables with the shipped agents (static positioning, RMSE/TFC, TCFE).

    PYTHONPATH=. python scripts/reproduce_seed004.py [--seeds 2] [--time-limit 20]
        [--flow-noise DB|off]

1. Static positioning at seed 004's five points (Table 1): mean Euclidean
   error of the per-detection fixes of the fused, TDOA-only and DOA-only
   least squares (the detection origin in ``info`` is used only to score the
   source's detections; the solvers never see it).
Seed 004's tank currents come from three current generators; the environment's
flow-noise model (``AcousticConfig.flow_noise_level``, off by default) lets
their radiated noise grow with the current, and sections 2 and 3 run with it
at ``SEED004_FLOW_NOISE_LEVEL`` (``--flow-noise DB`` to change the level,
``--flow-noise off`` for calm water). Section 3 repeats TCFE in calm water.

2. Dynamic tracking (medium current): mean and max episode RMSE and mean TFC,
   with the RMSE split into its systematic part (``error_bias``, the norm of
   the episode's mean error) and the rest; then the same episodes with the
   agents on the raw TDOAs (``clock_calibration=False``, the paper's
   pipeline), and with the hydrophone clock offsets switched off
   (``clock_offset_std = 0``), the one error source the environment applies
   alike to every band.
3. TCFE at low / medium / high current: ``tcfe`` (seed 004's definition, the
   entropy of the estimate's consecutive differences) and ``tcfe_fluctuation``
   (the same on second differences, 0 for the true motion). Every agent sees
   the same episodes; the ``truth`` row scores the noise-free true position
   given as the estimate.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

import gymnasium as gym
import numpy as np

import auv_envs  # noqa: F401
from auv_envs.core.acoustics import SEED004_FLOW_NOISE_LEVEL, AcousticConfig
from auv_envs.tasks.acoustic import TCFE_BIN_WIDTH
from baselines.acoustic.positioning import METHODS, LeastSquaresPositioner
from baselines.evaluation import run_episode
from baselines.registry import agent_spec

ENV_ID = "auv_envs/AcousticTracking-v0"
AGENTS = ("gmphd-gci", "gmphd-single", "ls-kf")
LEVELS = ("low", "medium", "high")


def static_errors(steps: int = 200, seed: int = 0) -> dict[str, list[float]]:
    out = {m: [] for m in METHODS}
    for point in range(1, 6):
        env = gym.make(ENV_ID, trajectory="static", static_point=point,
                       time_limit=steps / 100.0 + 1)
        cal = env.unwrapped.calibration
        solvers = {m: LeastSquaresPositioner(cal, m) for m in METHODS}
        errors = {m: [] for m in METHODS}
        try:
            obs, info = env.reset(seed=seed + point)
            for _ in range(steps):
                source = info["detection_origin"] == 0
                for m, solver in solvers.items():
                    fix = solver.solve(obs["tdoa"], obs["azimuth"], obs["elevation"],
                                       obs["mask"])
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--time-limit", type=float, default=20.0)
    parser.add_argument("--flow-noise", type=flow_level, default=SEED004_FLOW_NOISE_LEVEL,
                        metavar="DB|off",
                        help="flow-noise level in dB re 1 uPa^2/Hz at 1 m/s and 1 kHz, or off "
                             f"(default {SEED004_FLOW_NOISE_LEVEL:g})")
    args = parser.parse_args()
    flow = AcousticConfig(flow_noise_level=args.flow_noise)
    calm = AcousticConfig()
    flow_text = "calm water" if args.flow_noise is None else f"flow noise {args.flow_noise:g} dB"

    print("## Static positioning error (m), seed 004 Table 1 (paper fused: 0.11 average)")
    errs = static_errors()
    print("| point | " + " | ".join(METHODS) + " |\n|---|---|---|---|")
    for i in range(5):
        print(f"| {i + 1} | " + " | ".join(f"{errs[m][i]:.3f}" for m in METHODS) + " |")
    print("| avg | " + " | ".join(f"{np.mean(errs[m]):.3f}" for m in METHODS) + " |")

    def level_runs(acoustic: AcousticConfig) -> dict:
        return {(a, lvl): [episode(a, 1000 + s, lvl, args.time_limit, acoustic)
                           for s in range(args.seeds)] for a in AGENTS for lvl in LEVELS}

    truth = {lvl: [truth_episode(1000 + s, lvl, args.time_limit) for s in range(args.seeds)]
             for lvl in LEVELS}
    runs = level_runs(flow)
    print(f"\n## Dynamic tracking, medium current, {flow_text} ({args.seeds} episodes x "
          f"{args.time_limit:g} s; paper: 0.18 / 0.45 / 2)")
    dynamic_table({a: runs[a, "medium"] for a in AGENTS})
    print("\n## The same episodes on the raw TDOAs (clock_calibration=False, as the paper)")
    dynamic_table({a: [episode(a, 1000 + s, "medium", args.time_limit, flow,
                               clock_calibration=False)
                       for s in range(args.seeds)] for a in AGENTS})
    no_clock = dataclasses.replace(flow, clock_offset_std=0.0)
    print("\n## The same episodes without clock offsets (clock_offset_std = 0)")
    dynamic_table({a: [episode(a, 1000 + s, "medium", args.time_limit, no_clock)
                       for s in range(args.seeds)] for a in AGENTS})
    tcfe_tables(runs, truth, flow_text)
    if args.flow_noise is not None:
        tcfe_tables(level_runs(calm), truth, "calm water")


def flow_level(text: str) -> float | None:
    """``--flow-noise``: a level in dB, or ``off`` (None)."""
    if text.lower() == "off":
        return None
    try:
        return float(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"expected a level in dB or 'off', got {text!r}") from exc


def tcfe_tables(runs: dict, truth: dict, what_water: str) -> None:
    """TCFE on first and second differences per agent and current level, with the truth."""
    rows = {**{a: [runs[a, lvl] for lvl in LEVELS] for a in AGENTS},
            "truth": [truth[lvl] for lvl in LEVELS]}
    for key, what in (("tcfe", "first differences, seed 004's definition"),
                      ("tcfe_fluctuation", "second differences, 0 for the true motion")):
        print(f"\n## {key}, {what_water} (nats; {what}; {100 * TCFE_BIN_WIDTH:g} cm bins) "
              f"by current level (paper gmphd-gci: 0.05 / 0.07 / 0.09)")
        print("| agent | " + " | ".join(LEVELS) + " |\n|---|---|---|---|")
        for a, per_level in rows.items():
            print(f"| {a} | " + " | ".join(
                f"{np.mean([x[key] for x in r]):.3f}" for r in per_level) + " |")


def dynamic_table(runs: dict[str, list[dict]]) -> None:
    """RMSE (mean, max over episodes), its bias / random split, TFC, max error."""
    print("| agent | mean RMSE (m) | max RMSE (m) | mean bias (m) | mean random (m) | "
          "mean TFC | max error (m) |\n|---|---|---|---|---|---|---|")
    for a, r in runs.items():
        rmse = [x["rmse"] for x in r]
        bias = [x["error_bias"] for x in r]
        rest = [math.sqrt(max(e * e - b * b, 0.0)) for e, b in zip(rmse, bias, strict=True)]
        print(f"| {a} | {np.mean(rmse):.3f} | {np.max(rmse):.3f} | {np.mean(bias):.3f} | "
              f"{np.mean(rest):.3f} | {np.mean([x['tfc'] for x in r]):.1f} | "
              f"{np.max([x['max_error'] for x in r]):.3f} |")


if __name__ == "__main__":
    main()
