"""Leaderboard writers: Markdown, CSV, JSON, PNG plots and a static sortable HTML page.

Input is :func:`baselines.evaluation.summarise` output (one row per env, obs
mode, scenario and agent, with ``metrics``: name -> ``{mean, std, n}``) and
the pairs the plan skipped. Each environment gets its own table: its
*headline* metrics are the ones of :data:`HEADLINE_METRICS` (and every
``violation_*_steps`` count) that its rows report, so each task shows its own
measures (SPEC §4; docking: success, time, final deviations, constraint
violations, energy; LARS: capture, position-estimate error; acoustic: RMSE,
maximum error, TFC, TCFE, OSPA). Every file is written atomically; the HTML
page loads nothing from the network (inline CSS and script, plots and clips as
files next to it). The page opens on an overview (per environment and
scenario, the agents ranked with success and one headline metric), then each
environment's full table (scrolling sideways in its own box), its clips and a
plot of the metrics that differ between its agents.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from urllib.parse import quote

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from baselines import aggregate
from baselines.evaluation import jsonable, row_to_dict
from baselines.fileio import atomic_write
from baselines.stats import RANK_METRICS, beaten_ranks, differ, paired_p_value

#: Metrics shown in the tables and plots when an environment reports them:
#: key -> (label, format, which way is better). The final deviations appear as
#: magnitudes (``<key>_abs``, :data:`baselines.evaluation.SIGNED_METRICS`): a
#: signed mean would let a miss to the left cancel a miss to the right.
HEADLINE_METRICS: dict[str, tuple[str, str, str]] = {
    "success": ("success", ".0%", "higher"),
    "return": ("return", ".2f", "higher"),
    "docking_time": ("docking time s", ".1f", "lower"),
    "capture_time": ("capture time s", ".1f", "lower"),
    "final_lateral_error_abs": ("|final lateral| m", ".3f", "lower"),
    "final_vertical_error_abs": ("|final vertical| m", ".3f", "lower"),
    "final_heading_error_deg_abs": ("|final heading| deg", ".1f", "lower"),
    "final_capture_error": ("capture error m", ".3f", "lower"),
    "estimate_error_mean": ("estimate error mean m", ".3f", "lower"),
    "estimate_error_max": ("estimate error max m", ".3f", "lower"),
    "rmse": ("RMSE m", ".3f", "lower"),
    "max_error": ("max error m", ".3f", "lower"),
    "tfc": ("TFC", ".1f", "lower"),
    "tcfe": ("TCFE", ".3f", "lower"),
    "tcfe_fluctuation": ("TCFE 2nd diff", ".3f", "lower"),
    "mean_ospa": ("OSPA m", ".3f", "lower"),
    "control_effort": ("energy (control effort)", ".1f", "lower"),
}

OUTPUT_FILES = ("leaderboard.md", "leaderboard.csv", "leaderboard.json", "leaderboard.html",
                "skipped.json", "episodes.json")


def _violation_label(key: str) -> str:
    return key.removeprefix("violation_").removesuffix("_steps").replace("_", " ") + \
        " violation steps"


def headline_keys(rows: Sequence[Mapping]) -> list[str]:
    """The headline metrics that at least one of ``rows`` reports, in display order."""
    present = {k for r in rows for k in r["metrics"]}
    keys = [k for k in HEADLINE_METRICS if k in present]
    violations = sorted(k for k in present if k.startswith("violation_") and k.endswith("_steps"))
    # Constraint violations go before energy (the last column when present).
    at = keys.index("control_effort") if "control_effort" in keys else len(keys)
    return keys[:at] + violations + keys[at:]


def metric_label(key: str) -> str:
    if key in HEADLINE_METRICS:
        return HEADLINE_METRICS[key][0]
    if key.startswith("violation_") and key.endswith("_steps"):
        return _violation_label(key)
    return key


def _format(key: str, value: float) -> str:
    spec = HEADLINE_METRICS.get(key, ("", ".3g", "lower"))[1]
    return format(value, spec)


def metric_interval(stat: Mapping | None) -> tuple[float, float] | None:
    """The 95 % interval of a summarised metric; None when unreported or a single episode."""
    if stat is None or not stat.get("ci") or stat["ci"][0] is None:
        return None
    low, high = stat["ci"]
    return low, high


def cell_text(row: Mapping, key: str) -> str:
    """``mean [95 % interval]`` of ``row``'s metric ``key`` (``–`` when not reported).

    Success: ``rate (k/n) [Wilson interval]``; a metric of one episode has no
    interval; ``(n=9; 1 NaN)`` follows a mean that leaves out episodes whose value
    was NaN (``NaN (k of k)`` when no episode has a number).
    """
    stat = row["metrics"].get(key)
    if stat is None:
        return "–"
    interval = metric_interval(stat)
    if key == "success":
        text = f"{stat['mean']:.0%} ({round(stat['mean'] * stat['n'])}/{stat['n']})"
        return text if interval is None else f"{text} [{interval[0]:.0%}, {interval[1]:.0%}]"
    nan = stat.get("nan", 0)
    if not stat["n"]:
        return f"NaN ({nan} of {nan})"
    note = f" (n={stat['n']}; {nan} NaN)" if nan else ""
    if interval is None:
        return _format(key, stat["mean"]) + note
    low, high = (_format(key, end) for end in interval)
    return f"{_format(key, stat['mean'])} [{low}, {high}]{note}"




def rank_metric(rows: Sequence[Mapping]) -> tuple[str, str]:
    """``(metric, better)`` that ranks ``rows`` (one environment's)."""
    present = {k for r in rows for k in r["metrics"]}
    return next(((k, d) for k, d in RANK_METRICS if k in present), ("success", "higher"))


def _rank_interval(row: Mapping, key: str) -> tuple[float, float]:
    stat = row["metrics"].get(key)
    if stat is None or not stat["n"]:  # not reported: ranks after every row that reports it
        return math.inf, math.inf
    return metric_interval(stat) or (stat["mean"], stat["mean"])


def is_reference(row: Mapping) -> bool:
    """Whether ``row`` is a reference (a bound, not an agent): shown, never ranked."""
    return bool(row.get("reference"))


def reference_label(row: Mapping) -> str:
    """What a reference row is (its ``label``; ``"bound"`` when it has none)."""
    return str(row.get("label") or "bound")


def is_member(row: Mapping) -> bool:
    """Whether ``row`` is one training seed of a group (ranked as its group's row)."""
    return bool(row.get("group"))


def ranks(rows: Sequence[Mapping]) -> list[tuple[int, bool] | None]:
    """``(rank, tied)`` of each of an environment's rows (in any order) among the rows of
    its scenario (a difficulty level is one); None for a failed row, a reference and a
    group's member (its group row is ranked: :func:`is_member`).

    By :func:`rank_metric`: a row's rank is one more than the number of rows that beat it
    significantly (:func:`baselines.stats.beaten_ranks`, the rows taken best first by the
    metric's mean): on the same seeds by the paired permutation test of the mean
    per-seed difference at 5 %, otherwise by disjoint 95 % intervals
    (:func:`baselines.stats.differ`). ``tied``: another row has its rank.
    """
    key, _ = rank_metric(rows)
    best_first = _sort_key(rows)
    out: list[tuple[int, bool] | None] = [None] * len(rows)
    for scenario in dict.fromkeys(r["scenario"] for r in rows):
        ok = sorted((i for i, r in enumerate(rows) if r["scenario"] == scenario
                     and r["status"] != "failed" and not is_member(r)
                     and not is_reference(r)), key=lambda i: best_first(rows[i]))
        intervals = [_rank_interval(rows[i], key) for i in ok]

        def beats(j, i, ok=ok, intervals=intervals):
            return differ(intervals[j], intervals[i], _paired(rows[ok[j]], rows[ok[i]], key))

        for i, rank in zip(ok, beaten_ranks(len(ok), beats), strict=True):
            out[i] = rank
    return out


def _paired(above: Mapping, row: Mapping, key: str) -> float | None:
    """The paired test's p-value of ``above``'s rank metric against ``row``'s over the
    seeds both played (:func:`baselines.stats.paired_p_value`); None when not paired."""
    a, b = (r.get("by_seed", {}).get(key) for r in (above, row))
    return None if a is None or b is None else paired_p_value(a, b)


def rank_labels(rows: Sequence[Mapping]) -> list[str]:
    """:func:`ranks` as table text: ``"2"``, ``"2 (tie)"``, ``"–"`` for a failed row,
    ``"seed of G"`` for a member of group G."""
    return [f"seed of {row['group']}" if is_member(row) else "bound" if is_reference(row)
            else "–" if r is None
            else f"{r[0]} (tie)" if r[1] else str(r[0]) for row, r in zip(rows, ranks(rows),
                                                                          strict=True)]


def ranked_rows(rows: Sequence[Mapping]) -> list[Mapping]:
    """``rows`` without the members of groups (the overview, the terminal, the plots)."""
    return [r for r in rows if not is_member(r)]


def _sort_key(rows: Sequence[Mapping]):
    """Best first by the mean of ``rows``' :func:`rank_metric`, then higher success rate
    and mean return; failed rows last."""
    key, better = rank_metric(rows)

    def sort_key(row):
        metrics = row["metrics"]
        value = metrics.get(key, {}).get("mean", math.inf if better == "lower" else -math.inf)
        primary = value if better == "lower" else -value
        ret = metrics.get("return", {}).get("mean", -math.inf)
        success = metrics.get("success", {}).get("mean", 0.0)
        return (row["status"] == "failed", primary, -success, -ret, row["agent"])

    return sort_key


def by_env(summary: Sequence[Mapping]) -> dict[str, list[Mapping]]:
    """Rows grouped per environment (first-seen order), scenario by scenario (first-seen
    order), in rank order.

    Within a scenario: by :func:`ranks` (a row that more rows beat comes later), rows of
    one rank by the mean of the environment's :func:`rank_metric` (success rate, or the
    mean OSPA for tracking), then higher success rate and mean return; failed rows last;
    a reference stays beside the rows its metric puts it among. A group's members
    follow its row.
    """
    groups: dict[str, list[Mapping]] = {}
    for row in summary:
        groups.setdefault(row["env_id"], []).append(row)

    def order(rows):
        by_metric = sorted(ranked_rows(rows), key=_sort_key(rows))
        scenarios = list(dict.fromkeys(r["scenario"] for r in rows))  # first seen first
        placed, last = [], {}
        for row, rank in zip(by_metric, ranks(by_metric), strict=True):
            scenario = row["scenario"]  # a reference: where its metric puts it
            last[scenario] = rank[0] if rank else last.get(scenario, 0)
            placed.append((scenarios.index(scenario), row["status"] == "failed",
                           last[scenario]))
        ranked = [row for _, row in sorted(zip(placed, by_metric, strict=True),
                                           key=lambda pair: pair[0])]
        members = sorted((r for r in rows if is_member(r)), key=lambda r: r["agent"])
        out = []
        for row in ranked:  # a group's seeds right after it
            out.append(row)
            out += [m for m in members if m["group"] == row["agent"]
                    and (m["obs_mode"], m["scenario"]) == (row["obs_mode"], row["scenario"])]
        return out + [m for m in members if m not in out]

    return {env_id: order(rows) for env_id, rows in groups.items()}


def _short(env_id: str) -> str:
    return env_id.split("/", 1)[-1]


def _row_name(row: Mapping, rows: Sequence[Mapping]) -> str:
    """The agent's name, with the obs mode / scenario where an env's rows differ in them."""
    parts = [row["agent"]]
    for field in ("obs_mode", "scenario"):
        if len({r[field] for r in rows}) > 1:
            parts.append(row[field])
    return parts[0] if len(parts) == 1 else f"{parts[0]} [{', '.join(parts[1:])}]"


# ------------------------------------------------------------------ markdown
#: The columns of the terminal's compact tables, where an environment reports them.
COMPACT_METRICS = ("success", "docking_time", "final_capture_error", "mean_ospa", "rmse",
                   "max_error", "estimate_error_mean")

INTERVAL_NOTE = ("Each cell: mean [95 % interval] over the episodes (success: Wilson; "
                 "others: percentile bootstrap of the mean). Rank by success rate (tracking: "
                 "by mean OSPA): a row's rank is one more than the number of rows that beat it "
                 "significantly, on the same seeds by a paired permutation test of the "
                 "per-seed difference at 5 %, otherwise by disjoint intervals; (tie): "
                 "another row has the same rank.")


def markdown(summary: Sequence[Mapping], skipped: Sequence[Mapping] = (),
             plots: Mapping[str, str] | None = None, meta: Mapping | None = None,
             compact: bool = False, clips: Clips | None = None) -> str:
    """The leaderboard as Markdown: one table per environment, then the skipped pairs.

    ``compact``: only :data:`COMPACT_METRICS` (the terminal's view). ``clips``
    (see :data:`Clips`): listed as links under each environment's table.
    """
    lines = ["# Leaderboard", ""]
    if meta:
        lines += [f"- {k}: `{v}`" for k, v in meta.items()] + [""]
    lines += [INTERVAL_NOTE, ""]
    for env_id, env_rows in by_env(summary).items():
        keys = headline_keys(env_rows)
        if compact:
            keys = [k for k in COMPACT_METRICS if k in keys]
            env_rows = ranked_rows(env_rows)  # groups without their seeds
        scenarios = by_scenario(env_rows)
        for scenario, rows in scenarios.items():  # one table per scenario (difficulty level)
            title = env_id if len(scenarios) == 1 else f"{env_id} · {scenario}"
            lines += [f"## {title}", ""]
            header = ["rank", "agent", "obs mode", "scenario", "episodes"]
            header += [metric_label(k) for k in keys]
            lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            for row, rank in zip(rows, rank_labels(rows), strict=True):
                cells = [rank, row["agent"], row["obs_mode"], row["scenario"],
                         str(row["episodes"])]
                cells += [cell_text(row, k) for k in keys]
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
            notes = [f"`{r['agent']}`: {reference_label(r)} (a reference, not ranked)."
                     for r in rows if is_reference(r)]
            lines += notes + [""] * bool(notes)
        rows = env_rows
        failed = [r for r in rows if r["failed"]]
        if failed:
            lines.append("")
            for row in failed:
                lines.append(f"- **{row['agent']}** ({row['obs_mode']}, {row['scenario']}): "
                             f"{row['failed']}/{row['episodes']} episodes failed: "
                             + "; ".join(row["errors"]))
        listed = [r for r in rows if clips and clip_key(r) in clips]
        if listed:
            lines += ["", "Clips: " + ", ".join(
                f"[{_row_name(r, rows)}]({quote(clips[clip_key(r)])})" for r in listed)]
        if plots and env_id in plots:
            lines += ["", f"![{env_id}]({plots[env_id]})"]
        lines.append("")
    if skipped:
        lines += ["## Skipped (agent does not apply)", "",
                  "| env | agent | scenario | reason |", "|---|---|---|---|"]
        lines += [f"| {s['env_id']} | {s['agent']} | {s['scenario']} | {s['reason']} |"
                  for s in skipped]
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------- csv
def with_ranks(summary: Sequence[Mapping]) -> list[dict]:
    """``summary``'s rows, each with its ``rank`` (:func:`ranks`; None for a failed row,
    a group's member and a reference) and ``tied`` (another row of its environment and
    scenario has that rank), as the tables show them."""
    ranked = {}
    for rows in by_env(summary).values():
        for row, rank in zip(rows, ranks(rows), strict=True):
            ranked[id(row)] = rank
    return [{**row, "rank": None if ranked.get(id(row)) is None else ranked[id(row)][0],
             "tied": bool(ranked.get(id(row)) and ranked[id(row)][1])} for row in summary]


def csv_text(summary: Sequence[Mapping]) -> str:
    """One line per leaderboard row: its rank and tie (:func:`with_ranks`; empty where it
    is not ranked), then ``<metric>_mean``, ``_std``, ``_ci_low`` and ``_ci_high`` for
    every metric (the interval empty for a single episode)."""
    keys = headline_keys(summary)
    keys += sorted({k for r in summary for k in r["metrics"]} - set(keys))
    summary = with_ranks(summary)
    fields = ["env_id", "obs_mode", "scenario", "agent", "rank", "tied", "episodes", "failed",
              "status", "errors"]
    parts = ("mean", "std", "ci_low", "ci_high")
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(fields + [f"{k}_{s}" for k in keys for s in parts])
    for row in summary:
        values = (["" if row[f] is None else row[f] for f in fields[:-1]]
                  + ["; ".join(row["errors"])])
        for key in keys:
            stat = row["metrics"].get(key)
            if stat is None:
                values += [""] * len(parts)
                continue
            interval = metric_interval(stat)
            ci = ["", ""] if interval is None else [repr(c) for c in interval]
            values += [repr(stat["mean"]), repr(stat["std"]), *ci]
        writer.writerow(values)
    return buffer.getvalue()


# --------------------------------------------------------------------- plots
def _interval_error(stat: Mapping | None) -> tuple[float, float]:
    """Error-bar lengths (below, above the mean) of a metric's interval; 0 without one."""
    interval = metric_interval(stat)
    if interval is None:
        return 0.0, 0.0
    return max(0.0, stat["mean"] - interval[0]), max(0.0, interval[1] - stat["mean"])


def varying_keys(rows: Sequence[Mapping]) -> list[str]:
    """The headline metrics whose mean differs between ``rows`` (the rows that report it).

    A metric with the same mean for every agent (e.g. no agent ever violates a
    constraint: all zeros) tells nothing in a bar chart.
    """
    keys = []
    for key in headline_keys(rows):
        means = {r["metrics"][key]["mean"] for r in rows if key in r["metrics"]}
        if len({m for m in means if not math.isnan(m)}) > 1:
            keys.append(key)
    return keys


def plot_env(env_id: str, rows: Sequence[Mapping]) -> bytes | None:
    """PNG: one horizontal bar chart (mean and 95 % interval) per headline metric
    that varies between the agents (:func:`varying_keys`); None when none does."""
    keys = varying_keys(rows)
    if not keys:
        return None
    ncols = min(3, len(keys))
    nrows = math.ceil(len(keys) / ncols)
    names = [_row_name(r, rows) for r in rows]
    # Fixed margins in inches instead of a layout engine (several times faster):
    # room for the longest bar label left of every axis.
    label_in = 0.07 * max(len(n) for n in names) + 0.25
    axis_in, bar_in = 3.0, 0.3
    width = ncols * (label_in + axis_in) + 0.3
    height_row = bar_in * len(rows) + 0.9
    height = nrows * height_row + 0.8
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=label_in / width, right=1 - 0.3 / width, bottom=0.35 / height,
                        top=1 - 0.8 / height, wspace=label_in / axis_in,
                        hspace=0.75 / (height_row - 0.75))
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax, key in zip(axes, keys, strict=False):
        means = [r["metrics"][key]["mean"] if key in r["metrics"] else math.nan for r in rows]
        errors = [_interval_error(r["metrics"].get(key)) for r in rows]
        positions = list(range(len(rows)))
        ax.barh(positions, means, xerr=list(zip(*errors, strict=True)), color="#4477aa",
                ecolor="#222222", capsize=3)
        finite = [m for m in means if math.isfinite(m)]
        if finite and min(finite) > 0 and max(finite) / min(finite) > 100:
            ax.set_xscale("log")  # e.g. random next to trackers: keep both readable
        for position, row, mean in zip(positions, rows, means, strict=True):
            # No bar is not a zero bar: say so (a bound row states one metric only).
            if not math.isfinite(mean) and not (is_reference(row) and key not in row["metrics"]):
                ax.text(0.01, position, "NaN" if key in row["metrics"] else "not reported",
                        transform=ax.get_yaxis_transform(), va="center", fontsize=7,
                        color="#aa3333")
        ax.set_yticks(positions, names, fontsize=8)
        ax.invert_yaxis()
        better = HEADLINE_METRICS.get(key, ("", "", "lower"))[2]
        scale = ", log scale" if ax.get_xscale() == "log" else ""
        ax.set_title(f"{metric_label(key)} ({better} is better{scale})", fontsize=9)
        ax.tick_params(axis="x", labelsize=8)
        if ax.get_xscale() == "linear":
            ax.xaxis.set_major_locator(MaxNLocator(nbins=4))
        ax.grid(axis="x", alpha=0.3)
    for ax in axes[len(keys):]:
        ax.set_visible(False)
    # Placed in inches from the top, clear of the subplot titles below it.
    fig.suptitle(env_id, fontsize=11, y=1 - 0.12 / height, va="top")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    return buffer.getvalue()


