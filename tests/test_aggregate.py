"""Across-task statistics, checked against values worked by hand."""

from __future__ import annotations

import numpy as np
import pytest

from baselines import aggregate
from baselines.evaluation import EpisodeRow

DOCK, LARS, ACOUSTIC = ("auv_envs/DockingStation-v2", "auv_envs/LARSCapture-v0",
                        "auv_envs/AcousticTracking-v2")


def test_iqm_is_the_mean_of_the_middle_half():
    assert aggregate.iqm([1, 2, 3, 4, 5, 6, 7, 8]) == 4.5  # (3 + 4 + 5 + 6) / 4
    assert aggregate.iqm([0, 0, 0, 10]) == 0.0  # the outlier is trimmed
    assert aggregate.iqm([2.0] * 5) == 2.0


def test_probability_of_improvement_counts_wins_and_half_ties():
    # Pairs of (1, 2) against (0, 3): 1>0, 1<3, 2>0, 2<3 -> 2 of 4.
    assert aggregate.improvement_probability([1, 2], [0, 3]) == 0.5
    assert aggregate.improvement_probability([5, 6], [1, 2]) == 1.0
    # (1, 1) against (1, 2): two ties (1/2 each) and two losses -> 1 of 4.
    assert aggregate.improvement_probability([1, 1], [1, 2]) == 0.25


def test_profiles_weigh_tasks_equally():
    # Task A: scores (0, 1) -> above 0.5: 1/2; task B: (1, 1, 1, 1) -> 1. Mean 3/4.
    curve = aggregate.profile([[0.0, 1.0], [1.0, 1.0, 1.0, 1.0]], taus=[0.5, 1.0])
    np.testing.assert_allclose(curve, [0.75, 0.0])


def test_stratified_bootstrap_keeps_each_task_and_brackets_the_estimate():
    tasks = [np.linspace(0, 1, 30), np.linspace(2, 3, 10)]
    low, high = aggregate.stratified_interval(tasks, lambda t: np.mean(t[1], axis=1))
    # Task 2's mean, 2.5, from task 2's scores alone: about 2.5 -+ 1.96 * 0.32 / sqrt(10).
    assert low == pytest.approx(2.30, abs=0.05) and high == pytest.approx(2.70, abs=0.05)
    # Equal scores: no spread, the point itself.
    assert aggregate.stratified_interval([[1.0, 1.0]], lambda t: np.mean(t[0], axis=1)) == (1.0,
                                                                                           1.0)


def _row(env_id, agent, seed, ret, level="paper", rmse=None):
    metrics = {} if rmse is None else {"rmse": rmse}
    return EpisodeRow(env_id, agent, seed, "state", f"difficulty={level}", ret, 10, False, "",
                      metrics, 0.1, env_kwargs={"difficulty": level})


def test_scores_run_from_random_to_the_reference():
    episodes = [_row(DOCK, "random", 1, -10.0), _row(DOCK, "random", 2, -6.0),  # mean -8
                _row(DOCK, "pd-state", 1, 12.0), _row(DOCK, "pd-state", 2, 12.0),
                _row(DOCK, "mine-s0", 1, 2.0), _row(DOCK, "mine-s1", 1, 7.0),
                _row(ACOUSTIC, "random", 1, 0.0, rmse=100.0),
                _row(ACOUSTIC, "tracker", 1, 0.0, rmse=1.0),
                _row(LARS, "random", 1, 0.0)]  # no reference: LARS is left out
    bound = {"env_id": ACOUSTIC, "scenario": "difficulty=paper", "reference": True,
             "metrics": {"rmse": {"mean": 0.01}}}
    scores = aggregate.normalised_scores(episodes, [bound], {"mine-s0": "mine",
                                                             "mine-s1": "mine"})
    paper = scores["paper"]
    task = "DockingStation-v2 (difficulty=paper)"
    assert paper["random"][task] == [-0.1, 0.1]  # (-10 + 8) / 20, (-6 + 8) / 20
    assert paper["pd-state"][task] == [1.0, 1.0]
    assert paper["mine"][task] == [0.5, 0.75]  # the seeds pooled under their group
    # log(100 / 1) / log(100 / 0.01) = 2 / 4.
    assert paper["tracker"]["AcousticTracking-v2 (difficulty=paper)"] == pytest.approx([0.5])
    assert all("LARSCapture" not in t for agent in paper.values() for t in agent)
    view = aggregate.level_view(paper)
    assert view["agents"]["pd-state"]["iqm"] == 1.0
    assert view["improvement"]["pd-state", "random"] == 1.0
    assert view["improvement"]["mine", "random"] == 1.0
    assert ("tracker", "mine") not in view["improvement"]  # no task in common


def test_the_page_shows_the_levels_across_tasks(tmp_path):
    from baselines import leaderboard
    from baselines.evaluation import summarise

    episodes = [_row(DOCK, agent, seed, ret) for agent, rets in
                (("random", (-9.0, -7.0)), ("pd-state", (11.0, 13.0)), ("mine", (1.0, 5.0)))
                for seed, ret in zip((1, 2), rets, strict=True)]
    paths = leaderboard.write(tmp_path, summarise(episodes), episodes=episodes)
    assert "plots/across-tasks-paper.png" in paths
    page = (tmp_path / "leaderboard.html").read_text()
    assert '<section id="across">' in page and 'src="plots/across-tasks-paper.png"' in page
    md = (tmp_path / "leaderboard.md").read_text()
    # mine: returns 1 and 5 between random's mean -8 and the reference's 12: 0.45, 0.65.
    assert "| mine | 0.55 [0.45, 0.65] | 1 | 2 |" in md
