"""The published leaderboard: the full board run and written where the documentation and
the README read it.

    python -m baselines.evaluation.publish [--episodes 30] [--workers N] [--out DIR]

runs ``evaluate.py --episodes 30`` (every agent but the heavy image ones, on today's ids,
at ``paper`` and ``hard``, on the frozen seeds from 100000, acoustic episodes of 30 s)
into ``--out`` (default ``results/published``; its episode cache makes a rerun cheap),
then writes

* ``docs/leaderboard.md``: the board's tables under a header that gives the commit, the
  date, the ids, the levels, the seeds, the episodes and the wall time;
* ``docs/published/leaderboard.json`` and ``.csv`` (each row's rank and tie included)
  and the plots under ``docs/published/plots/``;
* the README's headline table, between :data:`README_START` and :data:`README_END`
  (:func:`headline_table`; ``tests/test_published_board.py`` checks that it is the
  published board's).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from baselines import leaderboard
from baselines.fileio import atomic_write

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
PUBLISHED = DOCS / "published"
PAGE = DOCS / "leaderboard.md"
README = ROOT / "README.md"
README_START = "<!-- headline table: python -m baselines.evaluation.publish writes it -->"
README_END = "<!-- end of the headline table -->"
#: The published board's design: episodes a pair, levels, the acoustic episodes' length.
EPISODES = 30
LEVELS = ("paper", "hard")
ENV_KWARGS = ("AcousticTracking-v2:time_limit=30.0",)


def evaluate_arguments(episodes: int, out: Path, workers: int | None) -> list[str]:
    """``evaluate.py``'s arguments for the published board."""
    argv = ["--episodes", str(episodes), "--difficulty", *LEVELS, "--env-kwargs",
            *ENV_KWARGS, "--no-video", "--no-progress", "--new-board", "--out", str(out)]
    return argv + (["--workers", str(workers)] if workers else [])


def _learned() -> set[str]:
    """The shipped policies and their groups: the learned agents."""
    from baselines.rl.agents import shipped_policy_specs

    specs = shipped_policy_specs()
    return {s.name for s in specs} | {s.group for s in specs if s.group}


def _cell(row: Mapping | None, rank, key: str) -> str:
    """An agent's headline cell: ``key`` (success, or for tracking the mean OSPA, with
    the RMSE beside it), and its rank; a bound gives the RMSE it bounds."""
    if row is None:
        return "–"
    if leaderboard.is_reference(row):
        return f"`{row['agent']}` RMSE ≥ {leaderboard.cell_text(row, 'rmse')} m (a bound)"
    if key == "success":
        text = leaderboard.cell_text(row, key)
    else:
        text = ", ".join(f"{name} {leaderboard.cell_text(row, k)} m" for name, k in
                         (("OSPA", key), ("RMSE", "rmse")) if k in row["metrics"])
    text = f"`{row['agent']}` {text}"
    return text if rank is None else f"{text} (rank {rank[0]})"


def headline_table(summary: Sequence[Mapping]) -> str:
    """The README's headline table from the published board's rows: per environment and
    level, the best classical agent, the best learned agent (each with its rank among the
    level's rows) and the best privileged reference (it reads the true state; ``random``
    is neither), or where there is none the level's bound (acoustic tracking's ``pcrb``,
    a bound of the RMSE)."""
    learned = _learned()
    lines = ["| environment | level | best classical | best learned | privileged reference |",
             "|---|---|---|---|---|"]
    for env_id, rows in leaderboard.by_env(summary).items():
        ranks = dict(zip(map(id, rows), leaderboard.ranks(rows), strict=True))
        key, _ = leaderboard.rank_metric(rows)
        for level in LEVELS:
            at = [r for r in rows if r.get("env_kwargs", {}).get("difficulty") == level
                  and r["status"] != "failed" and not leaderboard.is_member(r)
                  and not leaderboard.is_reference(r) and r["agent"] != "random"]
            if not at:
                continue
            privileged = [r for r in at if r["obs_mode"] == "state"] or [
                r for r in rows if leaderboard.is_reference(r)
                and r.get("env_kwargs", {}).get("difficulty") == level]  # a bound
            sensing = [r for r in at if r["obs_mode"] != "state"]
            classical = next((r for r in sensing if r["agent"] not in learned), None)
            rl = next((r for r in sensing if r["agent"] in learned), None)
            reference = privileged[0] if privileged else None
            lines.append(f"| `{env_id.split('/')[-1]}` | `{level}` | "
                         f"{_cell(classical, classical and ranks[id(classical)], key)} | "
                         f"{_cell(rl, rl and ranks[id(rl)], key)} | "
                         f"{_cell(reference, None, key)} |")
    return "\n".join(lines)


def readme_with(table: str, readme: str) -> str:
    """``readme`` with ``table`` between its markers (ValueError when they are missing)."""
    start, end = readme.find(README_START), readme.find(README_END)
    if start < 0 or end < start:
        raise ValueError(f"the README has no headline-table markers ({README_START!r} ... "
                         f"{README_END!r})")
    return readme[:start + len(README_START)] + "\n" + table + "\n" + readme[end:]


def readme_table(readme: str) -> str:
    """The table between the README's markers."""
    start, end = readme.find(README_START), readme.find(README_END)
    return readme[start + len(README_START):end].strip()


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                          check=False).stdout.strip()


def _dirty() -> str:
    """`` (with uncommitted changes)`` where the package code or assets differ from the
    commit."""
    return (" (with uncommitted changes)"
            if _git("status", "--porcelain", "--", "auv_envs", "baselines", "assets") else "")


