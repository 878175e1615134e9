"""Where episodes run: in this process, in local worker processes, or as Ray tasks.

:func:`run_tasks` reads the cached episodes, runs the rest on the chosen
backend and caches each as it finishes (:class:`~baselines.evaluation.cache.EpisodeCache`).
Every task builds a fresh environment and agent
(:func:`~baselines.evaluation.episodes.run_task`), so a row is the same on
every backend.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import os
import socket
import sys
from collections.abc import Iterator, Mapping, Sequence

from auv_envs.extras import require
from baselines.evaluation.cache import EpisodeCache
from baselines.evaluation.episodes import (
    POLICY_PREFIX,
    EpisodeRow,
    EpisodeTask,
    VideoSpec,
    failed_row,
    import_agent_modules,
    run_task,
)

#: The values of :func:`run_tasks`'s ``backend``.
BACKENDS = ("local", "ray")


def _init_worker(agent_modules: Sequence[str]) -> None:
    # Workers share the machine's cores: one thread each for the numeric libraries
    # (torch reads the variable when first imported; set it if already imported).
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    import_agent_modules(agent_modules)


def _run_local(tasks: Sequence[EpisodeTask], workers: int, agent_modules: Sequence[str],
               videos: Mapping[EpisodeTask, VideoSpec]
               ) -> Iterator[tuple[EpisodeTask, EpisodeRow]]:
    if workers == 1:
        for task in tasks:
            yield task, run_task(task, agent_modules, videos.get(task))
        return
    # Workers fork from a forkserver, not from this process (which may hold threads
    # or a GL context); it imports the agent modules once for all of them.
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(
        ["baselines.evaluation", "baselines.catalogue",
         *(m for m in agent_modules if not m.startswith(POLICY_PREFIX))])
    pool = concurrent.futures.ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=_init_worker,
        initargs=(tuple(agent_modules),),
    )
    finished = False
    try:
        futures = {pool.submit(run_task, task, tuple(agent_modules), videos.get(task)): task
                   for task in tasks}
        for future in concurrent.futures.as_completed(futures):
            task = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # a worker died (e.g. BrokenProcessPool)
                row = failed_row(task, exc)
            yield task, row
        finished = True
    finally:
        if not finished:  # interrupted: drop the episodes in flight instead of waiting
            _terminate_workers(pool)
        pool.shutdown(wait=True, cancel_futures=True)


def _terminate_workers(pool: concurrent.futures.ProcessPoolExecutor) -> None:
    """Stop a pool's worker processes now (``terminate_workers`` from Python 3.14 on)."""
    if hasattr(pool, "terminate_workers"):
        pool.terminate_workers()
        return
    # Before 3.14 the executor keeps its processes in this private mapping.
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def _import_ray():
    return require("ray", "ray", "--backend ray")


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail fast on a ``host:port`` (or ``ray://host:port``) nobody listens on.

    Ray itself retries an unreachable address for minutes.
    """
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return  # "auto" and other forms Ray resolves itself
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise RuntimeError(f"cannot reach the Ray cluster at {address}: {exc}") from exc


def _run_ray(tasks: Sequence[EpisodeTask], workers: int, address: str | None,
             agent_modules: Sequence[str], videos: Mapping[EpisodeTask, VideoSpec]
             ) -> Iterator[tuple[EpisodeTask, EpisodeRow]]:
    ray = _import_ray()
    started = False
    if not ray.is_initialized():
        if address:
            _check_reachable(address)
            ray.init(address=address)
        else:
            ray.init(num_cpus=workers, include_dashboard=False)
        started = True
    remote = ray.remote(num_cpus=1, max_retries=0)(run_task)
    pending = {remote.remote(task, tuple(agent_modules), videos.get(task)): task
               for task in tasks}
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                task = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except Exception as exc:  # the worker died or Ray failed the task
                    row = failed_row(task, exc)
                yield task, row
    finally:
        for ref in pending:
            ray.cancel(ref)
        if started:
            ray.shutdown()


@dataclasses.dataclass
class RunStats:
    """How many episodes a :func:`run_tasks` call ran and how many came from the cache."""

    ran: int = 0
    cached: int = 0
    failed: int = 0
    #: Cached episodes found and rejected (named in warnings; run again).
    rejected: int = 0


def run_tasks(
    tasks: Sequence[EpisodeTask],
    cache: EpisodeCache | None = None,
    backend: str = "local",
    workers: int = 1,
    ray_address: str | None = None,
    agent_modules: Sequence[str] = (),
    progress: bool = False,
    stats: RunStats | None = None,
    refresh: bool = False,
    videos: Mapping[EpisodeTask, VideoSpec] | None = None,
) -> list[EpisodeRow]:
    """Rows of ``tasks`` (in order): cached ones read, the rest run and cached as they finish.

    Args:
        tasks: the episodes.
        cache: where finished episodes are read from and written to (None: no cache).
        backend: ``"local"`` (``workers`` processes; 1 = this process) or
            ``"ray"`` (Ray tasks on a local Ray started with ``workers`` CPUs,
            or on the cluster at ``ray_address``).
        agent_modules: modules to import in every worker (agents registered
            outside :mod:`baselines.catalogue`).
        progress: show a tqdm progress bar on stderr.
        stats: filled with the counts of ran/cached/failed episodes and of cached
            episodes rejected (:class:`~baselines.evaluation.cache.EpisodeCache`).
        refresh: run every task again (and overwrite its cached episode).
        videos: tasks to record while they run; one whose clip is missing runs
            again even when its episode is cached.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    stats = stats if stats is not None else RunStats()
    rows: dict[EpisodeTask, EpisodeRow] = {}
    todo = []
    videos = dict(videos or {})
    rejected_before = len(cache.rejected) if cache is not None else 0
    for task in tasks:
        row = cache.load(task) if cache is not None and not refresh else None
        if task in videos and not videos[task].path(task).exists():
            row = None
        if row is None:
            todo.append(task)
        else:
            rows[task] = row
    stats.cached += len(rows)
    if cache is not None:
        stats.rejected += len(cache.rejected) - rejected_before
    from tqdm.auto import tqdm

    with tqdm(total=len(tasks), initial=len(rows), unit="episode", desc="evaluate",
              disable=not progress, dynamic_ncols=True) as bar:
        bar.set_postfix(cached=stats.cached, failed=0)
        if backend == "ray":
            results = _run_ray(todo, workers, ray_address, agent_modules, videos)
        else:
            results = _run_local(todo, workers, agent_modules, videos)
        for task, row in results:
            rows[task] = row
            stats.ran += 1
            if row.status == "ok":
                if cache is not None:
                    cache.store(task, row)
            else:
                stats.failed += 1
            bar.update(1)
            bar.set_postfix(cached=stats.cached, failed=stats.failed)
    return [rows[task] for task in tasks]
