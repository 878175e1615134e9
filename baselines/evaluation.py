"""Run agents on environments over frozen seeds, cache each episode, summarise the metrics.

The unit of work is one :class:`EpisodeTask` (environment id, obs mode,
environment arguments, agent name, seed). :func:`plan` expands a request into
tasks and the (env, agent) pairs it skips with the reason (the agent's own
declaration, :meth:`baselines.registry.AgentSpec.skip_reason`).
:func:`run_tasks` runs them in this process, in local worker processes or as
Ray tasks, and writes every finished episode to an :class:`EpisodeCache` at
once (one JSON file per episode, atomic), so a rerun skips it and an
interrupted run loses only the episodes in flight. Every task builds a fresh
environment and agent, so a result never depends on the worker or on the
order of the episodes.

An agent that raises (while being built or during an episode) gives a
*failed* row carrying the error; the rest of the run goes on. Failed rows are
not cached, so a rerun retries them.

``evaluate.py`` is a thin command line over :func:`evaluate_all` and
:mod:`baselines.leaderboard`; tests import these directly.
"""

from __future__ import annotations

import ast
import collections
import concurrent.futures
import dataclasses
import functools
import hashlib
import importlib
import inspect
import json
import math
import multiprocessing
import os
import re
import socket
import sys
import tempfile
import time
import traceback
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import auv_envs
from auv_envs.core.assets import asset_root, sha256_file
from baselines import registry
from baselines.registry import agent_names, agent_spec
from baselines.seeds import EVAL_SEED_BASE, default_seeds  # noqa: F401 (re-exported)
from baselines.stats import bootstrap_interval, wilson_interval

#: Version of the cached episode format and of the episode protocol in
#: :func:`run_episode`; bumping it invalidates every cached episode.
CACHE_FORMAT = 1

#: Files that cannot change an episode's result, left out of :func:`code_fingerprint`
#: (the leaderboard's tables and plots), relative to the package roots.
_NOT_RESULT_CODE = ("leaderboard.py",)


def source_fingerprint(roots: Sequence[str | Path], exclude: Sequence[str] = ()) -> str:
    """Hex digest of every file under ``roots`` (names and contents; ``__pycache__`` skipped).

    ``exclude`` lists paths relative to a root. The order of the roots matters;
    the order in which the file system lists files does not.
    """
    digest = hashlib.sha256()
    for index, root in enumerate(Path(r) for r in roots):
        files = sorted(p for p in root.rglob("*")
                       if p.is_file() and "__pycache__" not in p.relative_to(root).parts)
        for path in files:
            name = path.relative_to(root).as_posix()
            if name in exclude:
                continue
            digest.update(f"{index}/{name}\0".encode())
            digest.update(sha256_file(path).encode())
    return digest.hexdigest()[:16]


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """Fingerprint of the code and assets an episode runs on, for the cache key.

    Every file of the installed ``auv_envs`` and ``baselines`` packages and of
    the asset tree (models, tracker weights, policies), read once per process
    (about 0.05 s). Editing an environment or an agent changes it, so cached
    episodes of older code are run again instead of being served stale.
    """
    import baselines

    roots = (Path(auv_envs.__file__).parent, Path(baselines.__file__).parent, asset_root())
    return source_fingerprint(roots, _NOT_RESULT_CODE)

BACKENDS = ("local", "ray")


@dataclasses.dataclass(frozen=True)
class EpisodeRow:
    """One evaluated episode.

    ``status`` is ``"ok"`` or ``"failed"`` (the agent or the environment raised;
    ``error`` says what, the numbers are then NaN/empty). ``scenario`` labels
    the environment arguments of the run (``"default"`` when none).
    """

    env_id: str
    agent: str
    seed: int
    obs_mode: str
    scenario: str
    episode_return: float
    length: int
    success: bool
    failure_reason: str
    metrics: dict
    wall_time_s: float
    status: str = "ok"
    error: str = ""
    env_kwargs: dict = dataclasses.field(default_factory=dict)


# --------------------------------------------------------------------- seeds
def parse_seeds(text: str) -> list[int]:
    """``"A-B"`` (inclusive) or ``"A,B,C"`` -> list of seeds."""
    try:
        if "-" in text.strip("-"):
            first, last = (int(x) for x in text.split("-", 1))
            if last < first:
                raise ValueError
            return list(range(first, last + 1))
        return [int(x) for x in text.split(",")]
    except ValueError as exc:
        raise ValueError(f"seeds must look like 'A-B' or 'A,B,C', got {text!r}") from exc


