"""Nothing a user types or a file holds silently changes a result.

Cached episodes carry a checksum and are checked against their task and the row
schema; a rejected file is named and its episode rerun. NaN metrics are counted,
not dropped. A keyword given twice, or beside the option that sets it, is a usage
error, as are repeated and negative seeds. Actions follow one rule on the CPU and
the batched envs.
"""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

import evaluate
from baselines.commands.evaluate import DEFAULT_LEVELS, scenario_groups
from baselines.evaluation import EpisodeCache, EpisodeRow, EpisodeTask, evaluate_all, summarise
from baselines.evaluation.cache import checksum
from baselines.evaluation.episodes import run_episode
from baselines.leaderboard import cell_text
from tests.conftest import DOCKING_IDS

DOCK = DOCKING_IDS[0]


# ------------------------------------------------------------------ the cache
@pytest.fixture(scope="module")
def cached(tmp_path_factory):
    """Two random-agent episodes cached, and their rows as first run."""
    directory = tmp_path_factory.mktemp("cache")
    args = dict(env_ids=[DOCK], agents=["random"], seeds=[11, 12], cache_dir=directory,
                env_kwargs=({DOCK: {"time_limit": 3.0}},))
    first = evaluate_all(**args)
    return directory, args, first.rows


def _edit(path, change, reseal: bool):
    """Edit a cached file's row with ``change(row)``; ``reseal``: recompute its checksum,
    as someone who knows the format would."""
    data = json.loads(path.read_text())
    change(data["row"])
    if reseal:
        data["checksum"] = checksum(data["task"], data["row"])
    path.write_text(json.dumps(data))


def _rerun_after(cached, change, reseal, reason):
    directory, args, rows = cached
    task = EpisodeTask(DOCK, "state", "random", 12, (("time_limit", 3.0),))
    path = EpisodeCache(directory).path(task)
    assert path.exists()
    _edit(path, change, reseal)
    with pytest.warns(RuntimeWarning, match=reason) as caught:
        again = evaluate_all(**args)
    assert any(str(path) in str(w.message) for w in caught)  # the file is named
    assert again.stats.rejected == 1 and again.stats.ran == 1 and again.stats.cached == 1
    for old, new in zip(rows, again.rows, strict=True):  # rerun: the true rows again
        assert (old.success, old.episode_return, old.metrics) == \
            (new.success, new.episode_return, new.metrics)
    # The rewritten file is used as is.
    third = evaluate_all(**args)
    assert third.stats.cached == 2 and third.stats.rejected == 0


@pytest.mark.parametrize("field, value", [("success", True), ("episode_return", 123.0)])
def test_a_tampered_row_fails_its_checksum_and_is_rerun(cached, field, value):
    def change(row):
        row[field] = value if row[field] != value else not value

    _rerun_after(cached, change, reseal=False, reason="checksum does not match")


def test_an_edited_metric_fails_its_checksum(cached):
    def change(row):
        row["metrics"]["final_distance"] = 0.001

    _rerun_after(cached, change, reseal=False, reason="checksum")


@pytest.mark.parametrize("field, value, reason", [
    ("seed", 99, "seed is 99, the task's is 12"),
    ("agent", "pd-state", "agent is 'pd-state'"),
    ("env_kwargs", {"time_limit": 9.0}, "env_kwargs"),
    ("success", "banana", "invalid success"),
    ("length", 0, "invalid length"),
    ("length", 3.5, "invalid length"),
    ("episode_return", None, "invalid episode_return"),
    ("status", "failed", "status is 'failed'"),
    ("metrics", {"final_distance": "1e400"}, None),  # a string metric is allowed
    ("nan_metrics", ["final_distance"], "invalid nan_metrics"),
    ("nan_metrics", [["a"]], "unhashable"),
])
def test_a_resealed_row_that_breaks_its_task_or_schema_is_rejected(cached, field, value,
                                                                    reason):
    if reason is None:  # valid under the schema: kept (the checksum matches again)
        directory, args, _ = cached
        task = EpisodeTask(DOCK, "state", "random", 12, (("time_limit", 3.0),))
        path = EpisodeCache(directory).path(task)
        original = path.read_text()
        _edit(path, lambda row: row.__setitem__(field, value), reseal=True)
        assert EpisodeCache(directory).load(task).metrics == value
        path.write_text(original)
        return
    _rerun_after(cached, lambda row: row.__setitem__(field, value), reseal=True, reason=reason)


def test_nan_in_a_cached_file_and_foreign_formats_are_rejected(cached):
    directory, _, _ = cached
    task = EpisodeTask(DOCK, "state", "random", 11, (("time_limit", 3.0),))
    cache = EpisodeCache(directory)
    path = cache.path(task)
    original = path.read_text()
    try:
        data = json.loads(original)
        data["row"]["episode_return"] = math.nan  # json writes the NaN literal
        path.write_text(json.dumps(data))
        with pytest.warns(RuntimeWarning, match="rejected"):
            assert cache.load(task) is None
        data = json.loads(original)
        del data["checksum"]  # the format before checksums
        path.write_text(json.dumps(data))
        with pytest.warns(RuntimeWarning, match="not a cached episode of this format"):
            assert cache.load(task) is None
        assert [p for p, _ in cache.rejected] == [path, path]
    finally:
        path.write_text(original)
    assert cache.load(task) is not None


