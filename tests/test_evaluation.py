"""evaluate.py and the library behind it."""

from __future__ import annotations

import json

import pytest

import evaluate
from baselines.evaluation import (
    EVAL_SEED_BASE,
    default_seeds,
    format_table,
    parse_seeds,
    summarise,
)
from baselines.evaluation import (
    evaluate as run_evaluation,
)
from tests.conftest import DOCKING_IDS


def test_parse_seeds():
    assert parse_seeds("3-6") == [3, 4, 5, 6]
    assert parse_seeds("1,5,9") == [1, 5, 9]
    assert parse_seeds("7") == [7]
    for bad in ("6-3", "a-b", "1,,2"):
        with pytest.raises(ValueError, match="seeds"):
            parse_seeds(bad)


def test_default_seeds_are_disjoint_from_training_range():
    seeds = default_seeds(4)
    assert seeds == list(range(EVAL_SEED_BASE, EVAL_SEED_BASE + 4))
    with pytest.raises(ValueError):
        default_seeds(0)


def test_evaluate_is_deterministic_and_summarises():
    rows1 = run_evaluation([DOCKING_IDS[0]], ["pd-state", "random"], [10, 11])
    rows2 = run_evaluation([DOCKING_IDS[0]], ["pd-state", "random"], [10, 11])
    assert [r.episode_return for r in rows1] == [r.episode_return for r in rows2]
    summary = {s["agent"]: s for s in summarise(rows1)}
    assert summary["pd-state"]["success_rate"] == 1.0
    assert summary["random"]["success_rate"] == 0.0
    assert summary["pd-state"]["episodes"] == 2
    table = format_table(summarise(rows1))
    assert "pd-state" in table and "random" in table


def test_evaluate_rejects_unknown_env():
    with pytest.raises(ValueError, match="registered"):
        run_evaluation(["auv_envs/Nope-v0"], ["random"], [1])


def test_cli_writes_json_rows(tmp_path, capsys):
    out = tmp_path / "res"
    code = evaluate.main(["--envs", DOCKING_IDS[1], "--agents", "pd-state", "random",
                          "--seeds", "20-21", "--out", str(out)])
    assert code == 0
    rows = json.loads((out / "rows.json").read_text())
    assert len(rows) == 4
    assert {r["agent"] for r in rows} == {"pd-state", "random"}
    assert all(r["env_id"] == DOCKING_IDS[1] for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert {s["agent"] for s in summary} == {"pd-state", "random"}
    assert "| env | agent |" in capsys.readouterr().out


def test_cli_bad_seeds_exit_with_usage_error(tmp_path):
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--seeds", "x-y", "--out", str(tmp_path)])
    assert exc.value.code == 2