def across_tasks(summary: Sequence[Mapping], episodes: Sequence) -> dict:
    """Per level, :func:`baselines.aggregate.level_view` of the episodes' normalised
    scores (training seeds pooled under their group)."""
    groups = {r["agent"]: r["group"] for r in summary if r.get("group")}
    scores = aggregate.normalised_scores(episodes, summary, groups)
    return {level: aggregate.level_view(by_agent) for level, by_agent in scores.items()}


def plot_across_tasks(level: str, view: Mapping, top: int = 8) -> bytes:
    """PNG: the IQM of every agent's normalised score with its stratified bootstrap
    interval; the performance profiles and the probability of improvement of the
    ``top`` agents by IQM (and ``random``)."""
    agents = sorted(view["agents"], key=lambda a: -view["agents"][a]["iqm"])
    best = [a for a in agents if a != aggregate.RANDOM][:top]
    best += [aggregate.RANDOM] * (aggregate.RANDOM in agents)
    height = max(4.0, 0.3 * max(len(agents), len(best)) + 2.0)
    fig = Figure(figsize=(15.0, height))
    FigureCanvasAgg(fig)
    # Fixed margins in inches: the matrix's rotated names need 1.3 in below it.
    fig.subplots_adjust(left=0.14, right=0.99, bottom=1.3 / height, top=1 - 0.7 / height,
                        wspace=0.45)
    bars, curves, matrix = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.0, 1.0, 1.1]})
    iqms = [view["agents"][a]["iqm"] for a in agents]
    lows = [view["agents"][a]["iqm"] - view["agents"][a]["ci"][0] for a in agents]
    highs = [view["agents"][a]["ci"][1] - view["agents"][a]["iqm"] for a in agents]
    bars.barh(range(len(agents)), iqms, xerr=[lows, highs], color="#4477aa", ecolor="#222222",
              capsize=3)
    bars.set_yticks(range(len(agents)), [f"{a} ({len(view['agents'][a]['tasks'])})"
                                         for a in agents], fontsize=7)
    bars.invert_yaxis()
    bars.axvline(0.0, color="#999999", lw=0.8)
    bars.axvline(1.0, color="#999999", lw=0.8, ls="--")
    bars.set_title("IQM of the normalised score (tasks)", fontsize=9)
    for agent in best:
        curves.plot(view["taus"], view["agents"][agent]["profile"], label=agent, lw=1.2)
    curves.set_xlabel("normalised score τ", fontsize=8)
    curves.set_ylabel("fraction of episodes above τ", fontsize=8)
    curves.set_title("performance profiles", fontsize=9)
    curves.legend(fontsize=6, loc="lower left")
    grid = [[view["improvement"].get((x, y), math.nan) for y in best] for x in best]
    matrix.imshow(grid, vmin=0.0, vmax=1.0, cmap="RdBu", aspect="auto")
    for i, row in enumerate(grid):
        for j, value in enumerate(row):
            if math.isfinite(value):  # light text on the dark ends of the scale
                matrix.text(j, i, f"{value:.2f}", ha="center", va="center", fontsize=6,
                            color="white" if abs(value - 0.5) > 0.3 else "black")
    matrix.set_xticks(range(len(best)), best, rotation=60, ha="right", fontsize=6)
    matrix.set_yticks(range(len(best)), best, fontsize=6)
    matrix.set_title("P(row beats column)", fontsize=9)
    for ax in (bars, curves):
        ax.tick_params(labelsize=7)
        ax.grid(axis="x", alpha=0.3)
    fig.suptitle(f"across tasks: {level} (0: random, 1: the task's reference)", fontsize=11,
                 y=1 - 0.12 / height, va="top")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    return buffer.getvalue()


