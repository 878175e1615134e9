"""Where episodes run: in this process, in local worker processes, or as Ray tasks.

:func:`run_tasks` reads the cached episodes, runs the rest on the chosen
backend and caches each as it finishes (:class:`~baselines.evaluation.cache.EpisodeCache`).
Every task builds a fresh environment and agent
(:func:`~baselines.evaluation.episodes.run_task`), so a row is the same on
every backend.

On Ray, nothing is assumed about the nodes' disks: the code and assets travel
with the job (:func:`ray_runtime_env`), and each episode's row and recorded
clips come back to the driver, which writes the cache and the clips. An
episode whose worker process or node is lost runs again (:data:`RAY_RETRIES`;
counted in :attr:`RunStats.retried`). :class:`LocalRayCluster` starts a cluster
of several nodes on this machine, to try or test that path.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import multiprocessing
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

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
from baselines.fileio import atomic_write

#: The values of :func:`run_tasks`'s ``backend``.
BACKENDS = ("local", "ray")
#: How many times Ray runs an episode again after the worker process or the node
#: running it was lost (Ray's ``max_retries``). An episode's own exception is a
#: failed row (:func:`~baselines.evaluation.episodes.run_task`), never retried.
RAY_RETRIES = 3
#: What of the source tree stays behind (gitignore patterns; Ray also honours
#: ``.gitignore``): version control, environments, caches, build and run outputs, docs.
RAY_EXCLUDES = (".git", ".venv", "venv", "__pycache__", "*.egg-info", ".pytest_cache",
                ".ruff_cache", "/runs", "/results", "/build", "/dist", "/site", "/docs")


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


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail fast on a ``host:port`` (or ``ray://host:port``) nobody listens on.

    Ray itself retries an unreachable address for minutes.
    """
    parts = _host_port(address)
    if parts is None:
        return  # "auto" and other forms Ray resolves itself
    try:
        socket.create_connection(parts, timeout=timeout).close()
    except OSError as exc:
        raise RuntimeError(f"cannot reach the Ray cluster at {address}: {exc}") from exc


def _host_port(address: str | None) -> tuple[str, int] | None:
    """``(host, port)`` of a ``host:port`` or ``ray://host:port`` address; None for other
    forms ("auto", none)."""
    host, sep, port = (address or "").removeprefix("ray://").rpartition(":")
    return (host, int(port)) if sep and port.isdigit() else None


def _endpoint(address: str | None) -> tuple[str, int] | None:
    """:func:`_host_port` with the host resolved to its IP; None also for a host that
    does not resolve."""
    parts = _host_port(address)
    try:
        return None if parts is None else (socket.gethostbyname(parts[0]), parts[1])
    except OSError:
        return None


