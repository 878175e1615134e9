"""Docking success rates of named agents at a difficulty level, with 95 % Wilson intervals.

    PYTHONPATH=. python scripts/docking_headroom.py --env auv_envs/DockingStation-v2
        --difficulty hard --agents ofnmpc-ekf ofnmpc-state [--episodes 20]
        [--first-seed 620000] [--json PATH]

Episode ``i`` uses seed ``--first-seed + i`` and, in the ``current`` scenario (default),
[OFNMPC]'s current direction ``DIRECTIONS[i % 5]`` (Scenario 2's five directions). The
``hard`` headroom rule (``docs/difficulty.md``): the best non-privileged agent succeeds in
<= 80 % of episodes, a privileged one (``-state``) in >= 90 %.
"""

from __future__ import annotations

import argparse
from collections import Counter

import gymnasium as gym

import auv_envs  # noqa: F401
from auv_envs.core.difficulty import LEVELS
from baselines.evaluation import run_episode, write_figures
from baselines.registry import agent_spec
from baselines.stats import wilson_interval

#: [OFNMPC] Scenario 2's current directions, deg (DS frame).
DIRECTIONS = (0.0, 45.0, 90.0, 135.0, 180.0)


def success_rate(env_id: str, agent: str, difficulty: str, scenario: str, seeds: range) -> dict:
    """Success count, rate, 95 % Wilson interval and failure reasons of ``agent``."""
    spec = agent_spec(agent)
    wins, failures = 0, Counter()
    for i, seed in enumerate(seeds):
        kwargs = {"current_direction": DIRECTIONS[i % len(DIRECTIONS)]} \
            if scenario == "current" else {}
        env = gym.make(env_id, obs_mode=spec.obs_mode, scenario=scenario,
                       difficulty=difficulty, **kwargs)
        try:
            result = run_episode(env, spec.factory(env.unwrapped), seed, env_id, agent)
        finally:
            env.close()
        wins += bool(result.success)
        if not result.success:
            failures[result.metrics["failure_reason"]] += 1
    low, high = wilson_interval(wins, len(seeds))
    return {"success": wins, "episodes": len(seeds), "rate": wins / len(seeds),
            "ci95": [low, high], "failures": dict(failures)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="auv_envs/DockingStation-v2")
    parser.add_argument("--difficulty", choices=LEVELS, default="hard")
    parser.add_argument("--scenario", choices=("mismatch", "current"), default="current")
    parser.add_argument("--agents", nargs="+", default=["ofnmpc-ekf", "ofnmpc-state"])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=620_000,
                        help="episodes use seeds N, N+1, ... (default %(default)s)")
    parser.add_argument("--json", metavar="PATH", help="write the figures here")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    print(f"{args.env}, difficulty {args.difficulty!r}, scenario {args.scenario}, seeds "
          f"{seeds.start}-{seeds.stop - 1}")
    print("| agent | success (95 % interval) | failures |\n|---|---|---|")
    figures: dict = {"env": args.env, "difficulty": args.difficulty, "scenario": args.scenario,
                     "first_seed": args.first_seed, "episodes": args.episodes}
    for agent in args.agents:
        r = success_rate(args.env, agent, args.difficulty, args.scenario, seeds)
        figures[agent] = r
        print(f"| {agent} | {r['success']}/{r['episodes']} ({100 * r['rate']:.0f} %, "
              f"[{100 * r['ci95'][0]:.0f}, {100 * r['ci95'][1]:.0f}] %) | {r['failures']} |",
              flush=True)
    if args.json:
        write_figures(args.json, figures)


if __name__ == "__main__":
    main()