def _across_markdown(views: Mapping) -> list[str]:
    lines = []
    for level, view in views.items():
        lines += [f"## Across tasks · {level}", "", AGGREGATE_NOTE, "",
                  "| agent | IQM [95 % interval] | tasks | episodes |", "|---|---|---|---|"]
        for agent, stat in sorted(view["agents"].items(), key=lambda kv: -kv[1]["iqm"]):
            lines.append(f"| {agent} | {stat['iqm']:.2f} [{stat['ci'][0]:.2f}, "
                         f"{stat['ci'][1]:.2f}] | {len(stat['tasks'])} | {stat['episodes']} |")
        lines.append("")
    return lines


#: What the across-task figures show, in a sentence.
AGGREGATE_NOTE = ("Normalised score per episode: 0 at `random`'s mean, 1 at the task's "
                  "privileged reference (return) or at the posterior Cramér–Rao bound (RMSE, "
                  "log scale); interquartile mean with a stratified bootstrap 95 % interval "
                  "(`baselines/aggregate.py`).")


# ---------------------------------------------------------------------- html
#: Clips: ``(env_id, agent, obs_mode, scenario)`` -> path of a video relative
#: to the output directory.
Clips = Mapping[tuple[str, str, str, str], str]

_STYLE = """
*, *::before, *::after { box-sizing: border-box; }
body { font-family: system-ui, sans-serif; color: #222; line-height: 1.35;
       max-width: 110rem; margin: 0 auto; padding: 1rem 1.5rem 2rem; }
h1 { font-size: 1.6rem; margin: 0 0 0.25rem; }
h2 { font-size: 1.3rem; margin: 2rem 0 0.5rem; }
h3 { font-size: 1.05rem; margin: 0 0 0.3rem; }
h1, h2, h3, code { overflow-wrap: anywhere; }
a { color: #1f4e9c; }
p.meta { margin: 0 0 0.5rem; color: #555; font-size: 0.85rem; }
p.meta span { margin-right: 1.2rem; }
p.legend { margin: 0 0 0.75rem; color: #444; font-size: 0.9rem; max-width: 60rem; }
section#overview { margin-bottom: 1rem; }
section#overview h2 { margin-top: 1rem; }
.cards { display: grid; gap: 1rem;
         grid-template-columns: repeat(auto-fill, minmax(min(100%, 38rem), 1fr)); }
.card { min-width: 0; border: 1px solid #ccd; border-radius: 6px; padding: 0.6rem 0.75rem;
        background: #fafbff; }
.card .sub { color: #666; font-size: 0.85rem; font-weight: normal; }
.scroll { overflow-x: auto; max-width: 100%; }
table { border-collapse: collapse; margin: 0.5rem 0 1rem; font-size: 0.9rem; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.5rem; }
th { background: #eef; text-align: left; }
table.overview { width: 100%; margin: 0; }
table.overview th, table.overview td { border-width: 0 0 1px; }
table.overview td.rank { font-weight: 600; text-align: center; width: 2.5rem; }
table.overview td.agent { overflow-wrap: anywhere; }
table.overview td.num { white-space: nowrap; }
table.overview th.num { text-align: right; }
.mode { color: #666; font-size: 0.85em; }
.value { white-space: nowrap; }
.ci { color: #666; font-size: 0.85em; white-space: nowrap; }
table.leaderboard th { cursor: pointer; user-select: none; }
table.leaderboard th[aria-sort="ascending"]::after { content: " \\25B2"; }
table.leaderboard th[aria-sort="descending"]::after { content: " \\25BC"; }
table.leaderboard td { white-space: nowrap; }
table.leaderboard td.errors { white-space: normal; min-width: 16rem; }
tr.failed td { background: #fee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
img.plot { display: block; max-width: 100%; height: auto; border: 1px solid #ddd; }
.clips { display: flex; flex-wrap: wrap; gap: 0.75rem; margin: 0 0 1rem; }
.clips figure { margin: 0; width: 320px; max-width: 100%; }
.clips video { display: block; width: 100%; height: auto; background: #000; }
.clips figcaption { font-size: 0.85rem; color: #444; }
.clips .outcome { color: #555; }
code { background: #f4f4f4; padding: 0 0.2rem; }
details { margin: 2rem 0 1rem; }
details summary { cursor: pointer; font-weight: 600; }
@media (max-width: 40rem) {
  body { padding: 0.75rem; }
  .card { padding: 0.4rem 0.3rem; }
  table.overview { font-size: 0.8rem; }
  table.overview th, table.overview td { padding: 0.2rem 0.25rem; }
  table.overview td.rank { width: 1.8rem; }
  table.overview td.agent { min-width: 7.5rem; }
  .ci, .mode { display: block; }
  table.overview td.num { white-space: normal; }
  /* "seed of <group>" wraps instead of widening the detail table */
  table.leaderboard td.rank { white-space: normal; max-width: 8rem; overflow-wrap: break-word; }
}
"""

