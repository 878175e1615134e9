"""Outputs that last: a run merges into the board in its output
directory; rows it evaluates are replaced, the others kept; no stale plot remains."""

from __future__ import annotations

import json

import pytest

import evaluate
from baselines.evaluation import EpisodeTask, board

DOCK, LARS = "auv_envs/DockingStation-v2", "auv_envs/LARSCapture-v0"
COMMON = ["--difficulty", "easy", "--env-kwargs", "time_limit=1", "--workers", "1",
          "--no-progress", "--no-video"]


def _rows(out):
    rows = json.loads((out / "leaderboard.json").read_text())
    return {(r["env_id"], r["agent"]): r for r in rows}


def test_merge_replaces_the_rows_a_run_evaluates_and_keeps_the_others():
    def task(agent, seed, env=DOCK):
        return EpisodeTask(env, "state", agent, seed, (("difficulty", "easy"),))

    earlier = [task("random", 1), task("random", 2), task("pd-state", 1), task("random", 1, LARS)]
    new = [task("random", 5)]
    assert board.merge(earlier, new) == [task("pd-state", 1), task("random", 1, LARS),
                                         task("random", 5)]
    assert board.merge([], new) == new


def test_a_second_run_merges_into_the_board(tmp_path, capsys):
    out = tmp_path / "board"
    assert evaluate.main(["--envs", "DockingStation-v2", "LARSCapture-v0", "--agents", "random",
                          "pd-state", "ckf-pd-state", "--seeds", "100000,100001", *COMMON,
                          "--out", str(out)]) == 0
    first = _rows(out)
    assert {(DOCK, "random"), (DOCK, "pd-state"), (LARS, "random"),
            (LARS, "ckf-pd-state")} <= set(first)
    assert (out / "plots" / "LARSCapture-v0.png").exists()
    # A narrower run: one row replaced (its new seed only), the others kept from the cache.
    assert evaluate.main(["--envs", "DockingStation-v2", "--agents", "random", "--seeds",
                          "100005", *COMMON, "--out", str(out)]) == 0
    assert "0 failed" in capsys.readouterr().err
    second = _rows(out)
    assert set(second) == set(first)
    assert second[DOCK, "random"]["seeds"] == [100005]
    for key in ((DOCK, "pd-state"), (LARS, "random"), (LARS, "ckf-pd-state")):
        assert second[key]["seeds"] == first[key]["seeds"] == [100000, 100001]
        assert second[key]["metrics"] == first[key]["metrics"]
    assert (out / "plots" / "LARSCapture-v0.png").exists()
    assert "earlier runs kept" in (out / "leaderboard.md").read_text()
    episodes = json.loads((out / "episodes.json").read_text())
    assert len(episodes) == len(json.loads((out / board.BOARD_FILE).read_text())["tasks"])
    # --new-board: only this run's rows, and no plot of an environment it did not run.
    assert evaluate.main(["--envs", "DockingStation-v2", "--agents", "random", "--seeds",
                          "100005", *COMMON, "--out", str(out), "--new-board"]) == 0
    assert set(_rows(out)) == {(DOCK, "random")}
    assert not (out / "plots" / "LARSCapture-v0.png").exists()


def test_a_board_that_cannot_be_read_is_a_usage_error_and_gone_agents_are_dropped(tmp_path,
                                                                                   capsys):
    out = tmp_path / "board"
    out.mkdir()
    (out / board.BOARD_FILE).write_text('{"format": 1, "tasks": [')
    argv = ["--envs", "DockingStation-v2", "--agents", "random", "--seeds", "100000", *COMMON,
            "--out", str(out)]
    with pytest.raises(SystemExit) as exc:
        evaluate.main(argv)
    assert exc.value.code == 2 and "--new-board" in capsys.readouterr().err
    gone = EpisodeTask(DOCK, "state", "retired-agent", 100000, (("difficulty", "easy"),))
    board.write(out, [gone], [])
    assert evaluate.main(argv) == 0
    assert "name an agent or environment that no longer exists" in capsys.readouterr().err
    assert set(_rows(out)) == {(DOCK, "random")}