# ------------------------------------------------------------------ episodes
def jsonable(value):
    """``value`` as JSON data: NumPy scalars and arrays to Python, NaN/inf to ``None``."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    return value


def _is_number(value) -> bool:
    return isinstance(value, int | float | np.integer | np.floating | np.bool_)


def _estimate_error(estimate, info: dict) -> float | None:
    """Euclidean error of an agent's ``position_estimate()`` against ``info["true_position"]``."""
    if estimate is None:
        return None
    est = np.asarray(estimate, dtype=float)
    if est.shape != (3,) or not np.all(np.isfinite(est)):
        raise ValueError(f"position_estimate() must return a finite (3,) array or None, "
                         f"got {estimate!r}")
    if "true_position" not in info:
        raise ValueError("the environment's info has no 'true_position' to score "
                         "position_estimate() against")
    return float(np.linalg.norm(est - np.asarray(info["true_position"], dtype=float)))


def run_episode(env: gym.Env, agent, seed: int, env_id: str, agent_name: str,
                scenario: str | None = None) -> EpisodeRow:
    """One seeded episode of ``agent`` in ``env``; exceptions propagate.

    Metrics: the environment's ``info["episode_metrics"]`` at the last step,
    plus

    * ``<key>_steps`` for every boolean ``info["violation_<...>"]`` key: the
      number of steps on which that constraint was violated;
    * ``estimate_error_mean`` / ``estimate_error_max`` when the agent has
      ``position_estimate()``: after each ``act``, its (3,) world-frame
      estimate (or ``None``: no estimate yet) is compared with the
      ``info["true_position"]`` that came with the observation it acted on;
      ``estimate_steps`` counts the steps with an estimate;
    * ``agent_<key>`` for every numeric value of the agent's ``stats()`` at
      the end of the episode.
    """
    start = time.perf_counter()
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    estimate = getattr(agent, "position_estimate", None)
    errors: list[float] = []
    violations: collections.Counter = collections.Counter()
    total, length, done = 0.0, 0, False
    while not done:
        action = agent.act(obs, info)
        if callable(estimate):
            error = _estimate_error(estimate(), info)
            if error is not None:
                errors.append(error)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        length += 1
        for key, value in info.items():
            if key.startswith("violation_"):
                violations[key] += int(bool(np.any(value)))
        done = terminated or truncated
    metrics = jsonable(info.get("episode_metrics", {}))
    metrics.update({f"{key}_steps": count for key, count in violations.items()})
    if callable(estimate):
        metrics["estimate_steps"] = len(errors)
        if errors:
            metrics["estimate_error_mean"] = float(np.mean(errors))
            metrics["estimate_error_max"] = float(np.max(errors))
    if callable(getattr(agent, "stats", None)):
        for key, value in agent.stats().items():
            if _is_number(value):
                metrics[f"agent_{key}"] = jsonable(float(value))
    unwrapped = env.unwrapped
    return EpisodeRow(
        env_id=env_id,
        agent=agent_name,
        seed=int(seed),
        obs_mode=getattr(unwrapped, "obs_mode", ""),
        scenario=scenario if scenario is not None else getattr(unwrapped, "scenario", ""),
        episode_return=total,
        length=length,
        success=bool(info.get("is_success", False)),
        failure_reason=str(metrics.get("failure_reason", "")),
        metrics=metrics,
        wall_time_s=time.perf_counter() - start,
    )


@dataclasses.dataclass(frozen=True)
class EpisodeTask:
    """One episode to run: everything that determines its result.

    ``env_kwargs`` are sorted ``(name, value)`` pairs (hashable); they are the
    run's environment arguments, not the ones the agent's spec adds.
    """

    env_id: str
    obs_mode: str
    agent: str
    seed: int
    env_kwargs: tuple[tuple[str, Any], ...] = ()

    @property
    def kwargs(self) -> dict:
        return dict(self.env_kwargs)

    @property
    def scenario(self) -> str:
        return scenario_label(self.kwargs)

    def identity(self) -> dict:
        """What the cache key is made of (the package version and code included)."""
        return {
            "format": CACHE_FORMAT,
            "version": auv_envs.__version__,
            "code": code_fingerprint(),
            "env_id": self.env_id,
            "obs_mode": self.obs_mode,
            "agent": self.agent,
            "seed": self.seed,
            "env_kwargs": jsonable(self.kwargs),
        }

    def key(self) -> str:
        text = json.dumps(self.identity(), sort_keys=True, default=repr)
        return hashlib.sha256(text.encode()).hexdigest()[:24]