# Click a header to sort by that column (toggling ascending/descending). Cells
# sort by their data-value (a number) when they have one, else by their text;
# cells without a value always go last.
_SCRIPT = """
document.querySelectorAll("table.leaderboard").forEach(function (table) {
  var headers = table.querySelectorAll("thead th");
  headers.forEach(function (th, column) {
    th.addEventListener("click", function () {
      var order = th.getAttribute("aria-sort") === "ascending" ? "descending" : "ascending";
      headers.forEach(function (h) { h.removeAttribute("aria-sort"); });
      th.setAttribute("aria-sort", order);
      var sign = order === "ascending" ? 1 : -1;
      var body = table.tBodies[0];
      var key = function (row) {
        var cell = row.cells[column];
        if (cell.dataset.value === undefined) { return cell.textContent.trim(); }
        return cell.dataset.value === "" ? null : parseFloat(cell.dataset.value);
      };
      Array.from(body.rows).sort(function (a, b) {
        var x = key(a), y = key(b);
        if (x === null || y === null) { return (x === null) - (y === null); }
        if (typeof x === "number") { return sign * (x - y); }
        return sign * x.localeCompare(y);
      }).forEach(function (row) { body.appendChild(row); });
    });
  });
});
"""

OVERVIEW_NOTE = ("Agents ranked by success rate (tracking: by mean OSPA): a rank is one more than "
                 "the number of agents that beat it at 95 %; =2: another agent shares "
                 "rank 2; –: the agent failed. Each cell: mean "
                 "[95 % interval] over the episodes. Full tables, clips and plots per "
                 "environment below.")


