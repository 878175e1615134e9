"""Per agent and level, the acoustic tracking episodes of an ``evaluate.py`` run: the
board's ranking metric (mean OSPA), the mean and the median of the episodes' RMSE, each
with a 95 % bootstrap interval over the episodes (SciPy's ``bootstrap``, percentile,
10,000 resamples, seeded). Training seeds of one shipped group (``NAME-s0``, ``NAME-s1``
...) are pooled as the leaderboard pools them.

    python evaluate.py --agents cppo-acoustic-track ls-kf --envs AcousticTracking-v2 \\
        --difficulty paper hard --seeds 852000-852029 --no-video --out DIR --new-board
    python scripts/tracking_summary.py DIR/episodes.json
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
from scipy import stats

#: A training seed's suffix on a shipped policy's name.
SEED_SUFFIX = re.compile(r"-s\d+$")


def _interval(values: np.ndarray, statistic) -> tuple[float, float]:
    if len(values) < 2:
        return float("nan"), float("nan")
    result = stats.bootstrap((values,), statistic, n_resamples=10_000, method="percentile",
                             random_state=np.random.default_rng(0))
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


def summary(episodes: list[dict]) -> list[dict]:
    """One row per (level, agent group): episodes, mean OSPA, mean and median RMSE, each
    with its interval; sorted by level, then mean OSPA."""
    groups: dict[tuple[str, str], dict[str, list[float]]] = {}
    for ep in episodes:
        if not ep["env_id"].startswith("auv_envs/AcousticTracking") or ep["status"] != "ok":
            continue
        key = (ep["env_kwargs"].get("difficulty", "paper"), SEED_SUFFIX.sub("", ep["agent"]))
        values = groups.setdefault(key, {"rmse": [], "mean_ospa": []})
        for name in values:
            values[name].append(float(ep["metrics"][name]))
    rows = []
    for (level, agent), values in groups.items():
        rmse, ospa = np.array(values["rmse"]), np.array(values["mean_ospa"])
        rows.append({"level": level, "agent": agent, "episodes": len(rmse),
                     "mean_ospa": float(ospa.mean()), "mean_ospa_ci": _interval(ospa, np.mean),
                     "mean_rmse": float(rmse.mean()), "mean_rmse_ci": _interval(rmse, np.mean),
                     "median_rmse": float(np.median(rmse)),
                     "median_rmse_ci": _interval(rmse, np.median)})
    return sorted(rows, key=lambda r: (r["level"], r["mean_ospa"]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("episodes", type=Path, help="an evaluate.py run's episodes.json")
    args = parser.parse_args(argv)
    rows = summary(json.loads(args.episodes.read_text()))
    if not rows:
        raise SystemExit(f"no acoustic tracking episodes in {args.episodes}")
    print("| level | agent | episodes | mean OSPA m | mean RMSE m | median RMSE m |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        cells = [f"{r[k]:.3f} [{r[k + '_ci'][0]:.3f}, {r[k + '_ci'][1]:.3f}]"
                 for k in ("mean_ospa", "mean_rmse", "median_rmse")]
        print(f"| {r['level']} | `{r['agent']}` | {r['episodes']} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