def scenario_label(env_kwargs: Mapping[str, Any]) -> str:
    """``"k=v, k=v"`` of a run's environment arguments (``"default"`` when none)."""
    return ", ".join(f"{k}={v}" for k, v in sorted(env_kwargs.items())) or "default"


@dataclasses.dataclass(frozen=True)
class VideoSpec:
    """Record an episode while it is evaluated (:class:`auv_envs.record.EpisodeRecorder`).

    Rendering does not change an episode: its row is the same with or without
    a recording (tested).

    Attributes:
        directory: where the clips go.
        size: frame size (W, H), both even.
        speed: playback speed relative to real time; None: a full-length
            episode plays in 20 s (:func:`auv_envs.record.auto_speed`).
        gif: also write a GIF.
    """

    directory: str
    size: tuple[int, int] = (320, 240)
    speed: float | None = None
    gif: bool = True

    def stem(self, task: EpisodeTask) -> str:
        """The clip's file name prefix: environment, agent, obs mode, scenario, seed."""
        scenario = re.sub(r"[^A-Za-z0-9_.=-]+", "-", task.scenario).strip("-")
        return f"{_short(task.env_id)}_{task.agent}_{task.obs_mode}_{scenario}_seed{task.seed}"

    def path(self, task: EpisodeTask) -> Path:
        """Where the MP4 of ``task``'s episode is (RecordVideo numbers episodes from 0)."""
        return Path(self.directory) / f"{self.stem(task)}-episode-0.mp4"