def overview_metric(rows: Sequence[Mapping]) -> str | None:
    """The metric the overview shows beside success for one environment's ``rows``.

    Its ranking metric when that is not success (tracking: mean OSPA), else the first
    of :data:`COMPACT_METRICS` after success that the rows report (docking
    time, capture error); None when they report none.
    """
    key, _ = rank_metric(rows)
    if key != "success":
        return key
    present = {k for r in rows for k in r["metrics"]}
    return next((k for k in COMPACT_METRICS[1:] if k in present), None)


def by_scenario(rows: Sequence[Mapping]) -> dict[str, list[Mapping]]:
    """One environment's rows (best first) per scenario, first-seen order."""
    groups: dict[str, list[Mapping]] = {}
    for row in rows:
        groups.setdefault(row["scenario"], []).append(row)
    return groups


def short_rank(rank: tuple[int, bool] | None) -> str:
    """A :func:`ranks` entry as the overview's text: ``"2"``, ``"=2"`` (tied), ``"–"``."""
    if rank is None:
        return "–"
    return f"={rank[0]}" if rank[1] else str(rank[0])


def _anchor(env_id: str) -> str:
    return "env-" + _short(env_id)


def _cell_html(row: Mapping, key: str) -> str:
    """:func:`cell_text` as HTML: the value unbroken, its interval in a muted span."""
    text, bracket, interval = cell_text(row, key).partition(" [")
    esc = html.escape
    ci = f' <span class="ci">[{esc(interval)}</span>' if bracket else ""
    return f'<span class="value">{esc(text)}</span>{ci}'


