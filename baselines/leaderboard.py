"""Leaderboard writers: Markdown, CSV, JSON, PNG plots and a static sortable HTML page.

Input is :func:`baselines.evaluation.summarise` output (one row per env, obs
mode, scenario and agent, with ``metrics``: name -> ``{mean, std, n}``) and
the pairs the plan skipped. Each environment gets its own table: its
*headline* metrics are the ones of :data:`HEADLINE_METRICS` (and every
``violation_*_steps`` count) that its rows report, so each task shows its own
measures (SPEC §4; docking: success, time, final deviations, constraint
violations, energy; LARS: capture, position-estimate error; acoustic: RMSE,
maximum error, TFC, TCFE, OSPA). Every file is written atomically; the HTML
page loads nothing from the network (inline CSS and script, plots as files
next to it).
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from baselines.evaluation import atomic_write, jsonable, row_to_dict
from baselines.stats import tied_ranks

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
    interval.
    """
    stat = row["metrics"].get(key)
    if stat is None:
        return "–"
    interval = metric_interval(stat)
    if key == "success":
        text = f"{stat['mean']:.0%} ({round(stat['mean'] * stat['n'])}/{stat['n']})"
        return text if interval is None else f"{text} [{interval[0]:.0%}, {interval[1]:.0%}]"
    if interval is None:
        return _format(key, stat["mean"])
    low, high = (_format(key, end) for end in interval)
    return f"{_format(key, stat['mean'])} [{low}, {high}]"


#: What ranks an environment's agents: the first of these its rows report, with
#: the direction that is better. Tracking tasks rank by RMSE (every tracker
#: "succeeds" at following the target); the others by success rate.
RANK_METRICS = (("rmse", "lower"), ("success", "higher"))


def rank_metric(rows: Sequence[Mapping]) -> tuple[str, str]:
    """``(metric, better)`` that ranks ``rows`` (one environment's)."""
    present = {k for r in rows for k in r["metrics"]}
    return next(((k, d) for k, d in RANK_METRICS if k in present), ("success", "higher"))


def _rank_interval(row: Mapping, key: str) -> tuple[float, float]:
    stat = row["metrics"].get(key)
    if stat is None:  # not reported: ranks after every row that reports it
        return math.inf, math.inf
    return metric_interval(stat) or (stat["mean"], stat["mean"])


def ranks(rows: Sequence[Mapping]) -> list[tuple[int, bool] | None]:
    """``(rank, tied)`` of each of an environment's rows (sorted best first by
    :func:`by_env`); None for a failed row.

    By :func:`rank_metric`: a row whose 95 % interval overlaps the one above it
    shares its rank (a tie).
    """
    key, _ = rank_metric(rows)
    ok = [r for r in rows if r["status"] != "failed"]
    ranked = iter(tied_ranks([_rank_interval(r, key) for r in ok]))
    return [None if row["status"] == "failed" else next(ranked) for row in rows]


def rank_labels(rows: Sequence[Mapping]) -> list[str]:
    """:func:`ranks` as table text: ``"2"``, ``"2 (tie)"``, ``"–"`` for a failed row."""
    return ["–" if r is None else f"{r[0]} (tie)" if r[1] else str(r[0]) for r in ranks(rows)]


def by_env(summary: Sequence[Mapping]) -> dict[str, list[Mapping]]:
    """Rows grouped per environment (first-seen order), best first.

    Best: better mean of the environment's :func:`rank_metric` (success rate,
    or RMSE for tracking), then higher success rate and mean return; failed
    rows last.
    """
    groups: dict[str, list[Mapping]] = {}
    for row in summary:
        groups.setdefault(row["env_id"], []).append(row)

    def order(rows):
        key, better = rank_metric(rows)

        def rank(row):
            metrics = row["metrics"]
            value = metrics.get(key, {}).get("mean", math.inf if better == "lower" else -math.inf)
            primary = value if better == "lower" else -value
            ret = metrics.get("return", {}).get("mean", -math.inf)
            return (row["status"] == "failed", primary, -metrics["success"]["mean"], -ret,
                    row["agent"])

        return sorted(rows, key=rank)

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
COMPACT_METRICS = ("success", "docking_time", "final_capture_error", "rmse", "max_error",
                   "estimate_error_mean")