def failed_row(task: EpisodeTask, exc: BaseException, wall_time_s: float = 0.0) -> EpisodeRow:
    """The row of an episode that raised: status ``failed`` and the error with its location."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(frames[-1].filename).name}:{frames[-1].lineno} in " \
            f"{frames[-1].name})" if frames else ""
    return EpisodeRow(
        env_id=task.env_id, agent=task.agent, seed=task.seed, obs_mode=task.obs_mode,
        scenario=task.scenario, episode_return=math.nan, length=0, success=False,
        failure_reason="error", metrics={}, wall_time_s=wall_time_s, status="failed",
        error=f"{type(exc).__name__}: {exc}{where}", env_kwargs=jsonable(task.kwargs),
    )


#: Prefix of an ``agent_modules`` entry that registers a trained policy
#: (``policy:PATH``, :func:`baselines.rl.agents.register_external_policy`).
POLICY_PREFIX = "policy:"


def import_agent_modules(modules: Sequence[str]) -> None:
    """Import modules whose import registers agents (also done in every worker).

    An entry ``policy:PATH`` registers the trained policy at PATH instead.
    """
    for module in modules:
        if module.startswith(POLICY_PREFIX):
            from baselines.rl.agents import register_external_policy

            register_external_policy(module.removeprefix(POLICY_PREFIX))
        else:
            importlib.import_module(module)


def run_task(task: EpisodeTask, agent_modules: Sequence[str] = (),
             video: VideoSpec | None = None) -> EpisodeRow:
    """Build a fresh env and agent for ``task`` and run it; any exception -> a failed row.

    With ``video``, the episode is recorded as it runs (MP4 and GIF at
    ``video.path(task)``); a failed episode leaves no clip.
    """
    start = time.perf_counter()
    env = None
    recorder = None
    try:
        import_agent_modules(agent_modules)
        spec = agent_spec(task.agent)
        kwargs = {**spec.env_kwargs, **task.kwargs}  # plan() skips conflicting values
        if video is not None:
            kwargs.update(render_mode="rgb_array", render_size=tuple(video.size))
        env = gym.make(task.env_id, obs_mode=task.obs_mode, **kwargs)
        if video is not None:
            from auv_envs.record import EpisodeRecorder

            env = recorder = EpisodeRecorder(env, video.directory, video.stem(task),
                                             speed=video.speed, gif=video.gif)
        agent = spec.factory(env.unwrapped)
        row = run_episode(env, agent, task.seed, task.env_id, task.agent, task.scenario)
        return dataclasses.replace(row, env_kwargs=jsonable(task.kwargs))
    except Exception as exc:  # an agent's failure is a result, not a crash of the run
        if recorder is not None:
            recorder.discard()  # no clip of a failed episode
        return failed_row(task, exc, time.perf_counter() - start)
    finally:
        if env is not None:
            env.close()


# --------------------------------------------------------------------- cache
def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: Mode of a file :func:`atomic_write` creates: what ``open(path, "w")`` would
#: give (``mkstemp`` alone creates 0600 files, unreadable to a web server
#: serving the leaderboard).
_FILE_MODE = 0o666 & ~_umask()


def atomic_write(path: str | Path, data: str | bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and ``os.replace``.

    Readers see the old file or the whole new one, never a partial write. The
    file gets the permissions of a plain ``open(path, "w")`` (0666 less the umask).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            os.fchmod(handle.fileno(), _FILE_MODE)
            handle.write(data.encode() if isinstance(data, str) else data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_figures(path: str | Path, figures: dict) -> None:
    """Write a reproduction script's figures to ``path`` as JSON and say so.

    NumPy scalars are written as floats; the write is atomic (:func:`atomic_write`).
    """
    atomic_write(path, json.dumps(figures, indent=1, default=float))
    print(f"figures written to {path}")


def row_to_dict(row: EpisodeRow) -> dict:
    return jsonable(dataclasses.asdict(row))


def row_from_dict(data: Mapping) -> EpisodeRow:
    """Inverse of :func:`row_to_dict` (JSON ``null`` numbers come back as NaN)."""
    fields = {f.name for f in dataclasses.fields(EpisodeRow)}
    values = {k: v for k, v in data.items() if k in fields}
    for name in ("episode_return", "wall_time_s"):
        if values.get(name) is None:
            values[name] = math.nan
    return EpisodeRow(**values)


class EpisodeCache:
    """One JSON file per finished episode under ``directory``, named by the task's key.

    A file that cannot be read or belongs to another task (a corrupt or
    foreign file) is reported with a ``RuntimeWarning`` and treated as
    missing, so the episode runs again and the file is overwritten.

    The key covers the task, the package version and the code
    (:func:`code_fingerprint`): after an agent or an environment changes, its
    episodes run again. ``refresh`` (``--no-cache``) reruns everything anyway,
    e.g. after a dependency upgrade, which the fingerprint does not see.
    """

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)

    def path(self, task: EpisodeTask) -> Path:
        return self.directory / f"{task.key()}.json"

    def load(self, task: EpisodeTask) -> EpisodeRow | None:
        path = self.path(task)
        if not path.exists():
            return None
        try:
            data = json.loads(path.read_text())
            if data.get("task") != jsonable(task.identity()):
                raise ValueError("it was written for another task")
            return row_from_dict(data["row"])
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            warnings.warn(f"ignoring unreadable cached episode {path}: {exc}; rerunning it",
                          RuntimeWarning, stacklevel=2)
            return None

    def store(self, task: EpisodeTask, row: EpisodeRow) -> None:
        payload = {"task": jsonable(task.identity()), "row": row_to_dict(row)}
        atomic_write(self.path(task), json.dumps(payload, indent=1))


# ------------------------------------------------------------------ backends
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
        ["baselines.evaluation", *registry.BUILTIN_AGENT_MODULES,
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
    try:
        import ray
    except ImportError as exc:
        raise RuntimeError(
            "--backend ray needs Ray: pip install 'auv_envs[ray]' (or pip install ray)"
        ) from exc
    return ray


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
            outside ``BUILTIN_AGENT_MODULES``).
        progress: show a tqdm progress bar on stderr.
        stats: filled with the counts of ran/cached/failed episodes.
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
    for task in tasks:
        row = cache.load(task) if cache is not None and not refresh else None
        if task in videos and not videos[task].path(task).exists():
            row = None
        if row is None:
            todo.append(task)
        else:
            rows[task] = row
    stats.cached += len(rows)
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


# ------------------------------------------------------------------ planning
def env_parameters(env_id: str) -> tuple[str, ...]:
    """The named constructor arguments of environment ``env_id`` (``obs_mode`` excluded).

    Raises:
        KeyError: ``env_id`` is not registered with Gymnasium.
    """
    params = inspect.signature(auv_envs.env_class(env_id)).parameters.values()
    return tuple(p.name for p in params
                 if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name != "obs_mode")


def _short(env_id: str) -> str:
    return env_id.split("/", 1)[-1]


def parse_value(text: str):
    """A Python literal (``30``, ``1.5``, ``True``, ``(64, 48)``, ``None``) or else the string."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def resolve_env_kwargs(env_ids: Sequence[str], assignments: Sequence[str],
                       defaults: Mapping[str, Mapping[str, Any]] | None = None,
                       ) -> dict[str, dict[str, Any]]:
    """Per-environment constructor arguments from ``[ENV:]KEY=VALUE`` strings.

    ``KEY=VALUE`` goes to every environment of ``env_ids`` whose constructor
    has ``KEY``; ``ENV:KEY=VALUE`` to one environment (full id or the part
    after ``auv_envs/``). ``defaults`` (env id -> kwargs) are applied first.

    Raises:
        ValueError: malformed text, an environment that is not selected, or a
            key that no (or not that) environment accepts.
    """
    params = {env_id: env_parameters(env_id) for env_id in env_ids}
    out = {env_id: dict((defaults or {}).get(env_id, {})) for env_id in env_ids}
    for text in assignments:
        target, sep, value = text.partition("=")
        env_part, colon, key = target.rpartition(":")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"environment arguments look like [ENV:]KEY=VALUE, got {text!r}")
        if colon:
            chosen = [e for e in env_ids if env_part in (e, _short(e))]
            if not chosen:
                raise ValueError(f"{text!r}: {env_part!r} is not among the selected "
                                 f"environments ({', '.join(env_ids)})")
        else:
            chosen = [e for e in env_ids if key in params[e]]
        accepting = [e for e in chosen if key in params[e]]
        if not accepting:
            listing = "; ".join(f"{e}: {', '.join(params[e])}" for e in (chosen or env_ids))
            raise ValueError(f"{text!r}: no selected environment takes {key!r} ({listing})")
        for env_id in accepting:
            out[env_id][key] = parse_value(value.strip())
    return out