def _agent_html(row: Mapping, rows: Sequence[Mapping]) -> str:
    """:func:`_row_name` as HTML: the agent, then its obs mode / scenario muted."""
    name, bracket, rest = _row_name(row, rows).partition(" [")
    esc = html.escape
    return esc(name) + (f' <span class="mode">[{esc(rest)}</span>' if bracket else "")


def _episodes_note(rows: Sequence[Mapping]) -> str:
    counts = sorted({r["episodes"] for r in rows})
    text = str(counts[0]) if len(counts) == 1 else f"{counts[0]}–{counts[-1]}"
    return f"{text} episode{'s' if counts[-1] != 1 else ''} per agent"


def _card_html(env_id: str, scenario: str | None, rows: Sequence[Mapping]) -> str:
    """The overview card of one environment (and scenario): its agents ranked."""
    esc = html.escape
    keys = ["success"] + [k for k in [overview_metric(rows)] if k is not None]
    title = f'<a href="#{esc(_anchor(env_id))}">{esc(_short(env_id))}</a>'
    if scenario is not None:
        title += f" <span class=\"sub\">{esc(scenario)}</span>"
    head = "".join(
        f'<th class="num" title="{esc(HEADLINE_METRICS.get(k, ("", "", "lower"))[2])} is better">'
        f"{esc(metric_label(k))}</th>" for k in keys)
    out = [f'<div class="card" data-env="{esc(env_id)}" '
           f'data-scenario="{esc(rows[0]["scenario"])}">',
           f'<h3>{title} <span class="sub">· {esc(_episodes_note(rows))}</span></h3>',
           '<div class="scroll"><table class="overview"><thead><tr><th>rank</th><th>agent</th>'
           f"{head}</tr></thead><tbody>"]
    for row, rank in zip(rows, ranks(rows), strict=True):
        cells = "".join(f'<td class="num">{_cell_html(row, k)}</td>' for k in keys)
        tie = ' title="tied: another row has this rank"' if rank and rank[1] else ""
        cls = ' class="failed"' if row["status"] == "failed" else ""
        out.append(f'<tr{cls}><td class="rank"{tie}>{esc(short_rank(rank))}</td>'
                   f'<td class="agent">{_agent_html(row, rows)}</td>{cells}</tr>')
    out.append("</tbody></table></div></div>")
    return "\n".join(out)