# ------------------------------------------------------------------ NaN metrics
def _row(seed, rmse, **extra):
    metrics = {"rmse": None if rmse is None or math.isnan(rmse) else rmse}
    nan = ("rmse",) if rmse is not None and math.isnan(rmse) else ()
    return EpisodeRow(env_id=DOCK, agent="a", seed=seed, obs_mode="state", scenario="s",
                      episode_return=1.0, length=5, success=True, failure_reason="",
                      metrics=metrics, wall_time_s=0.1, nan_metrics=nan, **extra)


def test_a_nan_metric_is_counted_and_shown_not_dropped():
    rows = [_row(1, 0.1), _row(2, math.nan), _row(3, 0.3)]
    (summary,) = summarise(rows)
    stat = summary["metrics"]["rmse"]
    assert stat["n"] == 2 and stat["nan"] == 1 and stat["mean"] == pytest.approx(0.2)
    assert summary["episodes"] == 3
    assert "(n=2; 1 NaN)" in cell_text(summary, "rmse")
    (all_nan,) = summarise([_row(1, math.nan), _row(2, math.nan)])
    assert all_nan["metrics"]["rmse"]["n"] == 0
    assert cell_text(all_nan, "rmse") == "NaN (2 of 2)"
    # A metric that does not apply (None, not NaN: e.g. docking_time when not docked)
    # is neither averaged nor counted as NaN.
    (absent,) = summarise([_row(1, 0.1), _row(2, None)])
    assert absent["metrics"]["rmse"]["n"] == 1 and "nan" not in absent["metrics"]["rmse"]


class _NanStatsAgent:
    """Holds still; its stats report a NaN, as a diverged estimator's would."""

    def reset(self, seed):
        pass

    def act(self, obs, info):
        return np.zeros(4)

    def stats(self):
        return {"residual": math.nan, "iterations": 3}


def test_run_episode_records_which_metrics_were_nan():
    env = gym.make(DOCK, obs_mode="state", time_limit=0.5)
    try:
        row = run_episode(env, _NanStatsAgent(), 5, DOCK, "nan-stats")
    finally:
        env.close()
    assert row.nan_metrics == ("agent_residual",)
    assert row.metrics["agent_residual"] is None and row.metrics["agent_iterations"] == 3.0


# ------------------------------------------------------------------ arguments
def test_a_keyword_set_twice_is_refused_and_levels_follow_one_rule():
    assert scenario_groups([[]], None, None) == [[f"difficulty={lv}"] for lv in DEFAULT_LEVELS]
    assert scenario_groups([["difficulty=easy"]], None, None) == [["difficulty=easy"]]
    assert scenario_groups([["time_limit=5"], ["difficulty=easy"]], None, None) == \
        [["time_limit=5", f"difficulty={DEFAULT_LEVELS[0]}"],
         ["time_limit=5", f"difficulty={DEFAULT_LEVELS[1]}"], ["difficulty=easy"]]
    assert scenario_groups([["time_limit=5"]], "current", ["hard", "hard"]) == \
        [["time_limit=5", "scenario=current", "difficulty=hard"]]
    for groups, scenario, levels, option in (([["difficulty=easy"]], None, ["paper"],
                                              "--difficulty"),
                                             ([["Dock:scenario=current"]], "mismatch", None,
                                              "--scenario")):
        with pytest.raises(ValueError, match=f"and {option} both set"):
            scenario_groups(groups, scenario, levels)


@pytest.mark.parametrize("argv, message", [
    (["--env-kwargs", "difficulty=nope"], "difficulty must be one of"),
    (["--env-kwargs", "difficulty=easy", "--difficulty", "paper"],
     "--env-kwargs difficulty=easy and --difficulty both set difficulty"),
    (["--env-kwargs", "difficulty=easy", "difficulty=hard"], "already set"),
    (["--env-kwargs", "scenario=current", "--scenario", "mismatch"], "both set scenario"),
    (["--seeds", "8611,8611"], "8611 more than once"),
    (["--seeds=-5"], "non-negative"),
    (["--seeds", "100005-100001"], "reversed"),
])
def test_evaluate_refuses_conflicting_duplicate_and_negative_arguments(tmp_path, capsys, argv,
                                                                      message):
    base = ["--envs", "DockingStation-v2", "--agents", "random", "--seeds", "8611",
            "--no-progress", "--no-video", "--out", str(tmp_path)]
    with pytest.raises(SystemExit) as exc:
        evaluate.main([*base, *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "leaderboard.json").exists()


# ------------------------------------------------------------------ actions
BAD_ACTIONS = [
    (None, "action is None"),
    (np.array([1 + 1j, 0, 0, 0]), "complex numbers"),
    ([True, False, True, False], "booleans"),
    (["a", "b", "c", "d"], "text"),
    ([1, [2, 3]], "not an array of shape"),
    (np.zeros(3), "shape"),
    ([math.nan, 0, 0, 0], "finite"),
    ([math.inf, 0, 0, 0], "finite"),
]


@pytest.mark.parametrize("action, message", BAD_ACTIONS)
def test_cpu_env_refuses_bad_actions_saying_what_was_given(action, message):
    env = gym.make(DOCK, obs_mode="state")
    env.reset(seed=3)
    with pytest.raises(ValueError, match=message):
        env.step(action)
    env.close()


def test_a_huge_finite_action_is_clipped_like_a_small_one():
    env = gym.make(DOCK, obs_mode="state")
    results = []
    for action in ([1e300, -1e300, 0, 2], [2.0, -2.0, 0, 1.0], np.array([3, -3, 0, 1])):
        env.reset(seed=3)
        obs, *_ = env.step(action)
        results.append(obs)
    env.close()
    np.testing.assert_array_equal(results[0], results[1])
    np.testing.assert_array_equal(results[0], results[2])
