"""How stable the order of the acoustic trackers is under candidate ranking metrics, on
disjoint sets of seeds: the evidence behind the acoustic board's ranking metric
(``docs/evaluation.md``, "Ranking acoustic tracking").

    python evaluate.py --envs AcousticTracking-v2 --agents gmphd-gci ls-kf \\
        ppo-acoustic-measurements-s0 cppo-acoustic-measurements-s0 --difficulty paper hard \\
        --seeds <set A>,<set B> --env-kwargs time_limit=30.0 --no-video --out DIR
    python scripts/acoustic_rank_stability.py DIR/episodes.json \\
        --sets 500000-500019 510000-510019

For each level, set and candidate metric it prints the trackers' order by the metric's
point value and their ranks (one more than the number of trackers that beat one at 95 %,
paired on the set's seeds: :func:`baselines.stats.beaten_ranks`), then whether the order
and the ranks are the same on every set, and per set the share of its one-seed-out
subsets that keep its order (how far a single episode decides it). The candidates, each
over a set's episodes:

* ``mean_rmse``: the mean of the episodes' RMSE (the board's metric before this study);
* ``median_rmse``: their median (ranks: the paired test on the per-seed RMSE);
* ``trimmed_rmse``: their mean with the best and worst 10 % left out (likewise);
* ``mean_ospa``: the mean of the episodes' mean OSPA with its cut-off (the env's
  ``error_clip``, 5 m): a step's error counts at most the cut-off;
* ``success``: the share of episodes whose RMSE is within the env's ``success_radius``.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
from scipy import stats

from baselines.commands.evaluate import parse_seeds
from baselines.stats import ALPHA, beaten_ranks, paired_p_value

#: metric -> (the per-episode value it reads, its point value over episodes, better)
CANDIDATES: dict[str, tuple[str, Callable[[np.ndarray], float], str]] = {
    "mean_rmse": ("rmse", np.mean, "lower"),
    "median_rmse": ("rmse", np.median, "lower"),
    "trimmed_rmse": ("rmse", lambda v: stats.trim_mean(v, 0.1), "lower"),
    "mean_ospa": ("mean_ospa", np.mean, "lower"),
    "success": ("success", np.mean, "higher"),
}


def _values(episodes: Sequence[Mapping], level: str, seeds: Sequence[int], key: str
            ) -> dict[str, dict[str, float]]:
    """agent -> seed -> the episode's ``key``, for one level and set of seeds."""
    wanted = set(seeds)
    values: dict[str, dict[str, float]] = {}
    for ep in episodes:
        if ep["env_kwargs"].get("difficulty") == level and ep["seed"] in wanted \
                and ep["status"] == "ok":
            values.setdefault(ep["agent"], {})[str(ep["seed"])] = float(ep["metrics"][key])
    return values


def _order(values: Mapping[str, Mapping[str, float]], metric: str) -> list[tuple[str, float]]:
    """``(agent, point value)`` best first by ``metric``."""
    _, point, better = CANDIDATES[metric]
    sign = 1.0 if better == "lower" else -1.0
    points = [(a, float(point(np.array(list(v.values()))))) for a, v in values.items()]
    return sorted(points, key=lambda t: sign * t[1])


def table(episodes: Sequence[Mapping], level: str, seeds: Sequence[int], metric: str
          ) -> list[tuple[str, float, int]]:
    """``(agent, point value, rank)`` best first, for one level, set and metric."""
    values = _values(episodes, level, seeds, CANDIDATES[metric][0])
    order = _order(values, metric)

    def beats(j, i):
        p = paired_p_value(values[order[j][0]], values[order[i][0]])
        return p is not None and p < ALPHA

    ranks = beaten_ranks(len(order), beats)
    return [(a, v, r[0]) for (a, v), r in zip(order, ranks, strict=True)]


def one_episode_robustness(episodes: Sequence[Mapping], level: str, seeds: Sequence[int],
                           metric: str) -> float:
    """The share of the set's one-seed-out subsets whose order (by the point value) is the
    whole set's: 1 when no single episode decides the order."""
    def order(subset):
        return [a for a, _ in _order(_values(episodes, level, subset, CANDIDATES[metric][0]),
                                     metric)]

    whole = order(seeds)
    return sum(order([s for s in seeds if s != left]) == whole for left in seeds) / len(seeds)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("episodes", type=Path, help="an evaluate.py run's episodes.json")
    parser.add_argument("--sets", nargs="+", required=True, metavar="SEEDS",
                        help="disjoint seed sets, each 'A-B' or 'A,B,C'")
    parser.add_argument("--levels", nargs="+", default=["paper", "hard"])
    args = parser.parse_args(argv)
    episodes = [e for e in json.loads(args.episodes.read_text())
                if e["env_id"].startswith("auv_envs/AcousticTracking")]
    sets = [parse_seeds(text) for text in args.sets]
    print("| level | metric | " + " | ".join(f"set {i + 1}: order (rank)" for i in
                                              range(len(sets)))
          + " | same order | same ranks | one-episode robustness |")
    print("|---|---|" + "---|" * len(sets) + "---|---|---|")
    for level in args.levels:
        for metric in CANDIDATES:
            tables = [table(episodes, level, seeds, metric) for seeds in sets]
            cells = [", ".join(f"`{a}` {v:.3g} ({r})" for a, v, r in t) for t in tables]
            orders = {tuple(a for a, _, _ in t) for t in tables}
            ranks = {tuple(sorted((a, r) for a, _, r in t)) for t in tables}
            robust = [one_episode_robustness(episodes, level, seeds, metric)
                      for seeds in sets]
            print(f"| {level} | {metric} | " + " | ".join(cells)
                  + f" | {'yes' if len(orders) == 1 else 'no'}"
                  f" | {'yes' if len(ranks) == 1 else 'no'}"
                  f" | {', '.join(f'{r:.0%}' for r in robust)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