def overview_html(groups: Mapping[str, Sequence[Mapping]]) -> str:
    """The page's first section: per environment (and scenario, where it has several) a
    card with its agents ranked (:func:`ranks` within the scenario), success and
    :func:`overview_metric`."""
    cards = []
    for env_id, rows in groups.items():
        scenarios = by_scenario(ranked_rows(rows))
        for scenario, subset in scenarios.items():
            cards.append(_card_html(env_id, scenario if len(scenarios) > 1 else None, subset))
    return ('<section id="overview"><h2>Overview</h2>'
            f'<p class="legend">{html.escape(OVERVIEW_NOTE)}</p>'
            '<div class="cards">\n' + "\n".join(cards) + "\n</div></section>")


def _table_html(env_id: str, rows: Sequence[Mapping]) -> str:
    """One environment's full sortable table, in a box that scrolls sideways."""
    esc = html.escape
    keys = headline_keys(rows)
    header = ["rank", "agent", "obs mode", "scenario", "episodes", "failed"]
    header += [metric_label(k) for k in keys] + ["errors"]
    out = [f'<div class="scroll"><table class="leaderboard" data-env="{esc(env_id)}"><thead><tr>'
           + "".join(f"<th>{esc(h)}</th>" for h in header) + "</tr></thead><tbody>"]
    for row, rank, label in zip(rows, ranks(rows), rank_labels(rows), strict=True):
        cls = ' class="failed"' if row["failed"] else ""
        cells = [f'<td class="num rank" data-value="{"" if rank is None else rank[0]}">'
                 f"{esc(label)}</td>"]
        title = f' title="{esc(reference_label(row))}"' if is_reference(row) else ""
        cells.append(f"<td{title}>{esc(str(row['agent']))}</td>")
        cells += [f"<td>{esc(str(row[f]))}</td>" for f in ("obs_mode", "scenario")]
        cells += [f'<td class="num" data-value="{row[f]}">{row[f]}</td>'
                  for f in ("episodes", "failed")]
        for key in keys:
            stat = row["metrics"].get(key)
            value = "" if stat is None else repr(stat["mean"])
            cells.append(f'<td class="num" data-value="{value}">{esc(cell_text(row, key))}</td>')
        cells.append(f'<td class="errors">{esc("; ".join(row["errors"]))}</td>')
        out.append(f"<tr{cls}>" + "".join(cells) + "</tr>")
    out.append("</tbody></table></div>")
    return "\n".join(out)


def clip_key(row: Mapping) -> tuple[str, str, str, str]:
    """A row's key in a clips mapping: ``(env_id, agent, obs_mode, scenario)``."""
    return row["env_id"], row["agent"], row["obs_mode"], row["scenario"]


def clip_outcomes(episodes: Sequence, clips: Clips | None) -> dict[tuple, str]:
    """What each clip's episode came to: ``"success"`` or its failure reason, from the
    first episode of the clip's row (the recorded one: each row records its first seed)."""
    out: dict[tuple, str] = {}
    for episode in episodes:
        key = (episode.env_id, episode.agent, episode.obs_mode, episode.scenario)
        if clips and key in clips and key not in out:
            out[key] = "success" if episode.success else (
                f"failed: {episode.error}" if episode.status != "ok"
                else episode.failure_reason or "no success")
    return out


def _clips_html(rows: Sequence[Mapping], clips: Clips | None,
                outcomes: Mapping[tuple, str] | None = None) -> str:
    """A gallery of the clips of one environment's rows that have one ('' when none),
    each captioned with its row and, where known, how its episode ended."""
    esc = html.escape
    outcomes = outcomes or {}

    def caption(row) -> str:
        outcome = outcomes.get(clip_key(row))
        seed = f"seed {row['seeds'][0]}: " if row.get("seeds") else ""
        return esc(_row_name(row, rows)) + (
            f' <span class="outcome">({esc(seed + outcome)})</span>' if outcome else "")

    # Muted clips may autoplay: the gallery moves as soon as the page opens.
    figures = [f'<figure><video src="{esc(quote(clips[clip_key(row)]))}" width="320" muted loop '
               'playsinline autoplay controls preload="auto"></video>'
               f"<figcaption>{caption(row)}</figcaption></figure>"
               for row in rows if clips and clip_key(row) in clips]
    if not figures:
        return ""
    return '<div class="clips">\n' + "\n".join(figures) + "\n</div>"


