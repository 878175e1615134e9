"""evaluate.py end to end: the leaderboard files, resuming, the HTML page in Chromium, Ray."""

from __future__ import annotations

import csv
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

import evaluate
from baselines import leaderboard
from baselines.evaluation import evaluate_all, row_to_dict, summarise
from baselines.stats import wilson_interval
from tests.conftest import DOCKING_IDS

DOCK = DOCKING_IDS[0]
LARS = "auv_envs/LARSCapture-v0"
TINY = ["--envs", DOCK, "LARSCapture-v0", "--agents", "random", "pd-state",
        "--seeds", "100000-100001", "--env-kwargs", "time_limit=20", "--workers", "1",
        "--no-progress"]
#: (env, agent) pairs of the tiny run; pd-state does not apply to LARS.
PAIRS = {(DOCK, "random"), (DOCK, "pd-state"), (LARS, "random")}
CHROMIUM = "/usr/bin/chromium"
#: Flags that keep Chromium quiet on a closed network (FACTS.md).
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The tiny configuration through the command line, run once for this module."""
    out = tmp_path_factory.mktemp("leaderboard")
    assert evaluate.main([*TINY, "--out", str(out)]) == 0
    return out


def test_tiny_run_writes_every_output(tiny_run):
    for name in leaderboard.OUTPUT_FILES:
        assert (tiny_run / name).stat().st_size > 0, name
    rows = json.loads((tiny_run / "leaderboard.json").read_text())
    assert {(r["env_id"], r["agent"]) for r in rows} == PAIRS and len(rows) == len(PAIRS)
    for row in rows:
        assert row["episodes"] == 2 and row["obs_mode"] == "state"
        assert row["scenario"] == "time_limit=20" and row["seeds"] == [100000, 100001]
        for stat in row["metrics"].values():
            assert set(stat) == {"mean", "std", "n", "ci"}
    by_pair = {(r["env_id"], r["agent"]): r for r in rows}
    assert "control_effort" in by_pair[DOCK, "random"]["metrics"]
    assert "violation_fov_steps" in by_pair[DOCK, "random"]["metrics"]
    assert "final_capture_error" in by_pair[LARS, "random"]["metrics"]

    episodes = json.loads((tiny_run / "episodes.json").read_text())
    assert len(episodes) == 2 * len(PAIRS)
    skipped = json.loads((tiny_run / "skipped.json").read_text())
    assert [(s["env_id"], s["agent"]) for s in skipped] == [(LARS, "pd-state")]

    with open(tiny_run / "leaderboard.csv", newline="") as handle:
        table = list(csv.DictReader(handle))
    assert {(r["env_id"], r["agent"]) for r in table} == PAIRS
    ret = {(r["env_id"], r["agent"]): float(r["return_mean"]) for r in table}
    assert ret[DOCK, "random"] == by_pair[DOCK, "random"]["metrics"]["return"]["mean"]

    md = (tiny_run / "leaderboard.md").read_text()
    assert f"## {DOCK}" in md and f"## {LARS}" in md
    assert "| pd-state | state | time_limit=20 | 2 |" in md
    # 0/2 successes for both docking agents: Wilson [0 %, 66 %] each, a tie.
    assert "| 1 (tie) | pd-state |" in md and "0% (0/2) [0%, 66%]" in md
    assert "supports only" in md and "(plots/DockingStation-v1.png)" in md
    for env_id in (DOCK, LARS):
        png = tiny_run / "plots" / f"{env_id.split('/')[1]}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rerun_resumes_from_the_cache(tiny_run, tmp_path, capsys):
    out = tmp_path / "copy"
    shutil.copytree(tiny_run, out)
    cached = sorted((out / "episodes").glob("*.json"))
    assert len(cached) == 2 * len(PAIRS)
    stamps = [p.stat().st_mtime_ns for p in cached]
    capsys.readouterr()
    assert evaluate.main([*TINY, "--out", str(out)]) == 0
    assert "6 episodes: 0 run, 6 from the cache, 0 failed" in capsys.readouterr().err
    assert [p.stat().st_mtime_ns for p in cached] == stamps  # not rewritten
    assert (out / "leaderboard.json").read_text() == (tiny_run / "leaderboard.json").read_text()

    assert evaluate.main([*TINY, "--out", str(out), "--no-cache"]) == 0
    assert "6 episodes: 6 run, 0 from the cache, 0 failed" in capsys.readouterr().err
    assert all(p.stat().st_mtime_ns != s for p, s in zip(cached, stamps, strict=True))


def test_raising_agent_shows_as_failed_in_every_output(tmp_path, capsys):
    out = tmp_path / "res"
    code = evaluate.main(["--envs", DOCK, "--agents", "test-raises", "random", "--seeds", "1",
                          "--agent-module", "tests.leaderboard_agents", "--workers", "1",
                          "--no-progress", "--out", str(out)])
    assert code == 0
    rows = {r["agent"]: r for r in json.loads((out / "leaderboard.json").read_text())}
    assert rows["test-raises"]["status"] == "failed" and rows["random"]["status"] == "ok"
    assert "deliberate failure" in rows["test-raises"]["errors"][0]
    assert "deliberate failure" in (out / "leaderboard.md").read_text()
    assert "1 failed" in capsys.readouterr().err


def test_unknown_names_exit_with_the_valid_names(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--agents", "no-such-agent", "--out", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "no-such-agent" in err and "pd-state" in err and "random" in err
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--envs", "Nope-v0", "--out", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "unknown env id(s) Nope-v0" in err and DOCK in err and LARS in err


def test_bad_arguments_exit_with_usage_errors(tmp_path, capsys):
    for argv, message in [(["--seeds", "x-y"], "seeds"),
                          (["--envs", DOCK, "--env-kwargs", "nope=1"], "nope"),
                          (["--envs", DOCK, "--env-kwargs", "time_limit=-1"], "time_limit"),
                          (["--workers", "0"], "workers")]:
        with pytest.raises(SystemExit) as exc:
            evaluate.main([*argv, "--out", str(tmp_path)])
        assert exc.value.code == 2, argv
        assert message in capsys.readouterr().err, argv


def test_missing_ray_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--envs", DOCK, "--agents", "random", "--seeds", "1", "--backend",
                       "ray", "--no-progress", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "pip install" in capsys.readouterr().err


def test_unreachable_ray_address_is_a_clear_error(tmp_path, capsys):
    pytest.importorskip("ray")
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--envs", DOCK, "--agents", "random", "--seeds", "1", "--backend", "ray",
                       "--ray-address", "127.0.0.1:1", "--no-progress", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "cannot reach the Ray cluster at 127.0.0.1:1" in capsys.readouterr().err


def _chromium_page(url: str):
    """(console errors, page errors, failed requests, row texts, sort results) of ``url``."""
    from playwright.sync_api import sync_playwright

    console, page_errors, failed = [], [], []
    with tempfile.TemporaryDirectory() as profile, sync_playwright() as pw:
        browser = pw.chromium.launch_persistent_context(
            profile, executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            page.on("console", lambda m: console.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: page_errors.append(str(e)))
            page.on("requestfailed", lambda r: failed.append(r.url))
            page.goto(url)
            page.wait_for_load_state("load")
            rows = page.eval_on_selector_all(
                "table.leaderboard tbody tr",
                "rows => rows.map(r => [r.closest('table').dataset.env, r.cells[1].textContent])")
            images = page.eval_on_selector_all(
                "img.plot", "imgs => imgs.map(i => i.complete && i.naturalWidth > 0)")
            table = f'table.leaderboard[data-env="{DOCK}"]'
            headers = page.eval_on_selector_all(f"{table} thead th",
                                                "hs => hs.map(h => h.textContent)")
            column = headers.index("return")
            read = (f"t => Array.from(t.tBodies[0].rows).map(r => "
                    f"parseFloat(r.cells[{column}].dataset.value))")
            header = page.locator(f"{table} thead th").nth(column)
            header.click()
            ascending = page.eval_on_selector(table, read)
            state_up = header.get_attribute("aria-sort")
            header.click()
            descending = page.eval_on_selector(table, read)
            state_down = header.get_attribute("aria-sort")
        finally:
            browser.close()
    return console, page_errors, failed, rows, images, (ascending, state_up, descending,
                                                         state_down)


@pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed "
                    "(.ci/run installs Debian's chromium)")
def test_html_page_opens_in_headless_chromium_and_sorts(tiny_run):
    page = Path(tiny_run) / "leaderboard.html"
    console, page_errors, failed, rows, images, sort = _chromium_page(page.as_uri())
    assert console == [] and page_errors == [] and failed == []
    assert sorted(map(tuple, rows)) == sorted(PAIRS)  # one row per agent and environment
    assert images == [True, True]  # both plots loaded
    ascending, state_up, descending, state_down = sort
    assert len(ascending) == 2 and ascending == sorted(ascending)
    assert descending == sorted(ascending, reverse=True) and ascending != descending
    assert (state_up, state_down) == ("ascending", "descending")


def test_ray_backend_gives_the_same_metrics_as_the_local_backend(tmp_path):
    pytest.importorskip("ray")
    args = dict(env_ids=[DOCK, LARS], agents=["random", "pd-state"], seeds=[100000, 100001],
                env_kwargs=[{DOCK: {"time_limit": 20.0}}])
    local = evaluate_all(**args, workers=1)
    remote = evaluate_all(**args, backend="ray", workers=2, cache_dir=tmp_path)
    assert remote.stats.ran == len(local.rows) == 6 and remote.stats.failed == 0

    def strip(rows):
        return [{k: v for k, v in row_to_dict(r).items() if k != "wall_time_s"} for r in rows]

    assert strip(remote.rows) == strip(local.rows)

    def metrics(rows):
        return [{k: v for k, v in s["metrics"].items() if k != "wall_time_s"}
                for s in summarise(rows)]

    assert metrics(remote.rows) == metrics(local.rows)


def test_list_shows_environments_and_where_each_agent_applies(capsys):
    assert evaluate.main(["--list"]) == 0
    out = capsys.readouterr().out
    assert f"{DOCK}  obs modes: state, features, image" in out
    assert f"pd-state  obs modes: state; on {DOCK}" in out
    assert "random  obs modes: state; on every environment" in out


def test_a_run_where_nothing_applies_says_why(tmp_path, capsys):
    code = evaluate.main(["--envs", "AcousticTracking-v0", "--agents", "pd-state", "--seeds", "1",
                          "--no-progress", "--out", str(tmp_path)])
    assert code == 1
    err = capsys.readouterr().err
    assert "skipped pd-state on auv_envs/AcousticTracking-v0: supports only" in err
    assert "nothing evaluated" in err


def _summary_row(env_id, agent, successes, n, rmse=None, status="ok"):
    metrics = {"success": {"mean": successes / n, "std": 0.0, "n": n,
                           "ci": list(wilson_interval(successes, n))}}
    if rmse is not None:
        mean, low, high = rmse
        metrics["rmse"] = {"mean": mean, "std": 0.0, "n": n, "ci": [low, high]}
    return {"env_id": env_id, "agent": agent, "obs_mode": "state", "scenario": "default",
            "episodes": n, "failed": 0 if status == "ok" else n, "status": status,
            "errors": [], "metrics": metrics}


def test_ranks_tie_where_intervals_overlap_and_tracking_ranks_by_rmse():
    docking = [_summary_row(DOCK, "a", 30, 30), _summary_row(DOCK, "b", 28, 30),
               _summary_row(DOCK, "c", 5, 30), _summary_row(DOCK, "d", 0, 30, status="failed")]
    rows = leaderboard.by_env(docking)[DOCK]
    assert [r["agent"] for r in rows] == ["a", "b", "c", "d"]
    # 30/30 and 28/30 overlap (a tie); 5/30 is clearly below; a failed row has no rank.
    assert leaderboard.rank_labels(rows) == ["1 (tie)", "1 (tie)", "3", "–"]

    acoustic = "auv_envs/AcousticTracking-v0"
    tracking = [_summary_row(acoustic, "slow", 3, 3, rmse=(0.05, 0.04, 0.06)),
                _summary_row(acoustic, "best", 3, 3, rmse=(0.006, 0.005, 0.008)),
                _summary_row(acoustic, "close", 3, 3, rmse=(0.045, 0.035, 0.05))]
    assert leaderboard.rank_metric(tracking) == ("rmse", "lower")
    rows = leaderboard.by_env(tracking)[acoustic]
    assert [r["agent"] for r in rows] == ["best", "close", "slow"]
    assert leaderboard.rank_labels(rows) == ["1", "2 (tie)", "2 (tie)"]