def page(body: str, summary: Sequence[Mapping], run: Mapping, argv: Sequence[str]) -> str:
    """``docs/leaderboard.md``: a header (what was run, where, when) over the board."""
    ids = sorted({r["env_id"] for r in summary})
    episodes = sum(r["episodes"] for r in summary
                   if not leaderboard.is_member(r) and not leaderboard.is_reference(r))
    seeds = sorted({s for r in summary for s in r.get("seeds", [])})
    written = _git("rev-parse", "--short", "HEAD") + _dirty()
    header = [
        "# The published leaderboard",
        "",
        "Every agent but the heavy image front ends (about a minute an episode; `--all-agents`",
        "adds them), each at `paper` and `hard`, 30 episodes a pair, every training seed of",
        "an RL group (a group's row pools them); ranks and intervals as on every board",
        "([`evaluation.md`](evaluation.md)). Rows observing `state` read the true state:",
        "they are references, not competitors. The `pcrb` rows are a bound (the posterior",
        "Cramér–Rao bound of each episode's trajectory), not an agent.",
        "",
        f"- command: `python -m baselines.evaluation.publish` (that is, `python evaluate.py "
        f"{' '.join(argv)}`)",
        f"- commit: `{run['commit']}` (the episodes; the tables written at `{written}`); "
        f"date: {datetime.date.today().isoformat()}",
        f"- ids: {', '.join(f'`{i}`' for i in ids)}",
        f"- levels: {', '.join(f'`{level}`' for level in LEVELS)}; seeds "
        f"{seeds[0]}–{seeds[-1]} (frozen); {episodes:,} episodes",
        f"- wall time: {run['wall_s'] / 60:.1f} min on {os.cpu_count()} cores, "
        f"{run['ran']:,} episodes run (the others, if any, from the episode cache)",
        "- the same rows, each with its rank and tie: [`published/leaderboard.json`]"
        "(published/leaderboard.json), [`published/leaderboard.csv`]"
        "(published/leaderboard.csv)",
        "",
        "",
    ]
    # The run's own title and metadata (an absolute --out) give way to the header above.
    body = body[body.index(leaderboard.INTERVAL_NOTE):]
    body = body.replace("](plots/", "](published/plots/")
    return "\n".join(header) + body


def render(out: Path, argv: Sequence[str]) -> list[dict]:
    """The board in ``out`` written again from its episodes (``episodes.json``) with this
    code's summary, ranks and tables (no episode runs): its summary rows."""
    from baselines.evaluation import bound_rows, row_from_dict, summarise
    from baselines.registry import agent_groups

    rows = [row_from_dict(row) for row in json.loads((out / "episodes.json").read_text())]
    skipped = json.loads((out / "skipped.json").read_text())
    summary = summarise(rows, agent_groups())
    summary += bound_rows(summary)
    meta = {"command": f"python evaluate.py {' '.join(argv)}"}
    leaderboard.write(out, summary, skipped, rows, meta)
    return summary


def publish(out: Path, run: Mapping, argv: Sequence[str]) -> None:
    """Write the board in ``out`` (:func:`render`) to the docs and the README."""
    render(out, argv)
    summary = json.loads((out / "leaderboard.json").read_text())
    PUBLISHED.mkdir(parents=True, exist_ok=True)
    for name in ("leaderboard.json", "leaderboard.csv"):
        shutil.copy2(out / name, PUBLISHED / name)
    shutil.rmtree(PUBLISHED / "plots", ignore_errors=True)
    shutil.copytree(out / "plots", PUBLISHED / "plots")
    body = (out / "leaderboard.md").read_text()
    atomic_write(PAGE, page(body, summary, run, argv).encode())
    table = headline_table(summary)
    atomic_write(README, readme_with(table, README.read_text()).encode())


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m baselines.evaluation.publish",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=EPISODES)
    parser.add_argument("--workers", type=int, default=None,
                        help="evaluate.py's --workers (default: its own)")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "published")
    parser.add_argument("--write-only", action="store_true",
                        help="write the board already in --out again from its episodes "
                             "(this code's ranks and tables), evaluate nothing")
    args = parser.parse_args(argv)
    evaluate_argv = evaluate_arguments(args.episodes, args.out, args.workers)
    record = args.out / "evaluation.json"  # the evaluation's wall time and episodes run
    if not args.write_only:
        from baselines.commands.evaluate import main as evaluate

        commit = _git("rev-parse", "--short", "HEAD") + _dirty()
        cache = args.out / "episodes"
        before = len(list(cache.glob("*"))) if cache.is_dir() else 0
        start = time.perf_counter()
        code = evaluate(evaluate_argv, prog="python evaluate.py")
        if code:
            return code
        wall = time.perf_counter() - start
        ran = len(list(cache.glob("*"))) - before
        atomic_write(record, json.dumps({"wall_s": round(wall, 1), "ran": ran,
                                         "commit": commit}) + "\n")
    if not record.is_file():
        parser.error(f"no evaluation in {args.out} ({record.name} is missing): run without "
                     "--write-only first")
    run = json.loads(record.read_text())
    shown = evaluate_arguments(args.episodes, Path("results/published"), args.workers)
    publish(args.out, run, shown)
    print(f"wrote {PAGE.relative_to(ROOT)}, {PUBLISHED.relative_to(ROOT)}/ and the README's "
          f"headline table ({run['wall_s'] / 60:.1f} min)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