def _skipped_html(skipped: Sequence[Mapping]) -> str:
    """The skipped pairs, folded away (they are not results)."""
    esc = html.escape
    rows = "".join(f"<tr><td>{esc(s['env_id'])}</td><td>{esc(s['agent'])}</td>"
                   f"<td>{esc(s['scenario'])}</td><td>{esc(s['reason'])}</td></tr>"
                   for s in skipped)
    return (f'<details id="skipped"><summary>Skipped: {len(skipped)} (environment, agent) '
            "pairs where the agent does not apply</summary>"
            '<div class="scroll"><table class="skipped"><thead><tr><th>env</th><th>agent</th>'
            f"<th>scenario</th><th>reason</th></tr></thead><tbody>{rows}</tbody></table></div>"
            "</details>")


def page(summary: Sequence[Mapping], skipped: Sequence[Mapping] = (),
         plots: Mapping[str, str] | None = None, meta: Mapping | None = None,
         clips: Clips | None = None, outcomes: Mapping[tuple, str] | None = None,
         across: Mapping[str, str] | None = None) -> str:
    """A self-contained HTML page: the overview (:func:`overview_html`) first, then per
    environment a sortable table, its clips (``clips``: see :data:`Clips`, captioned with
    ``outcomes``, :func:`clip_outcomes`) and its plot."""
    esc = html.escape
    groups = by_env(summary)
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">',
           "<title>auv_envs leaderboard</title>", f"<style>{_STYLE}</style></head><body>",
           "<h1>auv_envs leaderboard</h1>"]
    if meta:
        out.append('<p class="meta">' + "".join(
            f"<span>{esc(str(k))}: <code>{esc(str(v))}</code></span>" for k, v in meta.items())
            + "</p>")
    out.append(overview_html(groups))
    out.append('<p class="legend">Intervals: Wilson for success rates, percentile bootstrap of '
               "the mean for the other metrics. Click a column header of a table to sort by "
               "it.</p>")
    for env_id, rows in groups.items():
        out.append(f'<section class="env" id="{esc(_anchor(env_id))}" data-env="{esc(env_id)}">'
                   f"<h2>{esc(env_id)}</h2>")
        out.append(_table_html(env_id, rows))
        out.append(_clips_html(rows, clips, outcomes))
        if plots and env_id in plots:  # a link: on a phone the plot opens at full size
            out.append(f'<a href="{esc(plots[env_id])}"><img class="plot" '
                       f'src="{esc(plots[env_id])}" alt="metrics of {esc(env_id)}"></a>')
        out.append("</section>")
    if across:
        out.append('<section id="across"><h2>Across tasks</h2>'
                   f'<p class="legend">{esc(AGGREGATE_NOTE.replace("`", ""))}</p>')
        out += [f'<a href="{esc(p)}"><img class="plot" src="{esc(p)}" '
                f'alt="across tasks at {esc(level)}"></a>' for level, p in across.items()]
        out.append("</section>")
    if skipped:
        out.append(_skipped_html(skipped))
    out.append(f"<script>{_SCRIPT}</script></body></html>")
    return "\n".join(out)


# --------------------------------------------------------------------- write
def write(out_dir: str | Path, summary: Sequence[Mapping], skipped: Sequence[Mapping] = (),
          episodes: Sequence = (), meta: Mapping | None = None,
          clips: Clips | None = None) -> dict[str, Path]:
    """Write every leaderboard output under ``out_dir``; returns name -> path.

    Files: ``leaderboard.{md,csv,json,html}``, ``skipped.json``,
    ``episodes.json`` (the per-episode rows) and ``plots/<env>.png`` for each
    environment where a metric varies between the agents (:func:`plot_env`; any
    other plot in ``plots/``, an earlier run's, is removed). ``clips``
    (:data:`Clips`, paths relative to ``out_dir``) are shown on the page and
    listed in the Markdown; they are not copied.
    """
    out = Path(out_dir)
    paths: dict[str, Path] = {}
    plots: dict[str, str] = {}
    for env_id, rows in by_env(summary).items():
        rel = f"plots/{_short(env_id)}.png"
        png = plot_env(env_id, ranked_rows(rows))
        if png is None:
            (out / rel).unlink(missing_ok=True)
            continue
        atomic_write(out / rel, png)
        plots[env_id] = rel
        paths[rel] = out / rel
    views = across_tasks(summary, episodes)
    across: dict[str, str] = {}
    for level, view in views.items():
        rel = f"plots/across-tasks-{level}.png"
        atomic_write(out / rel, plot_across_tasks(level, view))
        across[level] = rel
        paths[rel] = out / rel
    texts = {
        "leaderboard.md": "\n".join([markdown(summary, skipped, plots, meta, clips=clips),
                                      *_across_markdown(views),
                                      *(f"![across tasks {lv}]({quote(p)})"
                                        for lv, p in across.items())]),
        "leaderboard.csv": csv_text(summary),
        "leaderboard.json": json.dumps(jsonable(with_ranks(summary)), indent=1),
        "leaderboard.html": page(summary, skipped, plots, meta, clips,
                                 clip_outcomes(episodes, clips), across),
        "skipped.json": json.dumps(list(skipped), indent=1),
        "episodes.json": json.dumps([row_to_dict(r) for r in episodes], indent=1),
    }
    for name, text in texts.items():
        atomic_write(out / name, text)
        paths[name] = out / name
    for stale in (out / "plots").glob("*.png"):  # another board's: never beside this one
        if stale.relative_to(out).as_posix() not in paths:
            stale.unlink()
    return paths
