"""Learning curves of several training seeds, with 95 % bootstrap intervals across seeds.

    python scripts/plot_seeds.py RUN_DIR [RUN_DIR ...] --out curves.png [--csv curves.csv]

Each RUN_DIR is a ``train.py`` run directory (or an exported policy directory):
its ``eval_curve.csv`` holds the held-out evaluations (success rate and mean
return every ``eval_freq`` steps). At every step all runs evaluated at, the
plot shows the mean over the runs and the percentile-bootstrap 95 % interval of
that mean (:func:`baselines.stats.bootstrap_interval`, the leaderboard's
interval), for success and for return; thin lines are the single runs.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from baselines.evaluation import atomic_write
from baselines.stats import bootstrap_interval

METRICS = (("success_rate", "held-out success rate"), ("mean_return", "held-out return"))


def read_curve(run_dir: Path) -> dict[int, dict[str, float]]:
    """step -> {metric: value} of one run's ``eval_curve.csv``."""
    path = Path(run_dir) / "eval_curve.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: is {run_dir} a train.py run directory?")
    with open(path, newline="") as handle:
        return {int(row["step"]): {k: float(row[k]) for k, _ in METRICS}
                for row in csv.DictReader(handle)}


def aggregate(curves: list[dict[int, dict[str, float]]]) -> list[dict]:
    """Per step that every run evaluated at: mean and 95 % interval of each metric."""
    steps = sorted(set.intersection(*(set(c) for c in curves)))
    rows = []
    for step in steps:
        row = {"step": step, "runs": len(curves)}
        for key, _ in METRICS:
            values = [c[step][key] for c in curves]
            low, high = bootstrap_interval(values)
            row.update({key: sum(values) / len(values), f"{key}_low": low, f"{key}_high": high})
        rows.append(row)
    return rows


def plot(curves: list[dict], names: list[str], rows: list[dict], title: str) -> bytes:
    import io

    fig = Figure(figsize=(7, 6))
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 1, sharex=True)
    steps = [r["step"] for r in rows]
    for ax, (key, label) in zip(axes, METRICS, strict=True):
        for curve, name in zip(curves, names, strict=True):
            points = sorted(curve.items())
            ax.plot([s for s, _ in points], [v[key] for _, v in points], lw=0.8, alpha=0.5,
                    label=name)
        ax.plot(steps, [r[key] for r in rows], "o-", color="black", lw=2,
                label=f"mean of {len(curves)} runs")
        low = [r[f"{key}_low"] for r in rows]
        if not all(math.isnan(v) for v in low):
            ax.fill_between(steps, low, [r[f"{key}_high"] for r in rows], color="black",
                            alpha=0.15, label="95 % bootstrap interval")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-0.05, 1.05)
    axes[0].legend(fontsize=7, loc="best")
    axes[0].set_title(title)
    axes[1].set_xlabel("environment steps")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    return buffer.getvalue()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--csv", type=Path, help="also write the aggregated curve as CSV")
    parser.add_argument("--title", default=None)
    args = parser.parse_args(argv)
    try:
        curves = [read_curve(run) for run in args.runs]
    except FileNotFoundError as exc:
        parser.error(str(exc))
    rows = aggregate(curves)
    if not rows:
        parser.error("the runs share no evaluation step (were they trained with one eval_freq?)")
    names = [run.name for run in args.runs]
    atomic_write(args.out, plot(curves, names, rows, args.title or ", ".join(names)))
    if args.csv:
        fields = list(rows[0])
        lines = [",".join(fields)] + [",".join(str(r[f]) for f in fields) for r in rows]
        atomic_write(args.csv, "\n".join(lines) + "\n")
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
