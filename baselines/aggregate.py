"""Across tasks: normalised scores, their IQM with stratified bootstrap intervals, the
probability of improvement, and performance profiles (Agarwal et al. 2021).

A leaderboard table compares agents within one task (an environment at one level);
this module compares them across the tasks of a level, the way Agarwal, Schwarzer,
Castro, Courville and Bellemare ("Deep reinforcement learning at the edge of the
statistical precipice", NeurIPS 2021) recommend: per-episode scores normalised per
task, then

* the **interquartile mean** (IQM: the mean of the middle 50 % of the scores, SciPy's
  ``trim_mean(x, 0.25)``) with a 95 % **stratified bootstrap** interval (episodes
  resampled within each task, so every task keeps its weight);
* the **probability of improvement** P(X > Y) of agent X over Y: per shared task the
  Mann–Whitney probability that a random episode of X scores above one of Y (ties
  count half), averaged over the tasks both ran;
* **performance profiles**: the fraction of an agent's episodes, tasks weighted
  equally, whose score exceeds each threshold τ.

The normalised score of an episode is 0 at ``random``'s mean and 1 at the task's
reference: its return between ``random``'s and the privileged reference agent's mean
returns (:data:`REFERENCES`) where tasks rank by success, and its RMSE between
``random``'s and the posterior Cramér–Rao bound's on a log scale where they rank by
RMSE (acoustic tracking). A task without both anchors is left out. Training seeds of
one group are pooled under the group's name.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import stats

from baselines.stats import BOOTSTRAP_SEED, CONFIDENCE, RESAMPLES

#: The privileged reference of each success-ranked environment: score 1.
REFERENCES = {
    "auv_envs/DockingStation-v2": "pd-state",
    "auv_envs/LampArrayDocking-v2": "pd-state",
    "auv_envs/DockingMission-v0": "homing-pd-state",
    "auv_envs/LARSCapture-v0": "ckf-pd-state",
}
#: The anchor of score 0 in every task.
RANDOM = "random"
#: Thresholds of the performance profiles.
TAUS = np.linspace(0.0, 1.2, 25)


def iqm(scores, axis=None):
    """The interquartile mean: the mean of the middle 50 % (25 % trimmed off each end);
    along ``axis`` of an array (a float when ``axis`` is None)."""
    value = stats.trim_mean(np.asarray(scores, dtype=float), 0.25, axis=axis)
    return float(value) if axis is None else value


def improvement_probability(x, y) -> float:
    """P(X > Y) + P(X = Y) / 2 for one episode of each: the Mann–Whitney U of ``x``
    against ``y`` over ``len(x) * len(y)``."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return float(stats.mannwhitneyu(x, y).statistic / (x.size * y.size))


def profile(per_task: Sequence, taus=TAUS) -> np.ndarray:
    """Per threshold, the fraction of scores above it, each task's scores weighing the
    same (the mean over tasks of each task's fraction)."""
    return np.mean([[np.mean(np.asarray(s) > tau) for tau in taus] for s in per_task], axis=0)


def stratified_interval(per_task: Sequence, statistic, resamples: int = RESAMPLES,
                        confidence: float = CONFIDENCE, seed: int = BOOTSTRAP_SEED):
    """Percentile interval of ``statistic`` over bootstrap samples that redraw each
    task's scores from that task alone (a fixed generator: the same scores give the same
    interval). ``statistic`` takes the list of per-task resamples, each a
    ``(resamples, n_task)`` array, and returns the ``(resamples,)`` statistics (all
    resamples at once: thousands of small calls cost seconds)."""
    rng = np.random.default_rng(seed)
    tasks = [np.asarray(s, dtype=float) for s in per_task]
    values = statistic([t[rng.integers(t.size, size=(resamples, t.size))] for t in tasks])
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(values, [tail, 100 - tail])
    return float(low), float(high)


def _level(row) -> str:
    return str(dict(row.env_kwargs).get("difficulty", "default"))


def normalised_scores(episodes: Sequence, summary: Sequence[Mapping] = (),
                      groups: Mapping[str, str] | None = None) -> dict:
    """``{level: {agent: {task: scores}}}`` of the completed episodes; ``summary`` gives the
    bound rows (``reference``) that anchor tracking tasks, ``groups`` maps a training
    seed to its group (pooled under the group's name)."""
    groups = dict(groups or {})
    tasks: dict[tuple, dict[str, list]] = {}
    for row in episodes:
        if row.status != "ok":
            continue
        key = (_level(row), row.env_id, row.scenario)
        tasks.setdefault(key, {}).setdefault(groups.get(row.agent, row.agent), []).append(row)
    bounds = {(r["env_id"], r["scenario"]): r["metrics"]["rmse"]["mean"] for r in summary
              if r.get("reference") and "rmse" in r["metrics"]}
    out: dict = {}
    for (level, env_id, scenario), agents in tasks.items():
        if RANDOM not in agents:
            continue
        task = f"{env_id.split('/')[-1]} ({scenario})"
        if (env_id, scenario) in bounds:  # tracking: log RMSE from random's to the bound
            low = math.log(np.mean([r.metrics.get("rmse") or math.nan for r in agents[RANDOM]]))
            if not math.isfinite(low):
                continue
            high = math.log(bounds[env_id, scenario])

            def score(row, low=low, high=high):
                rmse = row.metrics.get("rmse")
                if not (isinstance(rmse, int | float) and rmse > 0 and math.isfinite(rmse)):
                    return math.nan  # left out below, as the table leaves out a NaN
                return (low - math.log(rmse)) / (low - high)
        elif REFERENCES.get(env_id) in agents:  # return from random's to the reference's
            low = float(np.mean([r.episode_return for r in agents[RANDOM]]))
            high = float(np.mean([r.episode_return for r in agents[REFERENCES[env_id]]]))
            if high <= low:
                continue

            def score(row, low=low, high=high):
                return (row.episode_return - low) / (high - low)
        else:
            continue
        for agent, rows in agents.items():
            values = [v for v in map(score, rows) if math.isfinite(v)]
            if values:
                out.setdefault(level, {}).setdefault(agent, {})[task] = values
    return out


def level_view(scores: Mapping[str, Mapping[str, list]]) -> dict:
    """One level's comparison: per agent its IQM, interval, tasks and profile, and the
    probability of improvement of every ordered pair over the tasks both ran."""
    agents = {}
    for agent, per_task in scores.items():
        tasks = list(per_task.values())
        pooled = np.concatenate(tasks)
        agents[agent] = {
            "iqm": iqm(pooled),
            "ci": stratified_interval(tasks, lambda t: iqm(np.concatenate(t, axis=1), axis=1)),
            "tasks": sorted(per_task), "episodes": int(pooled.size),
            "profile": profile(tasks).tolist(),
        }
    improvement = {}
    for x, x_tasks in scores.items():
        for y, y_tasks in scores.items():
            shared = sorted(set(x_tasks) & set(y_tasks))
            if x != y and shared:
                improvement[x, y] = float(np.mean([
                    improvement_probability(x_tasks[t], y_tasks[t]) for t in shared]))
    return {"agents": agents, "improvement": improvement, "taus": TAUS.tolist()}
