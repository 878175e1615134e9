"""The evaluation library: seeds, applicability, episode metrics, cache, failures, aggregation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from baselines import evaluation, fileio
from baselines.agents.random_agent import RandomAgent
from baselines.commands.evaluate import parse_seeds
from baselines.evaluation import (
    EVAL_SEED_BASE,
    EpisodeCache,
    EpisodeRow,
    EpisodeTask,
    default_seeds,
    evaluate_all,
    plan,
    resolve_env_kwargs,
    run_episode,
    run_task,
    summarise,
)
from baselines.evaluation import evaluate as run_evaluation
from baselines.registry import AgentSpec, agent_spec, make_agent
from tests import leaderboard_agents
from tests.conftest import DOCKING_IDS, make_env
from tests.test_stats import wilson_closed_form

DOCK = DOCKING_IDS[0]
LARS = "auv_envs/LARSCapture-v0"
ACOUSTIC = "auv_envs/AcousticTracking-v2"
TEST_AGENTS = ("tests.leaderboard_agents",)


def _comparable(row: EpisodeRow) -> dict:
    """A row as JSON data (NaN -> None) without its wall time, which differs between runs."""
    return {k: v for k, v in evaluation.row_to_dict(row).items() if k != "wall_time_s"}


def test_parse_seeds():
    assert parse_seeds("3-6") == [3, 4, 5, 6]
    assert parse_seeds("1,5,9") == [1, 5, 9]
    assert parse_seeds("7") == [7]
    for bad in ("a-b", "1,,2"):
        with pytest.raises(ValueError, match="seeds"):
            parse_seeds(bad)
    with pytest.raises(ValueError, match="reversed; did you mean 3-6"):
        parse_seeds("6-3")
    for bad, message in (("-5", "non-negative"), ("8611,8611", "8611 more than once"),
                         ("3,-1", "non-negative")):
        with pytest.raises(ValueError, match=message):
            parse_seeds(bad)
    for seeds in ([1, 1], [-2], [1.5], [True]):
        with pytest.raises(ValueError, match="seeds"):
            evaluate_all(env_ids=[DOCK], agents=["random"], seeds=seeds)


def test_default_seeds_are_disjoint_from_training_range():
    seeds = default_seeds(4)
    assert seeds == list(range(EVAL_SEED_BASE, EVAL_SEED_BASE + 4))
    with pytest.raises(ValueError):
        default_seeds(0)


def test_evaluate_is_deterministic_and_summarises():
    rows1 = run_evaluation([DOCK], ["pd-state", "random"], [10, 11])
    rows2 = run_evaluation([DOCK], ["pd-state", "random"], [10, 11])
    assert [r.episode_return for r in rows1] == [r.episode_return for r in rows2]
    summary = {s["agent"]: s for s in summarise(rows1)}
    success = summary["pd-state"]["metrics"]["success"]
    assert {k: success[k] for k in ("mean", "std", "n")} == {"mean": 1.0, "std": 0.0, "n": 2}
    assert success["ci"][1] == 1.0 and 0.3 < success["ci"][0] < 0.4  # Wilson of 2/2
    assert summary["random"]["metrics"]["success"]["mean"] == 0.0
    assert summary["pd-state"]["episodes"] == 2
    returns = [r.episode_return for r in rows1 if r.agent == "random"]
    assert summary["random"]["metrics"]["return"]["mean"] == pytest.approx(np.mean(returns))
    assert summary["random"]["metrics"]["return"]["std"] == pytest.approx(np.std(returns))


def test_evaluate_rejects_unknown_names_naming_valid_ones():
    with pytest.raises(ValueError, match="registered: .*DockingStation-v2"):
        run_evaluation(["auv_envs/Nope-v0"], ["random"], [1])
    with pytest.raises(ValueError, match="did you mean pd-state"):
        run_evaluation([DOCK], ["pd-stat"], [1])


# ------------------------------------------------------------ applicability
def test_agent_spec_keeps_positional_construction_and_normalises_modes():
    spec = AgentSpec("a", RandomAgent, "state", None, "d")
    assert spec.obs_modes == ("state",) and dict(spec.env_kwargs) == {}
    spec = AgentSpec("b", RandomAgent, "features", [DOCK], "d", obs_modes=("image", "features"))
    assert spec.obs_modes == ("features", "image") and spec.env_ids == (DOCK,)
    with pytest.raises(ValueError, match="obs modes"):
        AgentSpec("c", RandomAgent, "", None, "d")
    with pytest.raises(ValueError, match="env_ids"):
        AgentSpec("d", RandomAgent, "state", DOCK, "d")


def test_skip_reasons_name_the_environments_and_obs_modes():
    reason = agent_spec("pd-state").skip_reason(ACOUSTIC)
    assert "supports only" in reason and DOCK in reason
    images = AgentSpec("img", RandomAgent, "image", None, "d")
    reason = images.skip_reason(ACOUSTIC)
    assert "image" in reason and "measurements" in reason
    assert images.skip_reason(DOCK) is None
    assert "not state" in images.skip_reason(DOCK, "state")
    both = AgentSpec("both", RandomAgent, "stereo", None, "d", obs_modes=("features",))
    assert both.modes_for(DOCK) == ("features",)
    assert both.modes_for(LARS) == ("stereo", "features")
    assert both.modes_for(ACOUSTIC) == ()


def test_plan_skips_inapplicable_pairs_with_reasons_and_expands_variants():
    tasks, skipped = plan([DOCK, LARS], ["random", "pd-state"], [1, 2])
    assert {(t.env_id, t.agent) for t in tasks} == {(DOCK, "random"), (DOCK, "pd-state"),
                                                    (LARS, "random")}
    assert len(tasks) == 6 and all(t.obs_mode == "state" for t in tasks)
    assert [(s["env_id"], s["agent"]) for s in skipped] == [(LARS, "pd-state")]
    assert "supports only" in skipped[0]["reason"]

    tasks, skipped = plan([DOCK], ["random"], [1], obs_modes=["features"])
    assert not tasks and "requested features" in skipped[0]["reason"]

    variants = [{DOCK: {"scenario": "current"}}, {DOCK: {"scenario": "mismatch"}}]
    tasks, _ = plan([DOCK, LARS], ["random"], [1], env_kwargs=variants)
    assert sorted(t.scenario for t in tasks if t.env_id == DOCK) == ["scenario=current",
                                                                     "scenario=mismatch"]
    assert [t.scenario for t in tasks if t.env_id == LARS] == ["default"]  # not duplicated


def test_agent_env_kwargs_build_its_env_and_conflicting_runs_are_skipped():
    evaluation.import_agent_modules(TEST_AGENTS)
    row = run_task(EpisodeTask(LARS, "state", "test-position", 1))
    assert row.status == "ok", row.error  # the factory raises unless control="position"
    tasks, skipped = plan([LARS], ["test-position"], [1], env_kwargs=[{LARS: {"control":
                                                                              "torque"}}])
    assert not tasks and skipped[0]["reason"] == "needs control=position"
    tasks, skipped = plan([LARS], ["test-position"], [1], env_kwargs=[{LARS: {"control":
                                                                              "position"}}])
    assert len(tasks) == 1 and not skipped
    assert run_task(tasks[0]).status == "ok"


def test_resolve_env_kwargs_routes_keys_and_rejects_bad_ones():
    out = resolve_env_kwargs(
        [DOCK, ACOUSTIC],
        ["time_limit=5", "AcousticTracking-v2:disturbance=high", "scenario=current"],
        defaults={ACOUSTIC: {"time_limit": 30.0, "trajectory": "static"}},
    )
    assert out[DOCK] == {"time_limit": 5, "scenario": "current"}
    assert out[ACOUSTIC] == {"time_limit": 5, "disturbance": "high", "trajectory": "static"}
    assert resolve_env_kwargs([LARS], ["image_size=(64, 48)"])[LARS] == {"image_size": (64, 48)}
    for bad, match in [("nope=1", "no selected environment takes 'nope'"),
                       ("LARSCapture-v0:time_limit=1", "not among the selected"),
                       ("DockingStation-v2:disturbance=high", "no selected environment"),
                       ("time_limit", "KEY=VALUE")]:
        with pytest.raises(ValueError, match=match):
            resolve_env_kwargs([DOCK, ACOUSTIC], [bad])


def test_bad_env_argument_values_fail_before_any_episode():
    with pytest.raises(ValueError, match="rejects arguments time_limit=-1"):
        evaluate_all([DOCK], ["random"], [1], env_kwargs=[{DOCK: {"time_limit": -1}}])


# ---------------------------------------------------------- episode metrics
class _EstimatingPD:
    """pd-state plus a position estimate 0.3 m ahead of the observed CG, and stats."""

    OFFSET = np.array([0.3, 0.0, 0.0])

    def __init__(self, env):
        self.inner = make_agent("pd-state", env)
        self.calls = 0
        self.latest = None

    def reset(self, seed=None):
        self.inner.reset(seed)
        self.calls, self.latest = 0, None

    def act(self, observation, info):
        self.calls += 1
        self.latest = np.asarray(observation[:3], dtype=float) + self.OFFSET
        return self.inner.act(observation, info)

    def position_estimate(self):
        # No estimate on the first step: coverage is counted.
        return None if self.calls == 1 else self.latest

    def stats(self):
        return {"calls": self.calls, "name": "not a number", "warm": True}


def test_run_episode_scores_position_estimates_against_the_observed_step_and_merges_stats():
    env = make_env(DOCK, "state")
    try:
        row = run_episode(env, _EstimatingPD(env), 3, DOCK, "est")
    finally:
        env.close()
    m = row.metrics
    # The state observation is the float32 true position of the same step, so the
    # error is the offset; scoring against the next step's truth would add ~v*dt.
    assert m["estimate_error_mean"] == pytest.approx(0.3, abs=1e-5)
    assert m["estimate_error_max"] == pytest.approx(0.3, abs=1e-5)
    assert m["estimate_steps"] == row.length - 1
    assert m["agent_calls"] == row.length and m["agent_warm"] == 1.0
    assert "agent_name" not in m


def test_run_episode_counts_constraint_violation_steps():
    env = make_env(DOCK, "state")
    try:
        row = run_episode(env, make_agent("random", env), 4, DOCK, "random")
        agent = make_agent("random", env)
        obs, info = env.reset(seed=4)
        agent.reset(4)
        counts, done = {"violation_fov": 0, "violation_seabed": 0}, False
        while not done:
            obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
            for key in counts:
                counts[key] += bool(info[key])
            done = terminated or truncated
    finally:
        env.close()
    assert counts["violation_fov"] > 0
    assert row.metrics["violation_fov_steps"] == counts["violation_fov"]
    assert row.metrics["violation_seabed_steps"] == counts["violation_seabed"]


class _NaNEstimate(_EstimatingPD):
    def position_estimate(self):
        return np.array([np.nan, 0.0, 0.0])


def test_non_finite_position_estimate_is_an_error():
    env = make_env(DOCK, "state")
    try:
        with pytest.raises(ValueError, match="finite"):
            run_episode(env, _NaNEstimate(env), 1, DOCK, "nan")
    finally:
        env.close()


# ------------------------------------------------------------------ failures
def test_raising_agent_is_recorded_as_failed_and_the_run_goes_on(tmp_path):
    run = evaluate_all([DOCK], ["test-raises", "random"], [1, 2], cache_dir=tmp_path,
                       agent_modules=TEST_AGENTS)
    failed = [r for r in run.rows if r.agent == "test-raises"]
    assert len(failed) == 2 and all(r.status == "failed" for r in failed)
    assert all("RuntimeError: deliberate failure at step 5" in r.error for r in failed)
    assert all("leaderboard_agents.py" in r.error for r in failed)  # where it raised
    assert all(r.status == "ok" and r.length > 0 for r in run.rows if r.agent == "random")
    assert run.stats.failed == 2 and run.stats.ran == 4
    summary = {s["agent"]: s for s in summarise(run.rows)}
    assert summary["test-raises"]["status"] == "failed"
    assert summary["test-raises"]["metrics"]["success"]["mean"] == 0.0
    assert "return" not in summary["test-raises"]["metrics"]
    assert len(summary["test-raises"]["errors"]) == 1
    assert len(list(tmp_path.glob("*.json"))) == 2  # failed episodes are not cached


def test_unregistered_agent_in_a_task_is_a_failed_row():
    row = run_task(EpisodeTask(DOCK, "state", "never-registered", 1))
    assert row.status == "failed" and "never-registered" in row.error


def test_summarise_aggregates_mean_std_n_and_partial_failures():
    def row(seed, success, status="ok", metrics=None):
        return EpisodeRow(DOCK, "x", seed, "state", "default", 1.0 * seed, 10, success, "",
                          metrics or {}, 0.1, status)

    rows = [row(1, True, metrics={"docking_time": 40.0, "final_distance": 0.1,
                                  "final_lateral_error": -0.1}),
            row(2, False, metrics={"docking_time": None, "final_distance": 0.3,
                                   "final_lateral_error": 0.1}),
            row(3, False, status="failed")]
    (s,) = summarise(rows)
    assert s["status"] == "partial" and s["failed"] == 1 and s["episodes"] == 3
    success = s["metrics"]["success"]
    assert {k: success[k] for k in ("mean", "std", "n")} == {
        "mean": pytest.approx(1 / 3), "std": pytest.approx(np.std([1, 0, 0])), "n": 3}
    # The Wilson interval of 1/3 at 95 % (checked against its closed form in test_stats.py).
    assert success["ci"] == pytest.approx(list(wilson_closed_form(1, 3)), abs=1e-12)
    # One episode has no interval.
    assert s["metrics"]["docking_time"] == {"mean": 40.0, "std": 0.0, "n": 1,
                                            "ci": [None, None]}
    assert s["metrics"]["final_distance"]["mean"] == pytest.approx(0.2)
    # Two returns 1 and 2: bootstrap means are 1, 1.5 or 2; the 2.5/97.5 % points 1 and 2.
    assert s["metrics"]["return"] == {"mean": 1.5, "std": 0.5, "n": 2, "ci": [1.0, 2.0]}
    # A signed deviation: misses to either side do not cancel in its _abs statistics.
    assert s["metrics"]["final_lateral_error"]["mean"] == pytest.approx(0.0)
    assert s["metrics"]["final_lateral_error_abs"]["mean"] == pytest.approx(0.1)


# --------------------------------------------------------------------- cache
def test_rerun_reads_the_cache_and_runs_only_missing_episodes(tmp_path, monkeypatch):
    args = dict(env_ids=[DOCK], agents=["random", "pd-state"], seeds=[1, 2], cache_dir=tmp_path)
    first = evaluate_all(**args)
    assert first.stats.ran == 4 and first.stats.cached == 0
    assert len(list(tmp_path.glob("*.json"))) == 4

    real_run_task = evaluation.backends.run_task
    calls = []

    def counting_run_task(task, agent_modules=(), video=None):
        calls.append(task)
        return real_run_task(task, agent_modules, video)

    monkeypatch.setattr(evaluation.backends, "run_task", counting_run_task)
    second = evaluate_all(**args)
    assert calls == [] and second.stats.cached == 4 and second.stats.ran == 0
    assert [_comparable(r) for r in second.rows] == [_comparable(r) for r in first.rows]
    assert [r.wall_time_s for r in second.rows] == [r.wall_time_s for r in first.rows]

    cache = EpisodeCache(tmp_path)
    lost = EpisodeTask(DOCK, "state", "pd-state", 2)
    cache.path(lost).unlink()
    third = evaluate_all(**args)
    assert calls == [lost] and third.stats.ran == 1 and third.stats.cached == 3
    assert [_comparable(r) for r in third.rows] == [_comparable(r) for r in first.rows]


def test_interrupted_run_keeps_every_finished_episode(tmp_path, monkeypatch):
    real_run_task = evaluation.backends.run_task
    calls = []

    def interrupted(task, agent_modules=(), video=None):
        calls.append(task)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real_run_task(task, agent_modules, video)

    monkeypatch.setattr(evaluation.backends, "run_task", interrupted)
    args = dict(env_ids=[DOCK], agents=["random"], seeds=[1, 2, 3, 4], cache_dir=tmp_path)
    with pytest.raises(KeyboardInterrupt):
        evaluate_all(**args)
    assert len(list(tmp_path.glob("*.json"))) == 2
    assert not list(tmp_path.glob(".*tmp"))  # no half-written files
    monkeypatch.setattr(evaluation.backends, "run_task", real_run_task)
    resumed = evaluate_all(**args)
    assert resumed.stats.cached == 2 and resumed.stats.ran == 2


def test_corrupt_or_foreign_cache_files_are_rerun_with_a_warning(tmp_path):
    args = dict(env_ids=[DOCK], agents=["random"], seeds=[1, 2], cache_dir=tmp_path)
    first = evaluate_all(**args)
    cache = EpisodeCache(tmp_path)
    one, two = (EpisodeTask(DOCK, "state", "random", s) for s in (1, 2))
    cache.path(one).write_text('{"task": {"agent": "random"')  # truncated file
    cache.path(two).write_text(cache.path(two).read_text().replace('"seed": 2', '"seed": 9'))
    with pytest.warns(RuntimeWarning, match="rejected cached episode"):
        second = evaluate_all(**args)
    assert second.stats.ran == 2
    assert [_comparable(r) for r in second.rows] == [_comparable(r) for r in first.rows]
    assert json.loads(cache.path(one).read_text())["row"]["seed"] == 1  # repaired


def test_cache_key_covers_everything_that_changes_the_result():
    base = EpisodeTask(DOCK, "state", "random", 1)
    others = [EpisodeTask(DOCKING_IDS[1], "state", "random", 1),
              EpisodeTask(DOCK, "features", "random", 1),
              EpisodeTask(DOCK, "state", "pd-state", 1),
              EpisodeTask(DOCK, "state", "random", 2),
              EpisodeTask(DOCK, "state", "random", 1, (("scenario", "current"),))]
    keys = {t.key() for t in [base, *others]}
    assert len(keys) == 6 and base.key() == EpisodeTask(DOCK, "state", "random", 1).key()


# ------------------------------------------------------------------ backends
def test_worker_processes_match_in_process_and_import_agent_modules(tmp_path):
    args = dict(env_ids=[DOCK, LARS], agents=["random", "pd-state", "test-raises"],
                seeds=[5], agent_modules=TEST_AGENTS)
    local = evaluate_all(**args, workers=1)
    pool = evaluate_all(**args, workers=2, cache_dir=tmp_path)
    assert [_comparable(r) for r in pool.rows] == [_comparable(r) for r in local.rows]
    raised = [r for r in pool.rows if r.agent == "test-raises"]
    assert raised and all("deliberate failure" in r.error for r in raised)
    assert leaderboard_agents.RAISE_AT_STEP == 5


def test_run_tasks_rejects_bad_backend_and_workers():
    with pytest.raises(ValueError, match="backend"):
        evaluation.run_tasks([], backend="dask")
    with pytest.raises(ValueError, match="workers"):
        evaluation.run_tasks([], workers=0)


def test_failed_row_numbers_are_not_numbers():
    row = evaluation.failed_row(EpisodeTask(DOCK, "state", "random", 1), ValueError("bad"))
    assert math.isnan(row.episode_return) and row.error.startswith("ValueError: bad")
    assert evaluation.row_from_dict(evaluation.row_to_dict(row)).error == row.error


def test_atomic_write_keeps_the_old_file_when_the_write_fails(tmp_path, monkeypatch):
    target = tmp_path / "out" / "file.json"
    evaluation.atomic_write(target, "old")
    evaluation.atomic_write(target, b"new")
    assert target.read_text() == "new"
    plain = tmp_path / "plain"
    plain.write_text("x")
    assert target.stat().st_mode == plain.stat().st_mode  # not mkstemp's 0600

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(fileio.os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        evaluation.atomic_write(target, "newer")
    assert target.read_text() == "new"
    assert [p.name for p in target.parent.iterdir()] == ["file.json"]  # no temp file left


def test_source_fingerprint_sees_every_change_that_matters(tmp_path):
    root = tmp_path / "pkg"
    (root / "sub").mkdir(parents=True)
    (root / "a.py").write_text("x = 1\n")
    (root / "sub" / "b.xml").write_text("<mujoco/>")
    (root / "leaderboard.py").write_text("TITLE = 'one'\n")
    base = evaluation.source_fingerprint([root], ("leaderboard.py",))
    assert evaluation.source_fingerprint([root], ("leaderboard.py",)) == base
    (root / "__pycache__").mkdir()
    (root / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"\0\1")
    (root / "leaderboard.py").write_text("TITLE = 'two'\n")
    assert evaluation.source_fingerprint([root], ("leaderboard.py",)) == base  # ignored
    (root / "sub" / "b.xml").write_text("<mujoco model='x'/>")
    edited = evaluation.source_fingerprint([root], ("leaderboard.py",))
    assert edited != base
    (root / "sub" / "b.xml").rename(root / "sub" / "c.xml")
    assert evaluation.source_fingerprint([root], ("leaderboard.py",)) != edited  # renamed


def test_cached_episodes_of_other_code_run_again(tmp_path, monkeypatch):
    args = dict(env_ids=[DOCK], agents=["random"], seeds=[1], cache_dir=tmp_path)
    first = evaluate_all(**args)
    assert first.stats.ran == 1
    assert evaluate_all(**args).stats.cached == 1
    monkeypatch.setattr(evaluation.episodes, "code_fingerprint", lambda: "edited-code")
    again = evaluate_all(**args)
    assert again.stats.ran == 1 and again.stats.cached == 0
    assert [_comparable(r) for r in again.rows] == [_comparable(r) for r in first.rows]


def test_training_seeds_pool_into_one_ranked_row_and_stay_listed():
    from baselines import leaderboard
    from baselines.stats import wilson_interval

    def row(agent, seed, success):
        return EpisodeRow(DOCK, agent, seed, "features", "default", float(success), 10,
                          success, "", {"docking_time": 20.0 + seed}, 0.1)

    rows = [row("rl-s0", 1, True), row("rl-s0", 2, True), row("rl-s1", 1, True),
            row("rl-s1", 2, False), row("rl-s2", 1, True), row("rl-s2", 2, True),
            row("classic", 1, False), row("classic", 2, False)]
    groups = {"rl-s0": "rl", "rl-s1": "rl", "rl-s2": "rl"}
    summary = summarise(rows, groups)
    by_agent = {r["agent"]: r for r in summary}
    pooled = by_agent["rl"]
    assert pooled["members"] == ["rl-s0", "rl-s1", "rl-s2"] and pooled["group"] is None
    assert pooled["episodes"] == 6 and pooled["metrics"]["success"]["mean"] == pytest.approx(5 / 6)
    assert pooled["metrics"]["success"]["ci"] == pytest.approx(list(wilson_interval(5, 6)))
    assert by_agent["rl-s1"]["group"] == "rl" and by_agent["classic"]["group"] is None
    assert by_agent["rl-s1"]["metrics"]["success"]["mean"] == 0.5  # each seed on its own too

    ordered = leaderboard.by_env(summary)[DOCK]
    assert [r["agent"] for r in ordered] == ["rl", "rl-s0", "rl-s1", "rl-s2", "classic"]
    # Wilson intervals of 5/6 and 0/2 overlap: a tie, between the group and classic only.
    assert leaderboard.rank_labels(ordered) == ["1 (tie)", "seed of rl", "seed of rl",
                                                "seed of rl", "1 (tie)"]
    compact = leaderboard.markdown(summary, compact=True)
    full = leaderboard.markdown(summary)
    assert "rl-s1" not in compact and "| 1 (tie) | rl |" in compact
    assert "| seed of rl | rl-s1 |" in full
    assert "rl-s0" not in leaderboard.overview_html(leaderboard.by_env(summary))
    assert {r["agent"] for r in summarise(rows)} == {"rl-s0", "rl-s1", "rl-s2", "classic"}
