"""Training sweeps on Ray: seeds x variants of one ``train.py`` configuration.

``train.py --sweep-dir DIR --seeds 0 1 2 --grid learning_rate=1e-4,3e-4 ...`` trains
every seed with every combination of the ``--grid`` values (on top of the ``--set``
overrides they all share), each run one Ray task that calls ``train.py`` itself:

* **Ray tasks, not Ray Tune.** A run is a whole ``train.py`` run with its own
  evaluation, checkpoints and exit code; the sweep only places them on the cluster
  and gathers them. Tune's trial scheduling, search and early stopping would wrap
  each run in a trainable and report through its own result directory, none of which a
  grid of complete runs needs.
* **Each run its own run directory** ``DIR/<run name>``, the same files as a single
  ``train.py`` run (``config.yml``, ``run.json``, ``eval_curve.csv``, ``final/``...), and
  its output in ``DIR/logs/<run name>.log``. A run trains in a scratch directory on
  whichever node runs it; the directory comes back to the driver whole, so nothing
  stays on a worker's disk.
* **Resumable.** Run the same command again: finished runs are kept, an unfinished run
  with a checkpoint is continued from it (``train.py --resume``), one without is
  started again (its earlier directory kept beside it as ``<name>.attempt-<k>``).
* **A failing run is reported, the others finish.** Each run's exit code, steps,
  wall time and last evaluation go into ``DIR/summary.csv`` and the table printed at
  the end; the sweep's exit code is 0 only when every run finished.
* **A run Ray loses runs again.** A worker that dies is Ray's to retry (once); a run
  whose result Ray then cannot deliver (a lost object, a node gone) runs again from
  the start, up to :data:`LOST_RUN_RETRIES` times, and the sweep says so. A run's own
  failure is its exit code, never retried.

The cluster: ``--ray-address`` (a running cluster; the working tree travels to its
workers through Ray's ``runtime_env``,
:func:`~baselines.evaluation.backends.ray_session`, as for ``evaluate.py --backend
ray``) or a local Ray started for the sweep. ``--cpus-per-run`` CPUs are reserved for each run.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import itertools
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from collections.abc import Sequence
from pathlib import Path

from baselines.rl.config import COMPILED, ConfigError, parse_overrides

#: The summary's columns (``DIR/summary.csv``, the printed table).
SUMMARY_FIELDS = ("run", "seed", "variant", "status", "exit_code", "steps", "wall_time_s",
                  "success_rate", "mean_return", "log")
#: ``run.json``'s status of a run that reached its budget.
FINISHED = "finished"
#: How many times a run whose result Ray lost runs again.
LOST_RUN_RETRIES = 2


@dataclasses.dataclass(frozen=True)
class SweepRun:
    """One run of a sweep: its name (its directory's), seed, variant (``--grid`` values)
    and ``train.py`` arguments (without ``--run-dir``)."""

    name: str
    seed: int
    variant: tuple[tuple[str, str], ...]
    argv: tuple[str, ...]


def parse_grid(items: Sequence[str]) -> dict[str, list[str]]:
    """``["learning_rate=1e-4,3e-4"]`` -> ``{"learning_rate": ["1e-4", "3e-4"]}`` (each
    value checked readable as a ``--set`` value)."""
    grid = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        choices = [v.strip() for v in values.split(",") if v.strip()]
        if not sep or not key or not choices:
            raise ConfigError(f"a --grid entry must look like key=value1,value2, got {item!r}")
        if key in grid:
            raise ConfigError(f"--grid names {key!r} twice")
        parse_overrides([f"{key}={value}" for value in choices])
        grid[key] = choices
    return grid


def plan(seeds: Sequence[int], grid: dict[str, list[str]], common: Sequence[str]
         ) -> list[SweepRun]:
    """Every seed with every combination of ``grid``'s values; ``common``: the ``train.py``
    arguments every run shares (``--algo``, ``--env``, ``--set``...)."""
    if not seeds:
        raise ConfigError("a sweep needs at least one seed (--seeds)")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"--seeds repeats a seed: {list(seeds)}")
    keys = list(grid)
    runs = []
    for values in itertools.product(*(grid[key] for key in keys)):
        variant = tuple(zip(keys, values, strict=True))
        suffix = "".join(f"-{key.replace('.', '_')}={value}" for key, value in variant)
        for seed in seeds:
            sets = [arg for key, value in variant for arg in ("--set", f"{key}={value}")]
            runs.append(SweepRun(f"s{seed}{suffix}", seed, variant,
                                 (*common, "--seed", str(seed), *sets)))
    return runs


def _pack(directory: Path) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
        archive.add(directory, arcname=".")
    return buffer.getvalue()


def _unpack(data: bytes, directory: Path) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as archive:
        archive.extractall(directory, filter="data")


def run_one(name: str, argv: Sequence[str], previous: bytes | None) -> dict:
    """One run, where Ray places it: ``train.py`` in a process of its own, in a scratch
    directory (continuing ``previous``, a run directory's archive, when given), with this
    node's copy of the tree first on its path; returns the run's exit code, its output
    and its run directory's archive (None where none was written)."""
    root = Path(__file__).resolve().parents[2]
    # Paths the driver gave relative to the working tree, read against this node's copy.
    argv = [str(root / arg) if previous_arg == "--hyperparams-dir" else arg
            for previous_arg, arg in zip(("", *argv[:-1]), argv, strict=True)]
    if previous is not None:
        argv = ["--resume", name]
    else:
        argv = [*argv, "--run-dir", name]
    path = os.pathsep.join(filter(None, (str(root), os.environ.get("PYTHONPATH"))))
    with tempfile.TemporaryDirectory(prefix="auv-envs-sweep-") as scratch:
        if previous is not None:
            _unpack(previous, Path(scratch, name))
        # The run directory is recorded as ``name``, relative: not a scratch path.
        done = subprocess.run([sys.executable, "-m", "baselines.commands.train", *argv,
                               "--no-progress-bar"], cwd=scratch, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True,
                              env={**os.environ, "PYTHONPATH": path})
        run_dir = Path(scratch, name)
        archive = _pack(run_dir) if (run_dir / "run.json").exists() else None
    return {"exit_code": done.returncode, "log": done.stdout, "archive": archive}


def _status(run_dir: Path) -> dict:
    """``run.json``'s status, steps and wall time, and the last evaluation, of a run
    directory (empty where it has none)."""
    try:
        info = json.loads((run_dir / "run.json").read_text())
    except (OSError, ValueError):
        return {}
    row = {"status": info.get("status"), "steps": info.get("steps"),
           "wall_time_s": info.get("wall_time_s")}
    try:
        with open(run_dir / "eval_curve.csv", newline="") as handle:
            last = list(csv.DictReader(handle))[-1]
        row.update(success_rate=last.get("success_rate"), mean_return=last.get("mean_return"))
    except (OSError, IndexError):
        pass
    return row


def _has_checkpoint(run_dir: Path) -> bool:
    """Whether ``run_dir``'s checkpoints hold one ``train.py --resume`` can continue."""
    from baselines.rl.checkpoint import CheckpointError, latest_checkpoint

    try:
        latest_checkpoint(run_dir / "checkpoints")
    except CheckpointError:
        return False
    return True


def _set_aside(run_dir: Path) -> Path:
    """Move an unfinished run directory out of the way: ``<name>.attempt-<k>``."""
    k = 1
    while (aside := run_dir.with_name(f"{run_dir.name}.attempt-{k}")).exists():
        k += 1
    run_dir.rename(aside)
    return aside


def sweep(runs: Sequence[SweepRun], sweep_dir: str | Path, algo: str,
          ray_address: str | None = None, cpus_per_run: float = 1.0,
          echo=print) -> list[dict]:
    """Run ``runs`` as Ray tasks into ``sweep_dir`` (module docstring); returns the summary's
    rows (also written to ``sweep_dir/summary.csv``) in ``runs``' order."""
    from baselines.evaluation.backends import ray_session

    sweep_dir = Path(sweep_dir)
    (sweep_dir / "logs").mkdir(parents=True, exist_ok=True)
    rows, todo = {}, []
    for run in runs:
        run_dir = sweep_dir / run.name
        state = _status(run_dir)
        if state.get("status") == FINISHED:
            rows[run.name] = _row(run, sweep_dir, 0, state)
            echo(f"[sweep] {run.name}: finished before, kept")
            continue
        previous = None
        if run_dir.exists():
            if algo != COMPILED and _has_checkpoint(run_dir):
                previous = _pack(run_dir)
                echo(f"[sweep] {run.name}: continuing from its checkpoint")
            else:
                echo(f"[sweep] {run.name}: unfinished, set aside as "
                     f"{_set_aside(run_dir).name}; starting again")
        todo.append((run, previous))
    if todo:
        with ray_session(ray_address, None, [sweep_dir], "train.py --sweep-dir") as ray:
            remote = ray.remote(num_cpus=cpus_per_run, max_calls=1, max_retries=1)(run_one)
            pending = {remote.remote(run.name, run.argv, previous): (run, previous, 0)
                       for run, previous in todo}
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                run, previous, retries = pending.pop(done[0])
                try:
                    result = ray.get(done[0])
                except ray.exceptions.RayTaskError as exc:  # run_one itself failed
                    result = {"exit_code": 1, "log": f"the run's task failed: {exc}\n",
                              "archive": None}
                except ray.exceptions.RayError as exc:  # Ray lost the run or its result
                    if retries < LOST_RUN_RETRIES:
                        echo(f"[sweep] {run.name}: Ray lost it ({type(exc).__name__}); "
                             "running it again")
                        again = remote.remote(run.name, run.argv, previous)
                        pending[again] = (run, previous, retries + 1)
                        continue
                    result = {"exit_code": 1, "log": f"Ray could not run it: {exc}\n",
                              "archive": None}
                rows[run.name] = _gather(run, sweep_dir, result)
                echo(f"[sweep] {run.name}: {rows[run.name]['status']} "
                     f"(exit code {result['exit_code']}; {len(pending)} to go)")
    ordered = [rows[run.name] for run in runs]
    with open(sweep_dir / "summary.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=SUMMARY_FIELDS)
        writer.writeheader()
        writer.writerows(ordered)
    return ordered


def _gather(run: SweepRun, sweep_dir: Path, result: dict) -> dict:
    """A finished task's run directory and log written under ``sweep_dir``; its row."""
    run_dir = sweep_dir / run.name
    log = sweep_dir / "logs" / f"{run.name}.log"
    with open(log, "a") as handle:
        handle.write(result["log"])
    if result["archive"] is not None:
        scratch = run_dir.with_name(f".{run.name}.incoming")
        shutil.rmtree(scratch, ignore_errors=True)
        _unpack(result["archive"], scratch)
        if run_dir.exists():
            shutil.rmtree(run_dir)
        scratch.rename(run_dir)
    return _row(run, sweep_dir, result["exit_code"], _status(run_dir))


def _row(run: SweepRun, sweep_dir: Path, exit_code: int, state: dict) -> dict:
    status = state.get("status") or "failed"
    if exit_code and status in (FINISHED, "running"):
        status = "failed"
    return {"run": run.name, "seed": run.seed,
            "variant": " ".join(f"{key}={value}" for key, value in run.variant),
            "status": status, "exit_code": exit_code, "steps": state.get("steps"),
            "wall_time_s": state.get("wall_time_s"),
            "success_rate": state.get("success_rate"), "mean_return": state.get("mean_return"),
            "log": str(Path("logs") / f"{run.name}.log")}


def table(rows: Sequence[dict]) -> str:
    """The summary as a Markdown table."""
    def cell(value) -> str:
        if value is None or value == "":
            return "–"
        try:
            number = float(value)
        except (TypeError, ValueError):
            return str(value)
        return f"{number:.3g}" if not number.is_integer() else str(int(number))

    head = [field for field in SUMMARY_FIELDS if field != "log"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(cell(row[field]) for field in head) + " |" for row in rows]
    return "\n".join(lines)
