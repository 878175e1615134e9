"""Episodes -> leaderboard rows: per-agent statistics with 95 % intervals, and bound rows.

:func:`summarise` gives one row per (environment, obs mode, scenario, agent)
and one per group of training seeds; :func:`bound_rows` adds the reference
rows of environments that state a bound on their ranking metric.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Mapping, Sequence

import numpy as np

import auv_envs
from auv_envs.core.env import TaskEnv
from baselines.evaluation.episodes import EpisodeRow, is_number
from baselines.stats import RANK_METRICS, bootstrap_interval, wilson_interval

#: Episode metrics that are signed deviations (either side of the target is a
#: miss): the leaderboard averages their magnitudes, as ``<key>_abs``, so that a
#: miss to the left does not cancel a miss to the right.
SIGNED_METRICS = ("final_lateral_error", "final_vertical_error", "final_heading_error_deg")


def _stat(values: Sequence[float], success: bool = False) -> dict:
    """Mean, population std, n and a 95 % interval of the mean (Wilson for a
    success rate, percentile bootstrap otherwise; ``None`` ends for one value)."""
    arr = np.asarray(values, dtype=float)
    if success:
        ci = wilson_interval(int(round(arr.sum())), arr.size)
    else:
        ci = bootstrap_interval(arr)
    return {"mean": float(arr.mean()), "std": float(arr.std()), "n": int(arr.size),
            "ci": [None if math.isnan(c) else c for c in ci]}


def summarise(rows: Sequence[EpisodeRow], groups: Mapping[str, str] | None = None) -> list[dict]:
    """One leaderboard row per (env, obs mode, scenario, agent), in first-seen order.

    ``metrics`` maps a name to ``{"mean", "std", "n", "ci"}`` (population std
    over the ``n`` episodes that report it as a finite number, the number
    averaged; ``ci`` the 95 % interval of the mean, :func:`_stat`), plus
    ``"nan"``, the episodes whose value was NaN or inf
    (:attr:`EpisodeRow.nan_metrics`), where there are any (with none finite,
    the mean is NaN and ``n`` 0): ``success`` over every episode (a
    failed episode counts as no success), ``return`` and ``length`` and each
    numeric episode metric over the completed episodes (``docking_time`` only
    exists on success, so its ``n`` is the successful episodes). Booleans
    count as 0/1. Each of :data:`SIGNED_METRICS` also gets ``<key>_abs``, the
    statistics of its magnitude. ``status`` is ``ok``, ``partial`` (some episodes failed) or
    ``failed``; ``errors`` lists the distinct errors.

    ``groups`` maps agent names to the group they are training seeds of
    (:func:`baselines.registry.agent_groups`). Each group then gets one more
    row, after its members, pooling their episodes (``agent`` the group,
    ``members`` the seeds' names); a member's row carries ``group``.
    """
    groups = dict(groups or {})
    by_key: dict[tuple, list[EpisodeRow]] = {}
    for row in rows:
        by_key.setdefault((row.env_id, row.obs_mode, row.scenario, row.agent), []).append(row)
    pooled: dict[tuple, list[EpisodeRow]] = {}
    members: dict[tuple, list[str]] = {}
    for (env_id, obs_mode, scenario, agent), items in by_key.items():
        if agent in groups:
            key = (env_id, obs_mode, scenario, groups[agent])
            pooled.setdefault(key, []).extend(items)
            members.setdefault(key, []).append(agent)
    summary = [dict(_summary_row(key, items), group=groups.get(key[3]))
               for key, items in by_key.items()]
    summary += [dict(_summary_row(key, items), group=None, members=sorted(members[key]))
                for key, items in pooled.items()]
    return summary


#: The agent name and label of a bound row (:func:`bound_rows`).
BOUND_AGENT = "pcrb"
BOUND_LABEL = "posterior Cramér–Rao bound of the RMSE only"


def bound_rows(summary: Sequence[Mapping]) -> list[dict]:
    """Per environment and scenario whose environment states a bound on its ranking
    metric, a reference row ``agent`` = :data:`BOUND_AGENT` (``label``
    :data:`BOUND_LABEL`), ``reference`` True: shown beside the agents, never ranked.

    The acoustic tracking bound is per episode (``env.unwrapped.trajectory_bound()``
    after ``reset(seed)``: the posterior Cramér–Rao bound of that episode's trajectory,
    :mod:`auv_envs.tasks.acoustic.bound`), so the row holds its statistics over the
    seeds the scenario's agents ran (the union of their rows' ``seeds``), with the same
    interval as an agent's metric. The environment is built with the scenario's
    arguments, so each difficulty level gets its own. A scenario without seeds gets no row.
    """
    seeds: dict[tuple, set] = {}
    for row in summary:
        if not row.get("reference"):
            seeds.setdefault((row["env_id"], row["scenario"]), set()).update(row["seeds"])
    out, seen = [], set()
    for row in summary:
        key = (row["env_id"], row["scenario"])
        if key in seen or not seeds.get(key):
            continue
        seen.add(key)
        cls = auv_envs.task_class(row["env_id"])
        if not hasattr(cls, "trajectory_bound"):
            continue
        env = TaskEnv(cls, **row["env_kwargs"])
        try:
            values = []
            for seed in sorted(seeds[key]):
                env.reset(seed=seed)
                values.append(env.trajectory_bound())
        finally:
            env.close()
        out.append({
            "env_id": row["env_id"], "obs_mode": "model", "scenario": row["scenario"],
            "agent": BOUND_AGENT, "label": BOUND_LABEL, "episodes": len(values), "failed": 0,
            "status": "ok", "seeds": sorted(seeds[key]), "errors": [], "failure_reasons": {},
            "env_kwargs": row["env_kwargs"], "group": None, "reference": True,
            "metrics": {"rmse": _stat(values)},
        })
    return out


def _summary_row(key: tuple, items: Sequence[EpisodeRow]) -> dict:
    """The leaderboard row of one (env, obs mode, scenario, agent)'s episodes."""
    env_id, obs_mode, scenario, agent = key
    done = [r for r in items if r.status == "ok"]
    values: dict[str, list[float]] = {"success": [float(r.success) for r in items]}
    if done:
        values["return"] = [r.episode_return for r in done]
        values["length"] = [float(r.length) for r in done]
    not_numbers: collections.Counter = collections.Counter()
    for r in done:
        for name, value in r.metrics.items():
            if is_number(value) and math.isfinite(float(value)) and name != "success":
                values.setdefault(name, []).append(float(value))
                if name in SIGNED_METRICS:
                    values.setdefault(f"{name}_abs", []).append(abs(float(value)))
        for name in r.nan_metrics:
            not_numbers[name] += 1
            if name in SIGNED_METRICS:
                not_numbers[f"{name}_abs"] += 1
    metrics = {k: _stat(v, success=k == "success") for k, v in values.items()}
    by_seed: dict[str, dict[str, list[float]]] = {}  # per rank metric: seed -> values
    for r in items:  # success over every episode, a metric over the completed ones
        for key, _ in RANK_METRICS:
            value = r.success if key == "success" else (
                r.metrics.get(key) if r.status == "ok" else None)
            if is_number(value) and math.isfinite(float(value)):
                by_seed.setdefault(key, {}).setdefault(str(r.seed), []).append(float(value))
    for name, count in not_numbers.items():  # shown, never dropped silently
        metrics.setdefault(name, {"mean": math.nan, "std": math.nan, "n": 0,
                                  "ci": [None, None]})["nan"] = count
    failed = len(items) - len(done)
    reasons = collections.Counter(r.failure_reason for r in done if r.failure_reason)
    return {
        "env_id": env_id,
        "obs_mode": obs_mode,
        "scenario": scenario,
        "agent": agent,
        "episodes": len(items),
        "failed": failed,
        "status": "ok" if not failed else ("failed" if not done else "partial"),
        "seeds": [r.seed for r in items],
        "errors": list(dict.fromkeys(r.error for r in items if r.error)),
        "failure_reasons": dict(sorted(reasons.items())),
        "env_kwargs": items[0].env_kwargs,
        "metrics": metrics,
        # The rank metrics' mean per evaluation seed (a group's training seeds averaged),
        # for paired comparisons of rows played on the same seeds.
        "by_seed": {k: {seed: float(np.mean(v)) for seed, v in per.items()}
                    for k, per in by_seed.items()},
    }
