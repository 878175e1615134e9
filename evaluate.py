"""Evaluate every applicable agent on every registered environment over fixed seeds.

    python evaluate.py [--envs ID ...] [--agents NAME ...] [--episodes N]
                       [--seeds A-B] [--out DIR] [--scenario NAME]

Prints a Markdown table of the metrics and writes the per-episode rows and the
summary as JSON under ``--out``.
"""

from __future__ import annotations

import argparse
import sys

import auv_envs
from baselines.evaluation import (
    default_seeds,
    evaluate,
    format_table,
    parse_seeds,
    summarise,
    write_results,
)
from baselines.registry import agent_names


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", nargs="+", default=list(auv_envs.ENVIRONMENTS),
                        help="environment ids (default: all registered)")
    parser.add_argument("--agents", nargs="+", default=None,
                        help=f"agent names (default: all of {', '.join(agent_names())})")
    parser.add_argument("--episodes", type=int, default=3,
                        help="episodes per (env, agent) when --seeds is not given (default 3)")
    parser.add_argument("--seeds", type=str, default=None,
                        help="evaluation seeds 'A-B' or 'A,B,C' (default: N from 100000)")
    parser.add_argument("--scenario", type=str, default=None,
                        help="scenario passed to every env (default: the env's own default)")
    parser.add_argument("--out", type=str, default="results/evaluate",
                        help="directory for rows.json and summary.json")
    args = parser.parse_args(argv)

    try:
        seeds = parse_seeds(args.seeds) if args.seeds else default_seeds(args.episodes)
        env_kwargs = {"scenario": args.scenario} if args.scenario else None
        rows = evaluate(args.envs, args.agents, seeds, env_kwargs)
    except (ValueError, KeyError) as exc:
        parser.error(str(exc))
    if not rows:
        print("no (env, agent) pair applies; nothing evaluated", file=sys.stderr)
        return 1
    print(format_table(summarise(rows)))
    out = write_results(rows, args.out)
    print(f"\nwrote {len(rows)} episode rows to {out}/rows.json and summary.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
