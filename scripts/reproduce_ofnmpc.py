"""Reproduce [OFNMPC]'s simulations with the ``ofnmpc-ekf`` and ``ofnmpc-mhe`` agents.

    PYTHONPATH=. python scripts/reproduce_ofnmpc.py [--out results/ofnmpc] [--difficulty paper]
        [--first-seed 100000] [--episodes 4] [--json PATH]

Everything runs at ``--difficulty`` (default ``paper``: the disturbances and water of the
level, calibrated on Scenario 2 below; ``easy`` is the released environment) on seeds
``--first-seed``, ``--first-seed + 1``, ...; success rates are printed with their 95 %
Wilson interval, docking times with a 95 % bootstrap interval of the mean, and with
``--json`` the figures are written under the same names as the tables.

Scenario 1 (``scenario="mismatch"``: damping mismatch only, no noise, no
current), ``DockingStation-v2`` (``--env`` picks ``LampArrayDocking-v2``):

* both agents dock; plots of the 3-D trajectories, the outputs (x, y, z, psi
  against time, with the allowable deviations) and the disturbance estimates
  (``scenario1_*.png``);
* the steady-state disturbance estimate. The env's nominal model *knows* the
  10 N net buoyancy (it is part of the restoring forces of
  ``calibration.nominal_model``), so with it ``d_Z`` settles near 0 N. [OFNMPC]'s
  prediction model drops the restoring forces (its eq. 7), so its disturbance
  estimate absorbs the buoyancy; the run "[OFNMPC] model" uses the same
  :class:`NominalModel` with ``net_buoyancy=0`` to show that. Because an episode
  ends at the entrance while the vehicle still moves, the steady state is
  measured by station keeping at a set point 3 m in front of the entrance
  (``--hold`` seconds).

Scenario 2 (``scenario="current"``: 0.3 m/s current, 5 px / 0.02 m/s noise):
five current directions, one episode each per observer (``--episodes`` for
more seeds), a table like [OFNMPC]'s Table 4 (success, docking time) and the
trajectories
(``scenario2_trajectories.png``). If the image-mode agents
``ofnmpc-ekf-image`` / ``ofnmpc-mhe-image`` are registered, they fly the same
five episodes with ``obs_mode="image"`` and their success counts are printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import auv_envs  # noqa: E402, F401
from auv_envs.core.difficulty import LEVELS as DIFFICULTIES  # noqa: E402
from auv_envs.core.hydrodynamics import NominalModel  # noqa: E402
from auv_envs.tasks.docking.env import (  # noqa: E402
    SCENARIO_CURRENT_SPEED,
    SCENARIO_PIXEL_NOISE,
    SCENARIO_VELOCITY_NOISE,
)
from baselines.docking.agents import OFNMPCAgent  # noqa: E402
from baselines.evaluation import write_figures  # noqa: E402
from baselines.registry import agent_names, make_agent  # noqa: E402
from baselines.stats import bootstrap_interval, wilson_interval  # noqa: E402

ENV_ID = "auv_envs/DockingStation-v2"
OBSERVERS = ("ekf", "mhe")
DIRECTIONS = (0.0, 45.0, 90.0, 135.0, 180.0)


@dataclasses.dataclass
class Trace:
    """One episode, step by step."""

    time: list = dataclasses.field(default_factory=list)
    position: list = dataclasses.field(default_factory=list)
    heading: list = dataclasses.field(default_factory=list)
    estimate: list = dataclasses.field(default_factory=list)
    disturbance: list = dataclasses.field(default_factory=list)
    success: bool = False
    failure: str = ""
    docking_time: float | None = None
    solver_failures: int = 0


def fly(env, agent, seed: int, hold_point=None) -> Trace:
    """Run one episode (or a station-keeping run at ``hold_point``) and record it."""
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    inner = getattr(agent, "inner", agent)
    if hold_point is not None:
        inner.controller.reference = np.asarray(hold_point, dtype=float)
    trace, done = Trace(), False
    while not done:
        action = agent.act(obs, info)
        trace.time.append(info["time"])
        trace.position.append(info["true_position"].copy())
        trace.heading.append(info["true_euler"][2])
        est = inner.estimate
        trace.estimate.append(np.full(8, np.nan) if est is None else est.state.copy())
        trace.disturbance.append(np.full(4, np.nan) if est is None else est.disturbance.copy())
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    metrics = info["episode_metrics"]
    trace.success = bool(metrics["success"])
    trace.failure = metrics["failure_reason"]
    trace.docking_time = metrics["docking_time"]
    trace.solver_failures = int(inner.stats()["solver_failures"])
    return trace


def ofnmpc_model(calibration) -> NominalModel:
    """[OFNMPC]'s prediction model: the env's nominal model without restoring forces."""
    return NominalModel(dataclasses.replace(calibration.nominal_params, net_buoyancy=0.0))


def rate(successes: int, n: int) -> dict:
    """A success rate for ``--json``: count, episodes, rate and its 95 % Wilson interval."""
    low, high = wilson_interval(successes, n)
    return {"success": successes, "episodes": n, "rate": successes / n, "ci95": [low, high]}


def rate_text(r: dict) -> str:
    return (f"{r['success']}/{r['episodes']} ({100 * r['rate']:.0f} %, "
            f"[{100 * r['ci95'][0]:.0f}, {100 * r['ci95'][1]:.0f}] %)")


def mean_figure(values) -> dict:
    """Mean and 95 % bootstrap interval of ``values`` (None when there are none)."""
    if not values:
        return {"mean": None, "ci95": [None, None], "n": 0}
    low, high = bootstrap_interval(values)
    return {"mean": float(np.mean(values)), "ci95": [low, high], "n": len(values)}


def scenario1(args, out: Path) -> dict:
    env = gym.make(args.env, obs_mode="features", scenario="mismatch",
                   difficulty=args.difficulty)
    cal = env.unwrapped.calibration
    traces = {o: fly(env, OFNMPCAgent(env.unwrapped, o), args.seed) for o in OBSERVERS}
    print(f"## Scenario 1 (model mismatch), {args.env}, seed {args.seed}")
    print("| observer | docked | docking time s | solver failures | d at docking (X, Y, Z, N) |")
    print("|---|---|---|---|---|")
    for o, t in traces.items():
        d = ", ".join(f"{v:.2f}" for v in t.disturbance[-1])
        print(f"| {o.upper()} | {t.success} | {t.docking_time} | {t.solver_failures} | {d} |")
    figures = {f"ofnmpc-{o}": {"docked": t.success, "docking_time": t.docking_time,
                               "solver_failures": t.solver_failures,
                               "d_at_docking": [float(v) for v in t.disturbance[-1]]}
               for o, t in traces.items()}
    plot_trajectories({o.upper(): t for o, t in traces.items()}, cal,
                      out / "scenario1_trajectories.png", "Scenario 1: 3-D docking trajectories")
    plot_outputs(traces, cal, out / "scenario1_outputs.png")
    plot_disturbances(traces, out / "scenario1_disturbance.png")

    hold_point = np.array([cal.target_position[0] - 3.0, 0.0, 0.0, 0.0])
    hold_env = gym.make(args.env, obs_mode="features", scenario="mismatch",
                        time_limit=args.hold, difficulty=args.difficulty)
    print(f"\n## Scenario 1 steady state: station keeping at x = {hold_point[0]:.1f} m for "
          f"{args.hold:g} s; mean d over the last 5 s (N, N, N, N m)")
    print("| prediction model | observer | d_X | d_Y | d_Z | d_N |")
    print("|---|---|---|---|---|---|")
    holds = {}
    buoyancy = cal.nominal_params.net_buoyancy
    for label, model in ((f"env nominal model (knows the {buoyancy:g} N buoyancy)", None),
                         ("[OFNMPC] model (restoring forces dropped)", ofnmpc_model(cal))):
        for o in OBSERVERS:
            agent = OFNMPCAgent(hold_env.unwrapped, o, nominal_model=model)
            t = fly(hold_env, agent, args.seed, hold_point=hold_point)
            tail = np.asarray(t.disturbance)[np.asarray(t.time) >= t.time[-1] - 5.0]
            mean = np.nanmean(tail, axis=0)
            print(f"| {label} | {o.upper()} | " + " | ".join(f"{v:.2f}" for v in mean) + " |")
            holds[f"{o.upper()}, {label.split(' (')[0]}"] = t
            figures[f"steady_state_d_{o}_{'env' if model is None else 'paper'}_model"] = [
                float(v) for v in mean]
    plot_disturbances(holds, out / "scenario1_steady_state_disturbance.png",
                      "Station keeping: disturbance estimates")
    return figures


def scenario2(args, out: Path) -> dict:
    seeds = [args.seed + i for i in range(args.episodes)]
    print(f"\n## Scenario 2 ({SCENARIO_CURRENT_SPEED:g} m/s current, {SCENARIO_PIXEL_NOISE:g} px "
          f"/ {SCENARIO_VELOCITY_NOISE:g} m/s noise), {args.env}, difficulty "
          f"{args.difficulty!r}, seeds {seeds}")
    print("| current direction (deg) | OFNMPC-EKF | OFNMPC-MHE |")
    print("|---|---|---|")
    traces, wins = {o: {} for o in OBSERVERS}, dict.fromkeys(OBSERVERS, 0)
    docking_times: dict = {o: [] for o in OBSERVERS}
    cal = None
    for direction in args.directions:
        env = gym.make(args.env, obs_mode="features", scenario="current",
                       current_direction=direction, difficulty=args.difficulty)
        cal = env.unwrapped.calibration
        cells = []
        for o in OBSERVERS:
            agent = OFNMPCAgent(env.unwrapped, o)
            runs = [fly(env, agent, s) for s in seeds]
            traces[o][direction] = runs[0]
            docked = [t for t in runs if t.success]
            wins[o] += len(docked)
            docking_times[o] += [t.docking_time for t in docked]
            if len(runs) == 1:
                t = runs[0]
                cells.append(f"docked, {t.docking_time:.1f} s" if t.success
                             else f"failed ({t.failure})")
            else:
                times = [t.docking_time for t in docked]
                mean = f", mean {np.mean(times):.1f} s" if times else ""
                cells.append(f"{len(docked)}/{len(runs)} docked{mean}")
        print(f"| {direction:g} | " + " | ".join(cells) + " |")
    n = len(args.directions) * len(seeds)
    figures = {f"ofnmpc-{o}": {**rate(wins[o], n), "docking_time": mean_figure(docking_times[o])}
               for o in OBSERVERS}
    print("| success (95 % interval) | "
          + " | ".join(rate_text(figures[f"ofnmpc-{o}"]) for o in OBSERVERS) + " |")
    print("| docking time s (95 % interval) | " + " | ".join(
        "-" if f["docking_time"]["mean"] is None else
        f"{f['docking_time']['mean']:.1f} [{f['docking_time']['ci95'][0]:.1f}, "
        f"{f['docking_time']['ci95'][1]:.1f}]" for f in figures.values()) + " |")
    fig = plt.figure(figsize=(12, 5))
    for i, o in enumerate(OBSERVERS):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        for direction, t in traces[o].items():
            p = np.asarray(t.position)
            ax.plot(p[:, 0], p[:, 1], p[:, 2], label=f"{direction:g} deg")
        _station(ax, cal)
        ax.set_title(f"OFNMPC-{o.upper()} 3-D trajectories, Scenario 2")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "scenario2_trajectories.png", dpi=120)
    plt.close(fig)

    if args.no_image:
        return figures
    image_agents = [f"ofnmpc-{o}-image" for o in OBSERVERS if f"ofnmpc-{o}-image"
                    in agent_names()]
    if not image_agents:
        print("\nimage mode: ofnmpc-ekf-image / ofnmpc-mhe-image are not registered; skipped")
        return figures
    print("\n## Scenario 2 with image observations (lamp-array front end)")
    for name in image_agents:
        wins_image = 0
        for direction in args.directions:
            env = gym.make(args.env, obs_mode="image", scenario="current",
                           current_direction=direction, difficulty=args.difficulty)
            agent = make_agent(name, env)
            wins_image += sum(fly(env, agent, s).success for s in seeds)
            env.close()
        figures[name] = rate(wins_image, n)
        print(f"{name}: {rate_text(figures[name])} docked")
    return figures


def _station(ax, cal) -> None:
    lights = np.asarray(cal.light_positions)
    ax.scatter(lights[:, 0], lights[:, 1], lights[:, 2], c="gold", s=12, label="lights")
    ax.scatter([0], [0], [0], c="k", marker="x", label="entrance")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")


def plot_trajectories(traces: dict, cal, path: Path, title: str) -> None:
    fig = plt.figure(figsize=(7, 5))
    ax = fig.add_subplot(projection="3d")
    for label, t in traces.items():
        p, e = np.asarray(t.position), np.asarray(t.estimate)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], label=f"{label} (true)")
        ax.plot(e[:, 0], e[:, 1], e[:, 2], "--", lw=0.8, label=f"{label} (estimated)")
    _station(ax, cal)
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_outputs(traces: dict, cal, path: Path) -> None:
    """Nose position and heading against time with the allowable deviations."""
    tol = cal.tolerances
    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for o, t in traces.items():
        p, psi = np.asarray(t.position), np.asarray(t.heading)
        nose = p + cal.nose_offset * np.column_stack([np.cos(psi), np.sin(psi), 0 * psi])
        for ax, y in zip(axes, (nose[:, 0], nose[:, 1], nose[:, 2], np.degrees(psi)),
                         strict=True):
            ax.plot(t.time, y, label=f"OFNMPC-{o.upper()}")
    bands = (tol.longitudinal, tol.lateral, tol.vertical, tol.heading_deg)
    names = ("nose x (m)", "nose y (m)", "nose z (m)", "heading (deg)")
    for ax, band, name in zip(axes, bands, names, strict=True):
        ax.axhline(band, ls=":", c="gray")
        ax.axhline(-band, ls=":", c="gray")
        ax.set_ylabel(name)
    axes[0].legend()
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Scenario 1: outputs (dotted: allowable deviation)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_disturbances(traces: dict, path: Path,
                      title: str = "Scenario 1: disturbance estimates") -> None:
    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for label, t in traces.items():
        d = np.asarray(t.disturbance)
        name = label if len(label) > 3 else f"OFNMPC-{label.upper()}"
        for i, ax in enumerate(axes):
            ax.plot(t.time, d[:, i], label=name)
    for ax, name in zip(axes, ("d_X (N)", "d_Y (N)", "d_Z (N)", "d_N (N m)"), strict=True):
        ax.set_ylabel(name)
    axes[0].legend(fontsize=7)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/ofnmpc"))
    parser.add_argument("--env", default=ENV_ID,
                        choices=[ENV_ID, "auv_envs/LampArrayDocking-v2",
                                 # the -v1 plant (MuJoCo's staged RK4), for comparison
                                 "auv_envs/DockingStation-v1", "auv_envs/LampArrayDocking-v1"])
    parser.add_argument("--difficulty", choices=DIFFICULTIES, default="paper")
    parser.add_argument("--first-seed", "--seed", dest="seed", type=int, default=100_000,
                        help="episodes use seeds N, N+1, ... (default %(default)s)")
    parser.add_argument("--hold", type=float, default=40.0,
                        help="station-keeping seconds for the steady-state estimate")
    parser.add_argument("--directions", type=float, nargs="+", default=list(DIRECTIONS))
    parser.add_argument("--episodes", type=int, default=1,
                        help="seeds per direction in Scenario 2 (seed, seed + 1, ...)")
    parser.add_argument("--skip-scenario1", action="store_true")
    parser.add_argument("--no-image", action="store_true", help="skip the image-mode agents")
    parser.add_argument("--json", metavar="PATH", help="write the figures here")
    args = parser.parse_args()
    if args.hold <= 5.0 or not math.isfinite(args.hold):
        parser.error("--hold must be longer than 5 s")
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    args.out.mkdir(parents=True, exist_ok=True)
    figures: dict = {"env": args.env, "difficulty": args.difficulty, "first_seed": args.seed,
                     "episodes_per_direction": args.episodes, "directions": args.directions}
    if not args.skip_scenario1:
        figures["scenario1"] = scenario1(args, args.out)
    figures["scenario2"] = scenario2(args, args.out)
    print(f"\nplots in {args.out}/")
    if args.json:
        write_figures(args.json, figures)


if __name__ == "__main__":
    main()