def check_names(env_ids: Sequence[str], agents: Sequence[str]) -> None:
    """Raise ``ValueError`` listing the valid names for unknown env ids or agent names."""
    unknown = [e for e in env_ids if e not in auv_envs.ENVIRONMENTS]
    if unknown:
        raise ValueError(f"unknown env id(s) {', '.join(unknown)}; "
                         f"registered: {', '.join(auv_envs.ENVIRONMENTS)}")
    known = agent_names()
    unknown = [a for a in agents if a not in known]
    if unknown:
        raise ValueError(f"unknown agent(s) {', '.join(unknown)}; registered: {', '.join(known)}")


def plan(
    env_ids: Sequence[str],
    agents: Sequence[str],
    seeds: Sequence[int],
    obs_modes: Sequence[str] | None = None,
    env_kwargs: Sequence[Mapping[str, Mapping[str, Any]]] = ({},),
) -> tuple[list[EpisodeTask], list[dict]]:
    """Tasks for every applicable (env, kwargs variant, agent, obs mode) and every seed.

    Args:
        obs_modes: modes to evaluate each agent in (those it supports); default:
            the agent's default mode for the environment.
        env_kwargs: variants (scenarios), each mapping env id -> constructor
            arguments; every variant is evaluated.

    Returns:
        ``(tasks, skipped)``; ``skipped`` holds dicts with ``env_id``,
        ``agent``, ``scenario`` and ``reason``.
    """
    check_names(env_ids, agents)
    tasks, skipped = [], []
    seen: set[tuple[str, tuple]] = set()
    for variant in env_kwargs:
        for env_id in env_ids:
            kwargs = tuple(sorted(dict(variant.get(env_id, {})).items()))
            if (env_id, kwargs) in seen:  # a variant that does not touch this env
                continue
            seen.add((env_id, kwargs))
            for name in agents:
                spec = agent_spec(name)
                reason = spec.skip_reason(env_id)
                modes = [m for m in spec.modes_for(env_id) if obs_modes is None or m in obs_modes]
                if reason is None and not modes:
                    reason = (f"acts on obs mode(s) {', '.join(spec.obs_modes)}; requested "
                              f"{', '.join(obs_modes or ())}")
                conflicts = [k for k, v in kwargs if k in spec.env_kwargs
                             and spec.env_kwargs[k] != v]
                if reason is None and conflicts:
                    reason = "needs " + ", ".join(f"{k}={spec.env_kwargs[k]}" for k in conflicts)
                if reason is not None:
                    skipped.append({"env_id": env_id, "agent": name, "scenario":
                                    scenario_label(dict(kwargs)), "reason": reason})
                    continue
                if obs_modes is None:
                    modes = modes[:1]
                tasks.extend(EpisodeTask(env_id, mode, name, int(seed), kwargs)
                             for mode in modes for seed in seeds)
    return tasks, skipped


