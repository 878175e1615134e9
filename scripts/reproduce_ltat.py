"""Reproduce [LTAT]'s estimation and control results with the shipped agents.

    PYTHONPATH=. python scripts/reproduce_ltat.py --out results/ltat \\
        [--difficulty paper] [--first-seed 1000] [--seas calm,severe] [--json PATH] \\
        [--estimation-episodes 10] [--capture-episodes 20] [--agents ckf-pd,ltat-ckf-pd]

Every experiment runs the environment at ``--difficulty`` (default ``paper``,
the level calibrated on [LTAT]'s capture; ``easy`` is the released
sinusoidal heave) in each sea state of ``--seas``. Seeds: the tracking
episodes use ``N, N+1, ...`` with ``N = --first-seed``, the attitude cases
``N + 1000, ...``, the capture episodes ``N + 2000, ...`` (the default 1000
gives the seeds of the release: 1000, 2000, 3000). Success rates come with
their 95 % Wilson interval, mean errors with a 95 % percentile bootstrap
interval; ``--json PATH`` writes every figure under the names of the printed
tables.

1. **Position error per axis, measured vs CKF** (paper Figs. 9-12): ``ckf-pd``
   tracks the AUV (no strike) for ``--track-time`` s per episode in calm and
   severe sea. "Measured" is the AUV centre triangulated from the marker in
   that frame (frames with a fix); "CKF" is the filter's estimate in every
   frame after the first ``--warmup`` s (also the frames it bridges). Both
   are compared with ``info["true_position"]`` of the same frame (taken into
   the arm's frame with ``info["ship_motion"]`` when a sea moves the ship, as
   at ``paper`` and ``hard``: the fixes are relative to the arm). Reported:
   mean and max of the absolute error per axis, and the paper's Fig. 10
   statistic (the largest mean of 25 consecutive errors), with the range
   (AUV centre to arm end) the errors were taken at.
2. **Pitch and yaw at set angles** (Tables 2-3): the AUV pinned at pitch
   15/20/30 deg (yaw 0) and yaw -30/0/30 deg (pitch 0); per-frame estimates
   from the noisy features through eqs. 4-6 as printed and with ``D`` along
   the body axis, and the agent's running mean at the end.
3. **Capture** over ``--capture-episodes`` seeded episodes per sea state for
   each agent in ``--agents`` that is registered (``ltat-ckf-pd`` runs on
   ``stereo`` images): success rate, final capture error (at the step the
   env declares the capture), failures.

Everything printed is also written to ``OUT/ltat.json``; plots go to
``OUT/*.png``. The agents never read ``info``; the script does, to score them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import auv_envs  # noqa: F401
from auv_envs.core.difficulty import LEVELS
from auv_envs.core.ops import FLOATS
from auv_envs.tasks.lars.env import CONTROL_PERIOD
from auv_envs.tasks.lars.sea import SeaSample, ShipPose
from baselines.evaluation import run_episode, write_figures
from baselines.lars.agents import CKFPDAgent
from baselines.lars.perception.marker import MarkerLocaliser, marker_attitude
from baselines.registry import agent_names, agent_spec, make_agent
from baselines.stats import bootstrap_interval, wilson_interval

ENV_ID = "auv_envs/LARSCapture-v0"
SEAS = ("calm", "severe")
AXES = ("x", "y", "z")
PITCHES = (15.0, 20.0, 30.0)
YAWS = (-30.0, 0.0, 30.0)
#: Seed offsets from ``--first-seed``: each experiment draws its own episodes.
ESTIMATION_OFFSET, ATTITUDE_OFFSET, CAPTURE_OFFSET = 0, 1000, 2000
DEFAULT_FIRST_SEED = 1000
#: Frames per block of the paper's Fig. 10 statistic.
BLOCK = 25


def block_max(errors: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """Largest mean of ``block`` consecutive absolute errors per axis (paper Fig. 10)."""
    n = (len(errors) // block) * block
    if n == 0:
        return np.full(errors.shape[1], np.nan)
    return np.abs(errors[:n]).reshape(-1, block, errors.shape[1]).mean(axis=1).max(axis=0)


def true_in_arm_frame(info: dict, sea_model) -> np.ndarray:
    """The AUV's true CG in the frame the agent measures in: the arm's (ship's) frame.

    Without a sea the ship is still and that is the world frame. With one, the
    ship heaves, rolls and pitches (``info["ship_motion"]``) and carries the
    arm and its cameras: the marker fixes are relative to it.
    """
    if sea_model is None:
        return info["true_position"]
    heave, roll, pitch = info["ship_motion"]
    sample = SeaSample(0.0, 0.0, 0.0, 0.0, heave, roll, pitch, (), 0.0, 0.0, 0.0, 0.0)
    return ShipPose(sea_model.ship_origin, sample, FLOATS).to_ship(info["true_position"], np)


def track_episode(sea: str, seed: int, track_time: float, difficulty: str) -> dict:
    """One tracking-only ``ckf-pd`` episode: per-frame truth, measurement and estimate."""
    env = gym.make(ENV_ID, obs_mode="features", sea_state=sea, time_limit=track_time,
                   difficulty=difficulty)
    try:
        agent = CKFPDAgent(env.unwrapped, strike=False)
        obs, info = env.reset(seed=seed)
        agent.reset(seed)
        rows = {k: [] for k in ("time", "truth", "measured", "estimate", "range", "hidden")}
        done = False
        while not done:
            action = agent.act(obs, info)
            est = agent.position_estimate()
            meas = agent.last_measurement
            rows["time"].append(info["time"])
            rows["truth"].append(true_in_arm_frame(info, env.unwrapped.calibration.sea))
            rows["measured"].append(np.full(3, np.nan) if meas is None else meas)
            rows["estimate"].append(np.full(3, np.nan) if est is None else est)
            rows["range"].append(np.linalg.norm(info["true_position"] - info["end_position"]))
            rows["hidden"].append(meas is None)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        out = {k: np.array(v) for k, v in rows.items()}
        out["stats"] = agent.stats()
        return out
    finally:
        env.close()


def estimation(sea: str, episodes: int, track_time: float, warmup: float, difficulty: str,
               first_seed: int) -> tuple[dict, list]:
    runs = [track_episode(sea, first_seed + i, track_time, difficulty) for i in range(episodes)]
    meas_err, est_err, blocks_m, blocks_e, ranges = [], [], [], [], []
    bridged = frames = 0
    for run in runs:
        keep = run["time"] >= warmup
        m = run["measured"][keep] - run["truth"][keep]
        e = run["estimate"][keep] - run["truth"][keep]
        m = m[np.all(np.isfinite(m), axis=1)]
        e = e[np.all(np.isfinite(e), axis=1)]  # (a filter that has had no fix yet)
        meas_err.append(m)
        est_err.append(e)
        blocks_m.append(block_max(m))
        blocks_e.append(block_max(e))
        ranges.append(run["range"][keep].max())
        bridged += int(run["hidden"][keep].sum())
        frames += int(keep.sum())
    m, e = np.abs(np.concatenate(meas_err)), np.abs(np.concatenate(est_err))
    summary = {
        "episodes": episodes, "frames": frames, "bridged_frames": bridged,
        "max_range_m": float(max(ranges)),
        "measured_mean_mm": (1e3 * m.mean(axis=0)).tolist(),
        "measured_max_mm": (1e3 * m.max(axis=0)).tolist(),
        "measured_block25_max_mm": (1e3 * np.nanmax(blocks_m, axis=0)).tolist(),
        "ckf_mean_mm": (1e3 * e.mean(axis=0)).tolist(),
        "ckf_max_mm": (1e3 * e.max(axis=0)).tolist(),
        "ckf_block25_max_mm": (1e3 * np.nanmax(blocks_e, axis=0)).tolist(),
    }
    return summary, runs


def attitude(pitch_deg: float, yaw_deg: float, seed: int, steps: int, difficulty: str) -> dict:
    """Pitch/yaw estimates with the AUV pinned at the set angles (with a sea, the waves'
    pitch comes on top of the set one)."""
    env = gym.make(ENV_ID, obs_mode="features", time_limit=steps * CONTROL_PERIOD + 1,
                   difficulty=difficulty)
    try:
        cal = env.unwrapped.calibration
        literal_loc = MarkerLocaliser(cal, refine_attitude=False)
        agent = CKFPDAgent(env.unwrapped, strike=False)
        options = {"motion": {"pitch": math.radians(pitch_deg), "yaw": math.radians(yaw_deg)}}
        obs, info = env.reset(seed=seed, options=options)
        agent.reset(seed)
        literal, refined = [], []
        for _ in range(steps):
            fix = literal_loc.locate(obs["pixels"], obs["visible"], obs["joint_position"])
            if fix.pitch is not None:
                literal.append((fix.pitch, fix.yaw))
                refined.append(marker_attitude(fix.corners, cal.marker.depth_offset))
            obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
            if terminated or truncated:
                break
        final = agent.attitude_estimate()
    finally:
        env.close()
    literal, refined = np.degrees(literal), np.degrees(refined)
    return {
        "set_pitch": pitch_deg, "set_yaw": yaw_deg, "frames": len(literal),
        "literal_mean": literal.mean(axis=0).tolist(),
        "literal_max_abs_error": np.abs(literal - (pitch_deg, yaw_deg)).max(axis=0).tolist(),
        "refined_mean": refined.mean(axis=0).tolist(),
        "refined_max_abs_error": np.abs(refined - (pitch_deg, yaw_deg)).max(axis=0).tolist(),
        "agent_final": np.degrees(final).tolist() if final is not None else None,
    }


def capture(agent_name: str, sea: str, episodes: int, difficulty: str, first_seed: int) -> dict:
    spec = agent_spec(agent_name)
    env = gym.make(ENV_ID, obs_mode=spec.obs_mode, sea_state=sea, difficulty=difficulty,
                   **spec.env_kwargs)
    rows = []
    try:
        agent = make_agent(agent_name, env)
        for i in range(episodes):
            rows.append(run_episode(env, agent, first_seed + i, ENV_ID, agent_name))
    finally:
        env.close()
    ok = [r for r in rows if r.success]
    final = np.array([r.metrics["final_capture_error"] for r in ok])
    reasons: dict[str, int] = {}
    for r in rows:
        if not r.success:
            reasons[r.failure_reason] = reasons.get(r.failure_reason, 0) + 1
    return {
        "agent": agent_name, "sea": sea, "episodes": episodes,
        "success_rate": len(ok) / episodes,
        "success_rate_ci95": list(wilson_interval(len(ok), episodes)),
        "final_error_mean_mm": float(1e3 * final.mean()) if len(ok) else None,
        "final_error_mean_mm_ci95": list(bootstrap_interval(1e3 * final)) if len(ok) else None,
        "final_error_max_mm": float(1e3 * final.max()) if len(ok) else None,
        "final_error_le_28mm": float(np.mean(final <= 0.028)) if len(ok) else None,
        "capture_time_mean_s": float(np.mean([r.metrics["capture_time"] for r in ok]))
        if ok else None,
        "failures": reasons,
        "seconds_per_episode": float(np.mean([r.wall_time_s for r in rows])),
    }


# ---------------------------------------------------------------- plots
@contextlib.contextmanager
def axis_panels(title: str, path: Path):
    """One panel per axis x / y / z; on exit: legend, ``title``, saved to ``path``."""
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    try:
        yield axes
        axes[0].legend(fontsize=8)
        fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)


def plot_trajectories(run: dict, sea: str, path: Path) -> None:
    title = f"AUV position, {sea} sea: measured, true and CKF ([LTAT] Figs. 9/11)"
    with axis_panels(title, path) as axes:
        for k, ax in enumerate(axes):
            ax.plot(run["time"], run["measured"][:, k], ".", ms=2, color="tab:orange",
                    label="measured")
            ax.plot(run["time"], run["truth"][:, k], "-", lw=1.2, color="k", label="true")
            ax.plot(run["time"], run["estimate"][:, k], "-", lw=1.0, color="tab:blue",
                    label="CKF")
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"{AXES[k]} (m)")


def plot_errors(runs: list, sea: str, warmup: float, path: Path) -> None:
    run = runs[0]
    keep = run["time"] >= warmup
    title = f"Mean position error per {BLOCK} frames, {sea} sea ([LTAT] Figs. 10/12)"
    with axis_panels(title, path) as axes:
        for k, ax in enumerate(axes):
            for key, colour in (("measured", "tab:orange"), ("estimate", "tab:blue")):
                err = np.abs(run[key][keep, k] - run["truth"][keep, k])
                n = (len(err) // BLOCK) * BLOCK
                blocks = np.nanmean(err[:n].reshape(-1, BLOCK), axis=1) * 1e3
                offset = -0.2 if key == "measured" else 0.2
                ax.bar(np.arange(len(blocks)) + offset, blocks, width=0.4, color=colour,
                       label="measured" if key == "measured" else "CKF")
            ax.set_xlabel(f"block of {BLOCK} frames")
            ax.set_ylabel(f"|error| {AXES[k]} (mm)")


# ---------------------------------------------------------------- report
def _fmt(values, spec=".1f") -> str:
    return " / ".join(format(v, spec) for v in values)


def _interval(ci, spec=".1f", scale=1.0) -> str:
    """`` [low, high]`` of a 95 % interval; empty where there is none (one value)."""
    if ci is None or not all(math.isfinite(v) for v in ci):
        return ""
    return f" [{format(scale * ci[0], spec)}, {format(scale * ci[1], spec)}]"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/ltat")
    parser.add_argument("--difficulty", choices=LEVELS, default="paper")
    parser.add_argument("--first-seed", type=int, default=DEFAULT_FIRST_SEED,
                        help="tracking seeds N, N+1, ...; attitude N+1000, ...; "
                             "capture N+2000, ... (default %(default)s)")
    parser.add_argument("--seas", default=",".join(SEAS),
                        help="comma-separated sea states (default %(default)s)")
    parser.add_argument("--json", metavar="PATH", help="also write the figures here")
    parser.add_argument("--estimation-episodes", type=int, default=10)
    parser.add_argument("--track-time", type=float, default=20.0)
    parser.add_argument("--warmup", type=float, default=1.0)
    parser.add_argument("--attitude-steps", type=int, default=100)
    parser.add_argument("--capture-episodes", type=int, default=20)
    parser.add_argument("--agents", default="ckf-pd,ltat-ckf-pd",
                        help="capture agents (comma-separated; unregistered ones are skipped)")
    args = parser.parse_args(argv)
    seas = [s for s in args.seas.split(",") if s]
    if not seas or set(seas) - set(SEAS):
        parser.error(f"--seas must name some of {SEAS}, got {args.seas!r}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {"arguments": vars(args)}
    print(f"# [LTAT] reproduction, difficulty {args.difficulty!r}, first seed "
          f"{args.first_seed}\n")

    print("## Position error per axis x / y / z (mm), tracking at 0.8 m (Figs. 9-12)\n")
    print("| sea | frames (bridged) | max range m | measured mean | measured max "
          "| CKF mean | CKF max | 25-frame max measured | 25-frame max CKF |")
    print("|---|---|---|---|---|---|---|---|---|")
    results["estimation"] = {}
    for sea in seas:
        summary, runs = estimation(sea, args.estimation_episodes, args.track_time, args.warmup,
                                   args.difficulty, args.first_seed + ESTIMATION_OFFSET)
        results["estimation"][sea] = summary
        print(f"| {sea} | {summary['frames']} ({summary['bridged_frames']}) "
              f"| {summary['max_range_m']:.2f} | {_fmt(summary['measured_mean_mm'])} "
              f"| {_fmt(summary['measured_max_mm'])} | {_fmt(summary['ckf_mean_mm'])} "
              f"| {_fmt(summary['ckf_max_mm'])} | {_fmt(summary['measured_block25_max_mm'])} "
              f"| {_fmt(summary['ckf_block25_max_mm'])} |")
        plot_trajectories(runs[0], sea, out / f"trajectory_{sea}.png")
        plot_errors(runs, sea, args.warmup, out / f"errors_{sea}.png")

    print("\n## Pitch and yaw at set angles, deg (Tables 2-3)\n")
    print("| set pitch, yaw | frames | eqs. 4-6 mean | eqs. 4-6 max error | refined mean "
          "| refined max error | agent (running mean) |")
    print("|---|---|---|---|---|---|---|")
    results["attitude"] = []
    cases = [(p, 0.0) for p in PITCHES] + [(0.0, y) for y in YAWS]
    for i, (p, y) in enumerate(cases):
        r = attitude(p, y, args.first_seed + ATTITUDE_OFFSET + i, args.attitude_steps,
                     args.difficulty)
        results["attitude"].append(r)
        final = _fmt(r["agent_final"], ".2f") if r["agent_final"] else "-"
        print(f"| {p:g}, {y:g} | {r['frames']} | {_fmt(r['literal_mean'], '.2f')} "
              f"| {_fmt(r['literal_max_abs_error'], '.2f')} | {_fmt(r['refined_mean'], '.2f')} "
              f"| {_fmt(r['refined_max_abs_error'], '.2f')} | {final} |")

    print("\n## Capture\n")
    print("| agent | sea | episodes | success [95 %] | final error mean [95 %] / max mm "
          "| <= 28 mm | capture time s | failures | s/episode |")
    print("|---|---|---|---|---|---|---|---|---|")
    results["capture"] = []
    registered = set(agent_names())
    for name in [a.strip() for a in args.agents.split(",") if a.strip()]:
        if name not in registered:
            print(f"| {name} | - | - | not registered: skipped | | | | | |")
            continue
        for sea in seas:
            r = capture(name, sea, args.capture_episodes, args.difficulty,
                        args.first_seed + CAPTURE_OFFSET)
            results["capture"].append(r)
            err = (f"{r['final_error_mean_mm']:.1f}{_interval(r['final_error_mean_mm_ci95'])}"
                   f" / {r['final_error_max_mm']:.1f}"
                   if r["final_error_mean_mm"] is not None else "-")
            within = f"{r['final_error_le_28mm']:.0%}" if r["final_error_le_28mm"] is not None \
                else "-"
            when = f"{r['capture_time_mean_s']:.1f}" if r["capture_time_mean_s"] else "-"
            success = (f"{r['success_rate']:.0%}"
                       f"{_interval(r['success_rate_ci95'], '.0f', 100.0)}")
            print(f"| {name} | {sea} | {r['episodes']} | {success} | {err} "
                  f"| {within} | {when} | {r['failures'] or '-'} "
                  f"| {r['seconds_per_episode']:.1f} |")

    (out / "ltat.json").write_text(json.dumps(results, indent=2, default=float))
    if args.json:
        write_figures(args.json, results)
    print(f"\nwrote {out / 'ltat.json'} and plots to {out}/")


if __name__ == "__main__":
    main()
