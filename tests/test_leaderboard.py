"""evaluate.py end to end: the leaderboard files, resuming, the HTML page in Chromium, Ray;
the page's overview, plots and clips."""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import sys
from pathlib import Path
from urllib.parse import unquote

import pytest

import evaluate
from baselines import leaderboard
from baselines.evaluation import EpisodeRow, evaluate_all, row_to_dict, summarise
from baselines.stats import wilson_interval
from scripts.screenshot_leaderboard import CHROMIUM, open_chromium, screenshots
from tests.conftest import DOCKING_IDS

DOCK = DOCKING_IDS[0]
LARS = "auv_envs/LARSCapture-v0"
TINY = ["--envs", DOCK, "LARSCapture-v0", "--agents", "random", "pd-state",
        "--seeds", "100000-100001", "--env-kwargs", "time_limit=20", "--difficulty", "easy",
        "--workers", "1", "--no-progress"]
#: The tiny run's scenario label: its arguments, sorted.
TINY_SCENARIO = "difficulty=easy, time_limit=20"
#: (env, agent) pairs of the tiny run; pd-state does not apply to LARS.
PAIRS = {(DOCK, "random"), (DOCK, "pd-state"), (LARS, "random")}
needs_chromium = pytest.mark.skipif(
    not os.path.exists(CHROMIUM),
    reason=f"{CHROMIUM} is not installed (.ci/run installs Debian's chromium)")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The tiny configuration through the command line, run once for this module."""
    out = tmp_path_factory.mktemp("leaderboard")
    assert evaluate.main([*TINY, "--out", str(out)]) == 0
    return out


def test_tiny_run_writes_every_output(tiny_run):
    for name in leaderboard.OUTPUT_FILES:
        assert (tiny_run / name).stat().st_size > 0, name
    # One clip (an MP4 for the page) per (environment, agent): the first seed's episode.
    clips = sorted(p.name for p in (tiny_run / "videos").iterdir())
    assert len(clips) == len(PAIRS)
    assert all(name.endswith("seed100000-episode-0.mp4") for name in clips), clips
    rows = json.loads((tiny_run / "leaderboard.json").read_text())
    assert {(r["env_id"], r["agent"]) for r in rows} == PAIRS and len(rows) == len(PAIRS)
    for row in rows:
        assert row["episodes"] == 2 and row["obs_mode"] == "state"
        assert row["scenario"] == TINY_SCENARIO and row["seeds"] == [100000, 100001]
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
    assert f"| pd-state | state | {TINY_SCENARIO} | 2 |" in md
    # 0/2 successes for both docking agents: Wilson [0 %, 66 %] each, a tie.
    assert "| 1 (tie) | pd-state |" in md and "0% (0/2) [0%, 66%]" in md
    assert "supports only" in md and "(plots/DockingStation-v2.png)" in md
    png = tiny_run / "plots" / "DockingStation-v2.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # LARS has one agent: nothing varies between agents, so no plot.
    assert not (tiny_run / "plots" / "LARSCapture-v0.png").exists()
    assert "LARSCapture-v0.png" not in md


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
                          "--difficulty", "easy", "--agent-module", "tests.leaderboard_agents",
                          "--workers", "1", "--no-progress", "--out", str(out)])
    assert code == 0
    rows = {r["agent"]: r for r in json.loads((out / "leaderboard.json").read_text())}
    assert rows["test-raises"]["status"] == "failed" and rows["random"]["status"] == "ok"
    assert "deliberate failure" in rows["test-raises"]["errors"][0]
    assert "deliberate failure" in (out / "leaderboard.md").read_text()
    assert "1 failed" in capsys.readouterr().err


def test_unknown_names_exit_with_the_closest_names(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--agents", "no-such-agent", "--out", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "no-such-agent" in err and "python evaluate.py --list" in err
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--agents", "pd-stat", "--out", str(tmp_path)])
    assert "did you mean pd-state" in capsys.readouterr().err
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


def _listen(page, console: list, page_errors: list, failed: list) -> None:
    """Collect ``page``'s console errors, uncaught errors and failed requests."""
    page.on("console", lambda m: console.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: page_errors.append(str(e)))
    page.on("requestfailed", lambda r: failed.append(r.url))


