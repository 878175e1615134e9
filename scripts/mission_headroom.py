"""The docking mission's ``hard`` headroom against the AHRS heading deviation.

Runs agents on ``auv_envs/DockingMission-v0`` at ``difficulty="hard"`` with the level's
navigation sensors, the AHRS's per-episode heading deviation from the station's frame
(``AHRS.heading_bias_std``) replaced by each value of ``--deviations`` (degrees RMS; the
level's own is 8), and prints each agent's success with its 95 % Wilson interval and its
failures. The headroom rule (``docs/mission.md``): the best non-privileged classical agent
docks in at most 80 % of fresh episodes, the privileged reference in at least 90 %.

    PYTHONPATH=. python scripts/mission_headroom.py [--deviations 0 4 8]
        [--agents nav-homing-ofnmpc-ekf] [--layout six_lights] [--episodes 40]
        [--first-seed 720000] [--workers 2] [--json PATH]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

import gymnasium as gym

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.tasks.docking.env import HARD_NAVIGATION
from auv_envs.tasks.docking.mission import LAYOUTS
from baselines.evaluation import run_episode, write_figures
from baselines.registry import agent_spec
from baselines.stats import wilson_interval

ENV_ID = "auv_envs/DockingMission-v0"


def navigation(deviation_deg: float):
    """``hard``'s navigation sensors with the heading deviation ``deviation_deg`` RMS."""
    ahrs = dataclasses.replace(HARD_NAVIGATION.ahrs,
                               heading_bias_std=math.radians(deviation_deg))
    return dataclasses.replace(HARD_NAVIGATION, ahrs=ahrs)


def episode(task: tuple) -> tuple[bool, str]:
    """``(docked, failure reason)`` of one seeded episode."""
    agent, deviation, layout, seed = task
    spec = agent_spec(agent)
    env = gym.make(ENV_ID, obs_mode=spec.obs_mode, difficulty="hard", layout=layout,
                   navigation=navigation(deviation))
    try:
        row = run_episode(env, spec.factory(env.unwrapped), seed, ENV_ID, agent)
    finally:
        env.close()
    return bool(row.success), row.failure_reason


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--deviations", type=float, nargs="+", default=[0.0, 4.0, 8.0],
                        help="AHRS heading deviations to try, degrees RMS")
    parser.add_argument("--agents", nargs="+", default=["nav-homing-ofnmpc-ekf"])
    parser.add_argument("--layout", choices=sorted(LAYOUTS), default="six_lights")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--first-seed", type=int, default=720_000,
                        help="episodes use seeds N, N+1, ... (default %(default)s)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", metavar="PATH", help="write the figures here")
    args = parser.parse_args()
    if args.episodes < 1 or args.workers < 1:
        parser.error("--episodes and --workers must be at least 1")
    if any(not math.isfinite(d) or d < 0 for d in args.deviations):
        parser.error("--deviations must be finite and >= 0")
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    print(f"{ENV_ID}, hard, {args.layout}, seeds {seeds.start}-{seeds.stop - 1}")
    print("| heading deviation (RMS) | agent | docked (95 % interval) | failures |")
    print("|---|---|---|---|")
    figures: dict = {"layout": args.layout, "first_seed": args.first_seed,
                     "episodes": args.episodes, "rows": []}
    with ProcessPoolExecutor(args.workers) as pool:
        for deviation in args.deviations:
            for agent in args.agents:
                tasks = [(agent, deviation, args.layout, seed) for seed in seeds]
                results = list(pool.map(episode, tasks))
                wins = sum(docked for docked, _ in results)
                failures = Counter(reason for docked, reason in results if not docked)
                low, high = wilson_interval(wins, len(results))
                figures["rows"].append({"deviation_deg": deviation, "agent": agent,
                                        "docked": wins, "ci95": [low, high],
                                        "failures": dict(failures)})
                print(f"| {deviation:g}° | {agent} | {wins}/{len(results)} "
                      f"({100 * wins / len(results):.0f} %, [{100 * low:.0f}, "
                      f"{100 * high:.0f}] %) | {dict(failures)} |", flush=True)
    if args.json:
        write_figures(args.json, figures)


if __name__ == "__main__":
    main()