def check_env_kwargs(tasks: Sequence[EpisodeTask]) -> None:
    """Build each distinct environment configuration once; a bad argument raises ``ValueError``."""
    for env_id, obs_mode, kwargs in dict.fromkeys((t.env_id, t.obs_mode, t.env_kwargs)
                                                  for t in tasks):
        try:
            gym.make(env_id, obs_mode=obs_mode, **dict(kwargs)).close()
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{env_id} rejects arguments {scenario_label(dict(kwargs))}: "
                             f"{exc}") from exc


@dataclasses.dataclass
class EvaluationRun:
    """What :func:`evaluate_all` did: rows (task order), skipped pairs, episode counts."""

    rows: list[EpisodeRow]
    skipped: list[dict]
    stats: RunStats
    #: ``(env_id, agent, obs_mode, scenario)`` -> the MP4 of its recorded episode.
    clips: dict[tuple[str, str, str, str], Path] = dataclasses.field(default_factory=dict)


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
) -> EvaluationRun:
    """Plan, check and run an evaluation (see :func:`plan` and :func:`run_tasks`).

    Defaults: every registered environment and agent, 3 frozen seeds, no cache.
    With ``video``, the first seed's episode of every (environment, agent, obs
    mode, scenario) is recorded (``EvaluationRun.clips``).
    """
    import_agent_modules(agent_modules)
    env_ids = list(dict.fromkeys(env_ids or auv_envs.ENVIRONMENTS))
    agents = list(dict.fromkeys(agents or agent_names()))
    seeds = list(seeds if seeds is not None else default_seeds(3))
    tasks, skipped = plan(env_ids, agents, seeds, obs_modes, env_kwargs)
    check_env_kwargs(tasks)
    stats = RunStats()
    cache = EpisodeCache(cache_dir) if cache_dir is not None else None
    videos = {}
    if video is not None:
        first: dict[tuple, EpisodeTask] = {}
        for task in tasks:
            first.setdefault((task.env_id, task.agent, task.obs_mode, task.env_kwargs), task)
        videos = {task: video for task in first.values()}
    rows = run_tasks(tasks, cache, backend, workers, ray_address, agent_modules, progress, stats,
                     refresh, videos)
    clips = {(t.env_id, t.agent, t.obs_mode, t.scenario): spec.path(t)
             for t, spec in videos.items() if spec.path(t).exists()}
    return EvaluationRun(rows, skipped, stats, clips)


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


# --------------------------------------------------------------- aggregation
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
    over the ``n`` episodes that report it; ``ci`` the 95 % interval of the
    mean, :func:`_stat`): ``success`` over every episode (a
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


#: The agent name of a bound row (:func:`bound_rows`).
BOUND_AGENT = "cramer-rao-bound"


def bound_rows(summary: Sequence[Mapping]) -> list[dict]:
    """Per environment and scenario whose environment states a bound on its ranking
    metric (``env.rmse_bound()``: the acoustic Cramer-Rao bound), a reference row
    ``agent`` = :data:`BOUND_AGENT`, ``reference`` True: shown beside the agents,
    never ranked. The bound is computed from the environment built with the
    scenario's arguments, so each difficulty level gets its own.
    """
    out, seen = [], set()
    for row in summary:
        key = (row["env_id"], row["scenario"])
        if key in seen:
            continue
        seen.add(key)
        cls = auv_envs.env_class(row["env_id"])
        if not hasattr(cls, "rmse_bound"):
            continue
        env = cls(**row["env_kwargs"])
        try:
            bound = env.rmse_bound()
        finally:
            env.close()
        out.append({
            "env_id": row["env_id"], "obs_mode": "model", "scenario": row["scenario"],
            "agent": BOUND_AGENT, "episodes": 0, "failed": 0, "status": "ok", "seeds": [],
            "errors": [], "failure_reasons": {}, "env_kwargs": row["env_kwargs"],
            "group": None, "reference": True,
            "metrics": {"rmse": {"mean": bound, "std": 0.0, "n": 1, "ci": [None, None]}},
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
    for r in done:
        for name, value in r.metrics.items():
            if _is_number(value) and math.isfinite(float(value)) and name != "success":
                values.setdefault(name, []).append(float(value))
                if name in SIGNED_METRICS:
                    values.setdefault(f"{name}_abs", []).append(abs(float(value)))
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
        "metrics": {k: _stat(v, success=k == "success") for k, v in values.items()},
    }