def _source_root() -> Path | None:
    """The repository root when this code runs from a source checkout, else None."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "pyproject.toml").is_file() and (root / "assets").is_dir() else None


def ray_runtime_env(outputs: Sequence[str | Path] = ()) -> dict:
    """Ray's ``runtime_env`` that sends this code and its assets to every worker.

    From a source checkout, the repository root travels as the ``working_dir``:
    the packages, ``assets/`` (models, weights, the shipped policies under
    ``assets/policies``), ``tests/`` and ``scripts/``, less :data:`RAY_EXCLUDES`,
    what ``.gitignore`` lists, and ``outputs`` (the run's cache and clip
    directories) where they lie inside it. Each worker runs in its unpacked copy,
    which comes first on its ``sys.path``, so the code a worker runs is the
    driver's, installed there or not. Installed from a wheel, the ``auv_envs``
    (its assets inside) and ``baselines`` packages travel as ``py_modules``.

    What does not travel, every node must already have: the Python environment
    (the same Python and Ray versions as the driver, and the project's
    dependencies, e.g. from ``pip install -e .``), and a policy given by path
    (``--policy``, ``policy:PATH`` agent modules) that lies outside the tree
    or in an excluded directory such as ``runs/``, at the same path.
    """
    root = _source_root()
    if root is None:
        import auv_envs
        import baselines

        return {"py_modules": [str(Path(m.__file__).parent) for m in (auv_envs, baselines)],
                "excludes": list(RAY_EXCLUDES)}
    excludes = list(RAY_EXCLUDES)
    for output in outputs:
        with contextlib.suppress(ValueError):  # outside the tree: nothing to leave out
            inside = Path(output).resolve().relative_to(root)
            if inside.parts:
                excludes.append(f"/{inside.as_posix()}")
    return {"working_dir": str(root), "excludes": excludes}


@dataclasses.dataclass(frozen=True)
class _RemoteResult:
    """What a Ray task sends back: the row, the bytes of its clip files by name, and
    which attempt of the task it was (0: the first)."""

    row: EpisodeRow
    clips: dict[str, bytes]
    attempt: int


def _attempt_number() -> int:
    """Which attempt of the running Ray task this is (0: the first run).

    Ray's public API tells this only through the state API (``ray.util.state``),
    which needs the dashboard (``ray[default]``) and reports late; the core
    worker that runs the task knows it. With a Ray that no longer offers it, 0.
    """
    import ray

    worker = getattr(ray._private.worker.global_worker, "core_worker", None)
    number = getattr(worker, "get_current_task_attempt_number", None)
    return int(number()) if number is not None else 0


def _run_remote(task: EpisodeTask, agent_modules: Sequence[str],
                video: VideoSpec | None) -> _RemoteResult:
    """:func:`run_task` in a Ray worker, recording into a directory of its own whose
    files go back to the driver (the worker's disk may be another machine's)."""
    import ray

    attempt = _attempt_number()
    if video is None:
        return _RemoteResult(run_task(task, agent_modules), {}, attempt)
    # Under the node's Ray directory: what a killed attempt leaves stays with Ray's files.
    node_dir = ray.get_runtime_context().get_temp_dir()
    with tempfile.TemporaryDirectory(prefix="auv-clips-", dir=node_dir) as scratch:
        row = run_task(task, agent_modules, dataclasses.replace(video, directory=scratch))
        clips = {path.name: path.read_bytes() for path in Path(scratch).iterdir()
                 if path.is_file()}
    return _RemoteResult(row, clips, attempt)


def _run_ray(tasks: Sequence[EpisodeTask], workers: int, address: str | None,
             agent_modules: Sequence[str], videos: Mapping[EpisodeTask, VideoSpec],
             outputs: Sequence[str | Path], stats: RunStats
             ) -> Iterator[tuple[EpisodeTask, EpisodeRow]]:
    if not tasks:
        return
    with ray_session(address, workers, outputs) as ray:
        yield from _ray_episodes(ray, tasks, agent_modules, videos, stats)


@contextlib.contextmanager
def ray_session(address: str | None, cpus: int | None, outputs: Sequence[str | Path] = (),
                purpose: str = "--backend ray"):
    """Ray, connected to the cluster at ``address`` (checked reachable first) or a Ray
    started on this machine with ``cpus`` CPUs (None: all), the working tree shipped to
    its workers (:func:`ray_runtime_env`, ``outputs`` left out), shut down afterwards
    where started here. Where Ray is running already, the caller's Ray and its
    ``runtime_env`` serve, provided it is the cluster at ``address`` (a ``ValueError``
    where it is another). ``purpose`` names what needs Ray, for a missing extra."""
    ray = require("ray", "ray", purpose)
    started = not ray.is_initialized()
    if not started and _endpoint(address) is not None:
        running = ray.get_runtime_context().gcs_address
        if _endpoint(running) != _endpoint(address):
            raise ValueError(f"{purpose}: Ray is already connected to {running} in this "
                             f"process, not to the cluster at {address}; shut it down "
                             "(ray.shutdown()) or leave the address out to use it")
    if started:
        runtime_env = ray_runtime_env(outputs)
        if address:
            _check_reachable(address)
            ray.init(address=address, runtime_env=runtime_env)
        else:
            ray.init(num_cpus=cpus, include_dashboard=False, runtime_env=runtime_env)
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def _ray_episodes(ray, tasks: Sequence[EpisodeTask], agent_modules: Sequence[str],
                  videos: Mapping[EpisodeTask, VideoSpec], stats: RunStats
                  ) -> Iterator[tuple[EpisodeTask, EpisodeRow]]:
    remote = ray.remote(num_cpus=1, max_retries=RAY_RETRIES)(_run_remote)
    pending = {remote.remote(task, tuple(agent_modules), videos.get(task)): task
               for task in tasks}
    # Raised for a task only once its retries are spent.
    lost = (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError)
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                task = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:  # Ray failed the task
                    stats.retried += RAY_RETRIES if isinstance(exc, lost) else 0
                    yield task, failed_row(task, exc)
                    continue
                stats.retried += result.attempt
                for name, data in result.clips.items():  # before the row is cached
                    atomic_write(Path(videos[task].directory) / name, data)
                yield task, result.row
    finally:
        for ref in pending:
            ray.cancel(ref)


def _free_ports(count: int) -> list[int]:
    """``count`` distinct TCP ports nobody listens on now (all held until all are found)."""
    with contextlib.ExitStack() as stack:
        sockets = [stack.enter_context(socket.socket()) for _ in range(count)]
        for sock in sockets:
            sock.bind(("127.0.0.1", 0))
        return [sock.getsockname()[1] for sock in sockets]


class LocalRayCluster:
    """A Ray cluster of several nodes on this machine, to try and test the Ray backend.

    Each node is started by the ``ray start`` command (of this interpreter's Ray)
    with a temporary directory of its own, so it has its own raylet, object store
    and unpacked runtime environment, as a separate machine would; the first
    node is the head, the others join it. :meth:`stop` ends the processes of the
    nodes this object started (each node's process group), and no other Ray on
    the machine, which ``ray stop`` would end too.

    ::

        with LocalRayCluster(nodes=2) as cluster:
            evaluate_all(..., backend="ray", ray_address=cluster.address)

    Args:
        nodes: how many nodes, the head included.
        cpus: CPUs each node offers (episodes it runs at once).
        env: environment variables of the nodes' processes and of their workers,
            beside this process's.
        object_store_mb: each node's object store, MiB.
    """

    #: Seconds a node has to start.
    START_S = 120.0
    #: Seconds :meth:`stop` waits for the killed processes to be gone.
    STOP_S = 10.0

    def __init__(self, nodes: int = 2, cpus: int = 1, env: Mapping[str, str] | None = None,
                 object_store_mb: int = 200):
        if nodes < 1 or cpus < 1:
            raise ValueError(f"nodes and cpus must be >= 1, got {nodes} and {cpus}")
        self.nodes, self.cpus, self.object_store_mb = nodes, cpus, object_store_mb
        # No token authentication, whatever this process or ~/.ray say: the nodes and
        # a driver that connects by address then agree.
        self.env = {**os.environ, "RAY_AUTH_MODE": "disabled", **(env or {})}
        #: Each node's temporary directory (its sessions, logs, runtime environments).
        self.temp_dirs: list[Path] = []
        #: The head's ``host:port``, for ``ray.init(address=...)`` and ``--ray-address``.
        self.address = ""
        #: Each node's ``ray start``, the leader of the node's process group.
        self._leaders: list[subprocess.Popen] = []

    def start(self) -> LocalRayCluster:
        """Start the nodes; returns once every node has joined (``RuntimeError`` if one fails)."""
        try:
            for index in range(self.nodes):
                self._start_node(head=index == 0)
        except BaseException:
            self.stop()
            raise
        return self

    def _start_node(self, head: bool) -> None:
        # Short paths: Ray's socket paths under the temporary directory have a length limit.
        temp_dir = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))
        self.temp_dirs.append(temp_dir)
        gcs, dashboard, client, agent = _free_ports(4)
        command = [sys.executable, "-m", "ray.scripts.scripts", "start",
                   "--num-cpus", str(self.cpus), "--temp-dir", str(temp_dir),
                   "--object-store-memory", str(self.object_store_mb * 2**20),
                   "--node-ip-address", "127.0.0.1", "--dashboard-agent-listen-port", str(agent),
                   "--disable-usage-stats"]
        if head:
            self.address = f"127.0.0.1:{gcs}"
            command += ["--head", "--port", str(gcs), "--include-dashboard", "false",
                        "--dashboard-port", str(dashboard), "--ray-client-server-port",
                        str(client)]
        else:
            command += ["--address", self.address]
        # The node's processes keep ray start's output file open: a file, not a pipe.
        with tempfile.TemporaryFile("w+") as log:
            # A session of its own: the node's processes form one process group, ended as one.
            process = subprocess.Popen(command, env=self.env, stdout=log, stderr=log,
                                       start_new_session=True)
            self._leaders.append(process)
            try:
                process.wait(self.START_S)  # ray start returns once the node is up
            except subprocess.TimeoutExpired:
                raise RuntimeError(f"ray start took over {self.START_S} s") from None
            if process.returncode:
                log.seek(0)
                tail = "\n".join(log.read().strip().splitlines()[-5:])
                raise RuntimeError(f"ray start failed ({' '.join(command[3:])}):\n{tail}")

    def stop(self) -> None:
        """Kill the nodes' processes and remove their temporary directories.

        SIGKILL, as ``ray stop --force`` sends: the GCS server does not stop on
        SIGTERM, and nothing of a throwaway cluster needs a graceful end.
        """
        groups = [leader.pid for leader in self._leaders]
        for group in groups:
            _signal_group(group, signal.SIGKILL)
        for leader in self._leaders:
            leader.wait()
        deadline = time.monotonic() + self.STOP_S  # until the processes are reaped
        while any(_signal_group(g, 0) for g in groups) and time.monotonic() < deadline:
            time.sleep(0.1)
        self._leaders = []
        for temp_dir in self.temp_dirs:
            shutil.rmtree(temp_dir, ignore_errors=True)

    def __enter__(self) -> LocalRayCluster:
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()


def _signal_group(group: int, sig: int) -> bool:
    """Send ``sig`` to process group ``group``; whether any process of it was there."""
    try:
        os.killpg(group, sig)
    except ProcessLookupError:
        return False
    return True


@dataclasses.dataclass
class RunStats:
    """How many episodes a :func:`run_tasks` call ran and how many came from the cache."""

    ran: int = 0
    cached: int = 0
    failed: int = 0
    #: Cached episodes found and rejected (named in warnings; run again).
    rejected: int = 0
    #: Ray tasks run again because the worker process or the node running them was lost.
    retried: int = 0


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
            or on the cluster at ``ray_address``; the code goes with the job,
            :func:`ray_runtime_env`, and the rows and clips come back here).
        agent_modules: modules to import in every worker (agents registered
            outside :mod:`baselines.catalogue`).
        progress: show a tqdm progress bar on stderr.
        stats: filled with the counts of ran/cached/failed episodes, of cached
            episodes rejected (:class:`~baselines.evaluation.cache.EpisodeCache`)
            and of Ray's retries.
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
            outputs = [*([cache.directory] if cache is not None else []),
                       *{spec.directory for spec in videos.values()}]
            results = _run_ray(todo, workers, ray_address, agent_modules, videos, outputs,
                               stats)
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