INTERVAL_NOTE = ("Each cell: mean [95 % interval] over the episodes (success: Wilson; "
                 "others: percentile bootstrap of the mean). Rank by success rate (tracking: "
                 "by RMSE); rows whose intervals overlap share a rank (tie).")


def markdown(summary: Sequence[Mapping], skipped: Sequence[Mapping] = (),
             plots: Mapping[str, str] | None = None, meta: Mapping | None = None,
             compact: bool = False) -> str:
    """The leaderboard as Markdown: one table per environment, then the skipped pairs.

    ``compact``: only :data:`COMPACT_METRICS` (the terminal's view).
    """
    lines = ["# Leaderboard", ""]
    if meta:
        lines += [f"- {k}: `{v}`" for k, v in meta.items()] + [""]
    lines += [INTERVAL_NOTE, ""]
    for env_id, rows in by_env(summary).items():
        keys = headline_keys(rows)
        if compact:
            keys = [k for k in COMPACT_METRICS if k in keys]
        lines += [f"## {env_id}", ""]
        header = ["rank", "agent", "obs mode", "scenario", "episodes"]
        header += [metric_label(k) for k in keys]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for row, rank in zip(rows, rank_labels(rows), strict=True):
            cells = [rank, row["agent"], row["obs_mode"], row["scenario"], str(row["episodes"])]
            cells += [cell_text(row, k) for k in keys]
            lines.append("| " + " | ".join(cells) + " |")
        failed = [r for r in rows if r["failed"]]
        if failed:
            lines.append("")
            for row in failed:
                lines.append(f"- **{row['agent']}** ({row['obs_mode']}, {row['scenario']}): "
                             f"{row['failed']}/{row['episodes']} episodes failed: "
                             + "; ".join(row["errors"]))
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
def csv_text(summary: Sequence[Mapping]) -> str:
    """One line per leaderboard row; ``<metric>_mean``, ``_std``, ``_ci_low`` and
    ``_ci_high`` for every metric (the interval empty for a single episode)."""
    keys = headline_keys(summary)
    keys += sorted({k for r in summary for k in r["metrics"]} - set(keys))
    fields = ["env_id", "obs_mode", "scenario", "agent", "episodes", "failed", "status", "errors"]
    parts = ("mean", "std", "ci_low", "ci_high")
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(fields + [f"{k}_{s}" for k in keys for s in parts])
    for row in summary:
        values = [row[f] for f in fields[:-1]] + ["; ".join(row["errors"])]
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


def plot_env(env_id: str, rows: Sequence[Mapping]) -> bytes:
    """PNG: one horizontal bar chart (mean and 95 % interval) per headline metric."""
    keys = [k for k in headline_keys(rows) if any(k in r["metrics"] for r in rows)]
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
    fig.suptitle(env_id, fontsize=11)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    return buffer.getvalue()


