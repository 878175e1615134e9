"""Run agents on environments over frozen seeds, cache each episode, summarise the metrics.

The package's entry points are :func:`evaluate_all` (plan, check and run an
evaluation) and :func:`evaluate` (the rows of a plain in-process run). Each
module has one job:

* :mod:`~baselines.evaluation.episodes`: one episode (:class:`EpisodeRow`,
  :func:`run_episode`) and the unit of work, an :class:`EpisodeTask`
  (environment id, obs mode, environment arguments, agent name, seed) with
  :func:`run_task`, which builds a fresh environment and agent for it, so a
  result never depends on the worker or on the order of the episodes. An
  agent that raises (while being built or during an episode) gives a *failed*
  row carrying the error; the rest of the run goes on.
* :mod:`~baselines.evaluation.planning`: what to run; :func:`plan` expands a
  request into tasks and the (env, agent) pairs it skips with the reason (the
  agent's own declaration, :meth:`baselines.registry.AgentSpec.skip_reason`).
* :mod:`~baselines.evaluation.backends`: :func:`run_tasks` runs them in this
  process, in local worker processes or as Ray tasks (the code goes with the
  job, rows and clips come back, a lost worker or node costs a retry;
  :class:`LocalRayCluster` runs a cluster of several nodes on one machine).
* :mod:`~baselines.evaluation.cache`: every finished episode is written to an
  :class:`EpisodeCache` at once (one JSON file per episode, atomic), so a rerun
  skips it and an interrupted run loses only the episodes in flight. Failed
  rows are not cached, so a rerun retries them.
* :mod:`~baselines.evaluation.fingerprint`: the code version in the cache key.
* :mod:`~baselines.evaluation.summary`: episodes -> leaderboard rows.
* :mod:`~baselines.evaluation.board`: the board an output directory holds, which
  the next run merges into.

``evaluate.py`` (:mod:`baselines.commands.evaluate`) is a thin command line over
:func:`evaluate_all` and :mod:`baselines.leaderboard`; tests import these directly.
:func:`atomic_write` and :func:`write_figures` are re-exported from the leaf
:mod:`baselines.fileio`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import auv_envs
from baselines.evaluation import board
from baselines.evaluation.backends import BACKENDS, LocalRayCluster, RunStats, run_tasks
from baselines.evaluation.cache import EpisodeCache, row_from_dict, row_to_dict
from baselines.evaluation.episodes import (
    POLICY_PREFIX,
    EpisodeRow,
    EpisodeTask,
    VideoSpec,
    failed_row,
    import_agent_modules,
    jsonable,
    run_episode,
    run_task,
    scenario_label,
)
from baselines.evaluation.fingerprint import CACHE_FORMAT, code_fingerprint, source_fingerprint
from baselines.evaluation.planning import (
    check_env_kwargs,
    check_names,
    env_parameters,
    plan,
    resolve_env_kwargs,
)
from baselines.evaluation.summary import (
    BOUND_AGENT,
    BOUND_LABEL,
    SIGNED_METRICS,
    bound_rows,
    summarise,
)
from baselines.fileio import atomic_write, write_figures
from baselines.registry import agent_groups, agent_names, resolve_agent_names
from baselines.seeds import EVAL_SEED_BASE, check_seeds, default_seeds

__all__ = [
    "BACKENDS",
    "BOUND_AGENT",
    "BOUND_LABEL",
    "CACHE_FORMAT",
    "EVAL_SEED_BASE",
    "POLICY_PREFIX",
    "SIGNED_METRICS",
    "EpisodeCache",
    "EpisodeRow",
    "EpisodeTask",
    "EvaluationRun",
    "LocalRayCluster",
    "RunStats",
    "VideoSpec",
    "atomic_write",
    "bound_rows",
    "check_env_kwargs",
    "check_names",
    "code_fingerprint",
    "default_seeds",
    "env_parameters",
    "evaluate",
    "evaluate_all",
    "failed_row",
    "import_agent_modules",
    "jsonable",
    "plan",
    "resolve_env_kwargs",
    "row_from_dict",
    "row_to_dict",
    "run_episode",
    "run_task",
    "run_tasks",
    "scenario_label",
    "source_fingerprint",
    "summarise",
    "write_figures",
]


@dataclasses.dataclass
class EvaluationRun:
    """What :func:`evaluate_all` did: rows (task order), skipped pairs, episode counts."""

    rows: list[EpisodeRow]
    skipped: list[dict]
    stats: RunStats
    #: ``(env_id, agent, obs_mode, scenario)`` -> the MP4 of its recorded episode.
    clips: dict[tuple[str, str, str, str], Path] = dataclasses.field(default_factory=dict)
    #: The tasks of ``rows`` (the board: this run's and the earlier rows kept).
    tasks: list[EpisodeTask] = dataclasses.field(default_factory=list)
    #: How many of them were kept from the earlier board (:mod:`~baselines.evaluation.board`).
    kept: int = 0


def evaluate_all(
    env_ids: Sequence[str] | None = None,
    agents: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    obs_modes: Sequence[str] | None = None,
    env_kwargs: Sequence[Mapping[str, Mapping[str, Any]]] = ({},),
    cache_dir: str | Path | None = None,
    refresh: bool = False,
    backend: str = "local",
    workers: int = 1,
    ray_address: str | None = None,
    agent_modules: Sequence[str] = (),
    progress: bool = False,
    video: VideoSpec | None = None,
    earlier: Sequence[EpisodeTask] = (),
    select: Callable[[list[EpisodeTask]], list[EpisodeTask]] | None = None,
) -> EvaluationRun:
    """Plan, check and run an evaluation (see :func:`plan` and :func:`run_tasks`).

    Defaults: every registered environment and agent, 3 frozen seeds, no cache.
    With ``video``, the first seed's episode of every (environment, agent, obs
    mode, scenario) is recorded (``EvaluationRun.clips``); of a group's training
    seeds, only the first one's. ``earlier``: the
    tasks of a board to merge into (:func:`baselines.evaluation.board.merge`):
    its rows that this run does not evaluate are kept (read from the cache, or
    run again). ``select``: which of the planned episodes to run (e.g. the default
    run's design, :func:`baselines.evaluation.quick.thin`); default all.
    """
    import_agent_modules(agent_modules)
    env_ids = list(dict.fromkeys(env_ids or auv_envs.ENVIRONMENTS))
    agents = resolve_agent_names(agents) if agents else agent_names()  # groups: members
    seeds = check_seeds(seeds) if seeds is not None else default_seeds(3)
    tasks, skipped = plan(env_ids, agents, seeds, obs_modes, env_kwargs)
    if select is not None:
        tasks = select(tasks)
    planned = len(tasks)
    tasks = board.merge(earlier, tasks)
    check_env_kwargs(tasks)
    stats = RunStats()
    cache = EpisodeCache(cache_dir) if cache_dir is not None else None
    videos = {}
    if video is not None:
        first: dict[tuple, EpisodeTask] = {}
        groups = agent_groups()
        for task in tasks:  # a group's clip is its first-run member's
            first.setdefault((task.env_id, groups.get(task.agent, task.agent), task.obs_mode,
                              task.env_kwargs), task)
        videos = {task: video for task in first.values()}
    rows = run_tasks(tasks, cache, backend, workers, ray_address, agent_modules, progress, stats,
                     refresh, videos)
    clips = {(t.env_id, t.agent, t.obs_mode, t.scenario): spec.path(t)
             for t, spec in videos.items() if spec.path(t).exists()}
    return EvaluationRun(rows, skipped, stats, clips, tasks, len(tasks) - planned)


def evaluate(
    env_ids: Sequence[str] | None = None,
    agents: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    env_kwargs: dict | None = None,
) -> list[EpisodeRow]:
    """Every applicable (env, agent) pair on every seed, in this process; the rows.

    Args:
        env_ids: registered ids (default: all of ``auv_envs.ENVIRONMENTS``).
        agents: agent names (default: all registered).
        seeds: evaluation seeds (default: 3 from :data:`EVAL_SEED_BASE`).
        env_kwargs: extra constructor arguments for every env (e.g. scenario).
    """
    env_ids = list(env_ids or auv_envs.ENVIRONMENTS)
    variant = {env_id: dict(env_kwargs or {}) for env_id in env_ids}
    return evaluate_all(env_ids, agents, seeds, env_kwargs=(variant,)).rows