def _chromium_page(url: str):
    """(console errors, page errors, failed requests, row texts, sort results) of ``url``."""
    console, page_errors, failed = [], [], []
    with open_chromium() as browser:
        page = browser.new_page()
        _listen(page, console, page_errors, failed)
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
    return console, page_errors, failed, rows, images, (ascending, state_up, descending,
                                                         state_down)


@needs_chromium
def test_html_page_opens_in_headless_chromium_and_sorts(tiny_run):
    page = Path(tiny_run) / "leaderboard.html"
    console, page_errors, failed, rows, images, sort = _chromium_page(page.as_uri())
    assert console == [] and page_errors == [] and failed == []
    assert sorted(map(tuple, rows)) == sorted(PAIRS)  # one row per agent and environment
    # The docking plot and the across-task view (pd-state is docking's reference) loaded;
    # LARS (one agent) has no plot.
    assert images == [True, True]
    ascending, state_up, descending, state_down = sort
    assert len(ascending) == 2 and ascending == sorted(ascending)
    assert descending == sorted(ascending, reverse=True) and ascending != descending
    assert (state_up, state_down) == ("ascending", "descending")


#: The background colour of the test clips (pure green: easy to find in a screenshot).
CLIP_GREEN = (0, 160, 0)


def _write_clip(path: Path, codec: str = "libx264", seconds: float = 3.0) -> None:
    """A small moving test video (a white bar sweeping over green) at ``path``."""
    import numpy as np
    from moviepy import ImageSequenceClip

    fps, frames = 10, []
    for i in range(round(seconds * fps)):
        frame = np.full((48, 64, 3), CLIP_GREEN, dtype=np.uint8)
        frame[:, (2 * i) % 64:(2 * i) % 64 + 4] = 255
        frames.append(frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    ImageSequenceClip(frames, fps=fps).write_videofile(str(path), codec=codec, audio=False,
                                                       logger=None)


#: Reads the page's layout: page-level overflow, the first section, which boxes scroll.
_LAYOUT = """() => {
  const scrolls = b => b.scrollWidth > b.clientWidth;
  const boxes = Array.from(document.querySelectorAll("section.env .scroll"));
  const cards = Array.from(document.querySelectorAll("#overview .scroll"));
  const first = document.querySelector("section");
  return {scrollWidth: document.documentElement.scrollWidth, innerWidth: window.innerWidth,
          firstSection: first.id, overviewTop: first.getBoundingClientRect().top,
          innerHeight: window.innerHeight,
          tableScrolls: boxes.some(scrolls), overviewScrolls: cards.some(scrolls)};
}"""

#: Plays every <video> (muted, as a visitor's click would) and reports after a while.
_PLAY = """async () => Promise.all(Array.from(document.querySelectorAll("video")).map(
  async v => {
    let playError = null;
    try { await v.play(); } catch (e) { playError = String(e); }
    const start = v.currentTime;
    await new Promise(r => setTimeout(r, 800));
    return {src: v.getAttribute("src"), readyState: v.readyState, start: start,
            now: v.currentTime, error: v.error && v.error.code, playError: playError};
  }))"""


@needs_chromium
def test_page_fits_wide_and_phone_windows_and_its_clips_play(tiny_run, tmp_path):
    out = tmp_path / "lb"
    shutil.copytree(tiny_run, out)
    summary = json.loads((out / "leaderboard.json").read_text())
    clips = {(DOCK, "pd-state", "state", TINY_SCENARIO): "clips/dock pd-state.mp4",
             (LARS, "random", "state", TINY_SCENARIO): "clips/lars-random.mp4"}
    for rel in clips.values():
        _write_clip(out / rel)
    leaderboard.write(out, summary, json.loads((out / "skipped.json").read_text()), clips=clips)
    url = (out / "leaderboard.html").as_uri()
    console, page_errors, failed = [], [], []
    with open_chromium() as browser:
        for width in (1400, 390):
            page = browser.new_page()
            _listen(page, console, page_errors, failed)
            page.set_viewport_size({"width": width, "height": 900})
            page.goto(url)
            page.wait_for_load_state("load")
            layout = page.evaluate(_LAYOUT)
            assert layout["scrollWidth"] <= layout["innerWidth"] == width, layout
            assert layout["firstSection"] == "overview", layout
            assert layout["overviewTop"] < layout["innerHeight"] / 3, layout
            if width == 390:  # the docking table is wider than a phone: its box scrolls
                assert layout["tableScrolls"], layout
            assert not layout["overviewScrolls"], layout  # the overview fits, even on a phone
            videos = page.evaluate(_PLAY)
            assert sorted(v["src"] for v in videos) == sorted(
                p.replace(" ", "%20") for p in clips.values())
            for video in videos:
                assert video["error"] is None and video["playError"] is None, video
                assert video["readyState"] >= 2 and video["now"] > video["start"], video
            for video in page.locator("video").all():  # frames reach the screen
                assert _shows_green(video.screenshot())
            page.close()
    assert console == [] and page_errors == [] and failed == []


@needs_chromium
def test_clips_of_the_run_load_and_play(tiny_run):
    # evaluate.py records the first episode of every (environment, agent) and the page
    # shows it: each clip loads, plays, and puts a picture (not a black box) on screen.
    from PIL import Image

    console, page_errors, failed = [], [], []
    with open_chromium() as browser:
        page = browser.new_page()
        _listen(page, console, page_errors, failed)
        page.set_viewport_size({"width": 1400, "height": 900})
        page.goto((tiny_run / "leaderboard.html").as_uri())
        page.wait_for_load_state("load")
        videos = page.evaluate(_PLAY)
        assert len(videos) == len(PAIRS)
        for video in videos:
            assert video["src"].startswith("videos/") and video["src"].endswith(".mp4"), video
            assert (tiny_run / unquote(video["src"])).exists()
            assert video["error"] is None and video["playError"] is None, video
            assert video["readyState"] >= 2 and video["now"] > video["start"], video
        for element in page.locator("video").all():
            frame = Image.open(io.BytesIO(element.screenshot())).convert("L")
            assert max(frame.getdata()) - min(frame.getdata()) > 40  # a scene, not a flat box
        page.close()
    assert console == [] and page_errors == [] and failed == []


@needs_chromium
def test_screenshot_script_saves_both_widths_without_horizontal_overflow(tiny_run, tmp_path):
    from PIL import Image

    paths = screenshots(tiny_run / "leaderboard.html", tmp_path)
    assert [p.name for p in paths] == ["leaderboard-1400.png", "leaderboard-390.png"]
    # A full-page screenshot is as wide as the page: the viewport's width unless it overflows.
    assert [Image.open(p).size[0] for p in paths] == [1400, 390]


def _row_with(env_id, agent, successes, n, scenario="default", **means):
    """A summary row with extra metrics of the given means (interval: the mean)."""
    row = _summary_row(env_id, agent, successes, n)
    row["scenario"] = scenario
    for key, mean in means.items():
        row["metrics"][key] = {"mean": mean, "std": 0.0, "n": n, "ci": [mean, mean]}
    return row


def _shows_green(png: bytes) -> bool:
    """Whether a screenshot shows the test clips' green (a decoded frame on screen)."""
    from PIL import Image

    pixels = Image.open(io.BytesIO(png)).convert("RGB").getdata()
    return sum(abs(g - 160) < 40 and r < 60 and b < 60 for r, g, b in pixels) > 100


def _png_width(png: bytes) -> int:
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(png[16:20], "big")


def test_clips_are_captioned_with_how_their_episode_ended():
    rows = [_summary_row(DOCK, "a", 3, 3), _summary_row(DOCK, "b", 1, 3)]
    for row in rows:
        row["seeds"] = [7, 8]
    clips = {(DOCK, "a", "state", "default"): "a.mp4", (DOCK, "b", "state", "default"): "b.mp4"}

    def episode(agent, seed, success, reason=""):
        return EpisodeRow(DOCK, agent, seed, "state", "default", 1.0, 5, success, reason, {},
                          0.1)

    # Each row's first episode is the recorded one.
    episodes = [episode("a", 7, True), episode("a", 8, False, "seabed"),
                episode("b", 7, False, "lights_lost"), episode("b", 8, True),
                episode("c", 7, True)]
    outcomes = leaderboard.clip_outcomes(episodes, clips)
    assert outcomes == {(DOCK, "a", "state", "default"): "success",
                        (DOCK, "b", "state", "default"): "lights_lost"}
    page = leaderboard.page(rows, clips=clips, outcomes=outcomes)
    assert 'a <span class="outcome">(seed 7: success)</span>' in page
    assert 'b <span class="outcome">(seed 7: lights_lost)</span>' in page


def test_plots_leave_out_metrics_that_are_the_same_for_every_agent(tmp_path):
    rows = [_row_with(DOCK, "a", 3, 3, violation_fov_steps=0.0, control_effort=10.0),
            _row_with(DOCK, "b", 0, 3, violation_fov_steps=0.0, control_effort=10.0),
            _row_with(DOCK, "c", 1, 3, violation_fov_steps=0.0)]
    assert leaderboard.varying_keys(rows) == ["success"]
    one = leaderboard.plot_env(DOCK, rows)
    rows[2]["metrics"]["control_effort"] = {"mean": 5.0, "std": 0.0, "n": 3, "ci": [4.0, 6.0]}
    assert leaderboard.varying_keys(rows) == ["success", "control_effort"]
    two = leaderboard.plot_env(DOCK, rows)
    assert _png_width(two) > _png_width(one)  # two bar charts side by side, then one

    same = [_row_with(LARS, "a", 0, 3, capture_time=4.0), _row_with(LARS, "b", 0, 3)]
    assert leaderboard.varying_keys(same) == [] and leaderboard.plot_env(LARS, same) is None
    assert leaderboard.plot_env(LARS, same[:1]) is None  # one agent: nothing to compare

    stale = tmp_path / "plots" / "LARSCapture-v0.png"
    stale.parent.mkdir()
    stale.write_bytes(b"an earlier run's plot")
    paths = leaderboard.write(tmp_path, rows + same)
    assert "plots/DockingStation-v2.png" in paths and not stale.exists()
    page = (tmp_path / "leaderboard.html").read_text()
    assert page.count("<img") == 1 and 'src="plots/DockingStation-v2.png"' in page


def _overview(page: str) -> str:
    start = page.index('<section id="overview">')
    return page[start:page.index("</section>", start)]


def test_overview_comes_first_and_ranks_every_agent_of_every_environment():
    acoustic = "auv_envs/AcousticTracking-v2"
    summary = [_summary_row(DOCK, "a", 30, 30), _summary_row(DOCK, "b", 28, 30),
               _summary_row(DOCK, "c", 5, 30), _summary_row(DOCK, "d", 0, 30, status="failed"),
               _summary_row(acoustic, "slow", 3, 3, rmse=(0.05, 0.04, 0.06)),
               _summary_row(acoustic, "best", 3, 3, rmse=(0.006, 0.005, 0.008))]
    page = leaderboard.page(summary)
    assert '<meta name="viewport" content="width=device-width, initial-scale=1">' in page
    overview = _overview(page)
    assert page.index("<section") == page.index('<section id="overview">')
    assert page.index('id="overview"') < page.index('<table class="leaderboard"')
    cards = overview.split('<div class="card"')[1:]
    assert [c.split('data-env="')[1].split('"')[0] for c in cards] == [DOCK, acoustic]
    for card, agents, ranks, metric in [
            (cards[0], ["a", "b", "c", "d"], ["=1", "=1", "3", "–"], "success"),
            (cards[1], ["best", "slow"], ["1", "2"], "RMSE m")]:
        assert [c.split("</td>")[0] for c in card.split('<td class="agent">')[1:]] == agents
        assert [c.split(">", 1)[1].split("<")[0] for c in card.split('<td class="rank"')[1:]] \
            == ranks
        assert f">{metric}</th>" in card
    assert "100% (30/30)</span>" in cards[0] and '<span class="ci">[' in cards[0]
    assert "0.006</span>" in cards[1]
    assert all("<video" not in c for c in cards)


def test_overview_ranks_each_scenario_on_its_own():
    summary = [_row_with(DOCK, "a", 30, 30, scenario="calm", docking_time=20.0),
               _row_with(DOCK, "b", 0, 30, scenario="calm", docking_time=30.0),
               _row_with(DOCK, "a", 0, 30, scenario="current"),
               _row_with(DOCK, "b", 30, 30, scenario="current", docking_time=25.0)]
    cards = _overview(leaderboard.page(summary)).split('<div class="card"')[1:]
    assert [c.split('data-scenario="')[1].split('"')[0] for c in cards] == ["calm", "current"]
    for card, best in zip(cards, ["a", "b"], strict=True):
        assert '<span class="sub">' in card.split("</h3>")[0]  # the scenario's name
        assert card.split('<td class="agent">')[1].startswith(best)
        assert [c.split(">", 1)[1].split("<")[0] for c in card.split('<td class="rank"')[1:]] \
            == ["1", "2"]
        assert ">docking time s</th>" in card  # the docking headline beside success


def test_tables_rank_each_difficulty_level_on_its_own():
    summary = [_row_with(DOCK, "a", 30, 30, scenario="difficulty=paper"),
               _row_with(DOCK, "b", 0, 30, scenario="difficulty=paper"),
               _row_with(DOCK, "a", 0, 30, scenario="difficulty=hard"),
               _row_with(DOCK, "b", 30, 30, scenario="difficulty=hard")]
    text = leaderboard.markdown(summary, compact=True)
    tables = text.split(f"## {DOCK} · ")[1:]
    assert [t.split("\n")[0] for t in tables] == ["difficulty=paper", "difficulty=hard"]
    for table, best in zip(tables, ["a", "b"], strict=True):
        rows = [line for line in table.splitlines() if line.startswith("| ") and "rank" not in line]
        assert [r.split(" | ")[0] for r in rows] == ["| 1", "| 2"]
        assert rows[0].split(" | ")[1] == best
    # The full table's ranks too are per level: each level has its own first place.
    ranks = leaderboard.ranks(leaderboard.by_env(summary)[DOCK])
    assert sorted(r[0] for r in ranks) == [1, 1, 2, 2]


def test_a_row_is_ranked_below_every_row_that_beats_it(tmp_path):
    """The default run's mission table at hard, 6 shared seeds: 6/6, 4/6, 0/6, 0/6. Each
    neighbour pair ties (McNemar: p = 0.5, 0.125, 1), but 6/6 beats 0/6 (p = 0.031): the
    0/6 rows rank 2, not 1 through a chain of ties, and the files carry the ranks."""
    mission = "auv_envs/DockingMission-v0"
    seeds = [str(s) for s in range(100000, 100006)]
    rows = []
    for agent, wins in [("homing-pd-state", 6), ("nav-homing-ofnmpc-ekf", 4),
                        ("cppo-mission-nav-features", 0), ("random", 0)]:
        row = _summary_row(mission, agent, wins, 6)
        row["by_seed"] = {"success": {s: float(i < wins) for i, s in enumerate(seeds)}}
        rows.append(row)
    ordered = leaderboard.by_env(rows)[mission]
    assert [r["agent"] for r in ordered] == ["homing-pd-state", "nav-homing-ofnmpc-ekf",
                                             "cppo-mission-nav-features", "random"]
    assert leaderboard.rank_labels(ordered) == ["1 (tie)", "1 (tie)", "2 (tie)", "2 (tie)"]
    leaderboard.write(tmp_path, rows)
    written = {r["agent"]: (r["rank"], r["tied"])
               for r in json.loads((tmp_path / "leaderboard.json").read_text())}
    assert written == {"homing-pd-state": (1, True), "nav-homing-ofnmpc-ekf": (1, True),
                       "cppo-mission-nav-features": (2, True), "random": (2, True)}
    with open(tmp_path / "leaderboard.csv", newline="") as handle:
        table = {r["agent"]: (r["rank"], r["tied"]) for r in csv.DictReader(handle)}
    assert table["random"] == ("2", "True") and table["homing-pd-state"] == ("1", "True")


def test_rows_are_shown_in_rank_order():
    """A tracker with a worse mean but a spread so wide that nothing beats it ranks 1 and
    is shown among the rank-1 rows, before a row that a better one beats."""
    acoustic = "auv_envs/AcousticTracking-v2"
    rows = [_summary_row(acoustic, "tight", 3, 3, rmse=(0.30, 0.29, 0.31)),
            _summary_row(acoustic, "beaten", 3, 3, rmse=(0.35, 0.34, 0.36)),
            _summary_row(acoustic, "wide", 3, 3, rmse=(0.60, 0.20, 1.50))]
    ordered = leaderboard.by_env(rows)[acoustic]
    assert [r["agent"] for r in ordered] == ["tight", "wide", "beaten"]
    assert leaderboard.rank_labels(ordered) == ["1 (tie)", "1 (tie)", "2"]
    # ranks do not depend on the order the rows come in
    assert leaderboard.rank_labels(ordered[::-1]) == ["2", "1 (tie)", "1 (tie)"]


def test_clips_show_as_videos_under_their_environment():
    rows = [_summary_row(DOCK, "a", 3, 3), _summary_row(DOCK, "b", 1, 3),
            _summary_row(LARS, "a", 0, 3)]
    clips = {(DOCK, "b", "state", "default"): "clips/dock b.mp4",
             (LARS, "a", "state", "default"): "clips/lars-a.webm",
             (LARS, "a", "image", "default"): "clips/not-a-row.mp4"}
    page = leaderboard.page(rows, clips=clips)
    assert page.count("<video") == 2 and "not-a-row" not in page
    dock = page[page.index(f'data-env="{DOCK}">'):page.index(f'data-env="{LARS}">')]
    for section, src, label in [(dock, "clips/dock%20b.mp4", "b"),
                                (page[page.index(f'data-env="{LARS}">'):], "clips/lars-a.webm",
                                 "a")]:
        video = section.split("<video")[1].split(">")[0]
        assert f'src="{src}"' in video
        for attribute in ("muted", "loop", "playsinline", "autoplay", "controls", 'preload="auto"',
                          'width="320"'):
            assert attribute in video
        assert f"<figcaption>{label}</figcaption>" in section
    assert leaderboard.page(rows).count("<video") == 0
    md = leaderboard.markdown(rows, clips=clips)
    assert "Clips: [b](clips/dock%20b.mp4)" in md and "[a](clips/lars-a.webm)" in md


def test_ray_backend_gives_the_same_metrics_as_the_local_backend(tmp_path,
                                                               one_ray_cluster_at_a_time):
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
    code = evaluate.main(["--envs", "AcousticTracking-v2", "--agents", "pd-state", "--seeds", "1",
                          "--no-progress", "--out", str(tmp_path)])
    assert code == 1
    err = capsys.readouterr().err
    assert "skipped pd-state on auv_envs/AcousticTracking-v2: supports only" in err
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

    acoustic = "auv_envs/AcousticTracking-v2"
    tracking = [_summary_row(acoustic, "slow", 3, 3, rmse=(0.05, 0.04, 0.06)),
                _summary_row(acoustic, "best", 3, 3, rmse=(0.006, 0.005, 0.008)),
                _summary_row(acoustic, "close", 3, 3, rmse=(0.045, 0.035, 0.05))]
    assert leaderboard.rank_metric(tracking) == ("rmse", "lower")
    rows = leaderboard.by_env(tracking)[acoustic]
    assert [r["agent"] for r in rows] == ["best", "close", "slow"]
    assert leaderboard.rank_labels(rows) == ["1", "2 (tie)", "2 (tie)"]