# ---------------------------------------------------------------------- html
_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5rem; color: #222; }
table { border-collapse: collapse; margin: 0.5rem 0 1rem; font-size: 0.9rem; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.5rem; }
th { background: #eef; }
table.leaderboard th { cursor: pointer; user-select: none; }
table.leaderboard th[aria-sort="ascending"]::after { content: " \\25B2"; }
table.leaderboard th[aria-sort="descending"]::after { content: " \\25BC"; }
tr.failed td { background: #fee; }
table.leaderboard td { white-space: nowrap; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
img.plot { max-width: 100%; border: 1px solid #ddd; }
code { background: #f4f4f4; padding: 0 0.2rem; }
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


def page(summary: Sequence[Mapping], skipped: Sequence[Mapping] = (),
         plots: Mapping[str, str] | None = None, meta: Mapping | None = None) -> str:
    """A self-contained HTML page: per environment a sortable table and its plot."""
    esc = html.escape
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           "<title>auv_envs leaderboard</title>", f"<style>{_STYLE}</style></head><body>",
           "<h1>auv_envs leaderboard</h1>"]
    if meta:
        out.append("<ul>" + "".join(f"<li>{esc(str(k))}: <code>{esc(str(v))}</code></li>"
                                    for k, v in meta.items()) + "</ul>")
    out.append(f"<p>{esc(INTERVAL_NOTE)} Click a column header to sort.</p>")
    for env_id, rows in by_env(summary).items():
        keys = headline_keys(rows)
        out.append(f"<h2>{esc(env_id)}</h2>")
        out.append(f'<table class="leaderboard" data-env="{esc(env_id)}"><thead><tr>')
        header = ["rank", "agent", "obs mode", "scenario", "episodes", "failed"]
        header += [metric_label(k) for k in keys] + ["errors"]
        out.append("".join(f"<th>{esc(h)}</th>" for h in header) + "</tr></thead><tbody>")
        for row, rank, label in zip(rows, ranks(rows), rank_labels(rows), strict=True):
            cls = ' class="failed"' if row["failed"] else ""
            cells = [f'<td class="num" data-value="{"" if rank is None else rank[0]}">'
                     f"{esc(label)}</td>"]
            cells += [f"<td>{esc(str(row[f]))}</td>" for f in ("agent", "obs_mode", "scenario")]
            cells += [f'<td class="num" data-value="{row[f]}">{row[f]}</td>'
                      for f in ("episodes", "failed")]
            for key in keys:
                stat = row["metrics"].get(key)
                value = "" if stat is None else repr(stat["mean"])
                cells.append(f'<td class="num" data-value="{value}">'
                             f"{esc(cell_text(row, key))}</td>")
            cells.append(f"<td>{esc('; '.join(row['errors']))}</td>")
            out.append(f"<tr{cls}>" + "".join(cells) + "</tr>")
        out.append("</tbody></table>")
        if plots and env_id in plots:
            out.append(f'<img class="plot" src="{esc(plots[env_id])}" '
                       f'alt="metrics of {esc(env_id)}">')
    if skipped:
        out.append("<h2>Skipped (agent does not apply)</h2>")
        out.append('<table class="skipped"><thead><tr><th>env</th><th>agent</th>'
                   "<th>scenario</th><th>reason</th></tr></thead><tbody>")
        out += [f"<tr><td>{esc(s['env_id'])}</td><td>{esc(s['agent'])}</td>"
                f"<td>{esc(s['scenario'])}</td><td>{esc(s['reason'])}</td></tr>" for s in skipped]
        out.append("</tbody></table>")
    out.append(f"<script>{_SCRIPT}</script></body></html>")
    return "\n".join(out)


# --------------------------------------------------------------------- write
def write(out_dir: str | Path, summary: Sequence[Mapping], skipped: Sequence[Mapping] = (),
          episodes: Sequence = (), meta: Mapping | None = None) -> dict[str, Path]:
    """Write every leaderboard output under ``out_dir``; returns name -> path.

    Files: ``leaderboard.{md,csv,json,html}``, ``skipped.json``,
    ``episodes.json`` (the per-episode rows) and ``plots/<env>.png``.
    """
    out = Path(out_dir)
    paths: dict[str, Path] = {}
    plots: dict[str, str] = {}
    for env_id, rows in by_env(summary).items():
        rel = f"plots/{_short(env_id)}.png"
        atomic_write(out / rel, plot_env(env_id, rows))
        plots[env_id] = rel
        paths[rel] = out / rel
    texts = {
        "leaderboard.md": markdown(summary, skipped, plots, meta),
        "leaderboard.csv": csv_text(summary),
        "leaderboard.json": json.dumps(jsonable(list(summary)), indent=1),
        "leaderboard.html": page(summary, skipped, plots, meta),
        "skipped.json": json.dumps(list(skipped), indent=1),
        "episodes.json": json.dumps([row_to_dict(r) for r in episodes], indent=1),
    }
    for name, text in texts.items():
        atomic_write(out / name, text)
        paths[name] = out / name
    return paths
