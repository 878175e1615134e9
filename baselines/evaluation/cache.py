"""Finished episodes on disk: rows as JSON, and the per-episode cache.

:class:`EpisodeCache` writes every finished episode at once (one JSON file per
episode, atomic, named by :meth:`~baselines.evaluation.episodes.EpisodeTask.key`),
so a rerun skips it and an interrupted run loses only the episodes in flight.
Failed rows are not cached, so a rerun retries them. The atomic write is
:func:`baselines.fileio.atomic_write`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import warnings
from collections.abc import Mapping
from pathlib import Path

from baselines.evaluation.episodes import EpisodeRow, EpisodeTask, jsonable
from baselines.fileio import atomic_write


def row_to_dict(row: EpisodeRow) -> dict:
    """``row`` as JSON data (:func:`~baselines.evaluation.episodes.jsonable`)."""
    return jsonable(dataclasses.asdict(row))


def row_from_dict(data: Mapping) -> EpisodeRow:
    """Inverse of :func:`row_to_dict` (JSON ``null`` numbers come back as NaN)."""
    fields = {f.name for f in dataclasses.fields(EpisodeRow)}
    values = {k: v for k, v in data.items() if k in fields}
    for name in ("episode_return", "wall_time_s"):
        if values.get(name) is None:
            values[name] = math.nan
    if "nan_metrics" in values:
        values["nan_metrics"] = tuple(values["nan_metrics"])
    return EpisodeRow(**values)


def checksum(task_identity: Mapping, row: Mapping) -> str:
    """SHA-256 of a cached episode's content (its task's identity and its row), canonical
    JSON. It detects a file edited or damaged after it was written; it is not a signature
    (whoever edits a row can recompute it)."""
    text = json.dumps({"task": task_identity, "row": row}, sort_keys=True, allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


class CachedRowError(ValueError):
    """A cached episode that must not be used; the message says why."""


def _is_finite_number(value) -> bool:
    return (isinstance(value, int | float) and not isinstance(value, bool)
            and math.isfinite(value))


def _is_json_value(value) -> bool:
    """A metric's value: a string, a bool, a finite number, null, or a list of these."""
    if value is None or isinstance(value, str | bool) or _is_finite_number(value):
        return True
    return isinstance(value, list) and all(_is_json_value(v) for v in value)


def check_row(task: EpisodeTask, data) -> EpisodeRow:
    """The row a cache file holds for ``task``, checked against the task and the schema.

    Raises:
        CachedRowError: a field missing, unknown or of the wrong type; a number
            that must be finite and is not; a row of another task (environment,
            obs mode, agent, seed, arguments or scenario differ) or of a failed
            episode (never cached).
    """
    if not isinstance(data, dict):
        raise CachedRowError(f"the row is {type(data).__name__}, not an object")
    fields = {f.name: f for f in dataclasses.fields(EpisodeRow)}
    missing, unknown = sorted(set(fields) - set(data)), sorted(set(data) - set(fields))
    if missing or unknown:
        raise CachedRowError(f"fields missing {missing}, unknown {unknown}")
    expected = {"env_id": task.env_id, "obs_mode": task.obs_mode, "agent": task.agent,
                "seed": task.seed, "scenario": task.scenario,
                "env_kwargs": jsonable(task.kwargs), "status": "ok", "error": ""}
    for name, value in expected.items():
        if data[name] != value or type(data[name]) is not type(value):
            raise CachedRowError(f"{name} is {data[name]!r}, the task's is {value!r}")
    checks = {
        "episode_return": _is_finite_number(data["episode_return"]),
        "wall_time_s": _is_finite_number(data["wall_time_s"]) and data["wall_time_s"] >= 0,
        "length": (isinstance(data["length"], int) and not isinstance(data["length"], bool)
                   and data["length"] >= 1),
        "success": isinstance(data["success"], bool),
        "failure_reason": isinstance(data["failure_reason"], str),
        "metrics": (isinstance(data["metrics"], dict)
                    and all(_is_json_value(v) for v in data["metrics"].values())),
        "nan_metrics": (isinstance(data["nan_metrics"], list)
                        and all(isinstance(data["metrics"], dict)
                                and data["metrics"].get(k, 0) is None
                                for k in data["nan_metrics"])),
    }
    wrong = [name for name, ok in checks.items() if not ok]
    if wrong:
        raise CachedRowError("invalid " + ", ".join(f"{name} ({data[name]!r:.60})"
                                                    for name in wrong))
    return row_from_dict(data)


class EpisodeCache:
    """One JSON file per finished episode under ``directory``, named by the task's key.

    Every file carries a :func:`checksum` of its content. On load the checksum,
    the task it was written for and the row itself (:func:`check_row`) are
    checked; a file that fails (unreadable, edited, of another task, of another
    format, a row that breaks the schema) is named with its reason in a
    ``RuntimeWarning``, counted in :attr:`rejected` and treated as missing: the
    episode runs again and the file is overwritten. A cached row is never used
    unchecked.

    The key covers the task, the package version and the code
    (:func:`code_fingerprint`): after an agent or an environment changes, its
    episodes run again. ``refresh`` (``--no-cache``) reruns everything anyway,
    e.g. after a dependency upgrade, which the fingerprint does not see.
    """

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        #: ``(path, reason)`` of every cached file rejected by :meth:`load`.
        self.rejected: list[tuple[Path, str]] = []

    def path(self, task: EpisodeTask) -> Path:
        return self.directory / f"{task.key()}.json"

    def load(self, task: EpisodeTask) -> EpisodeRow | None:
        path = self.path(task)
        if not path.exists():
            return None
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict) or set(data) != {"task", "row", "checksum"}:
                raise CachedRowError("not a cached episode of this format")
            if data["checksum"] != checksum(data["task"], data["row"]):
                raise CachedRowError("its checksum does not match its content (edited or "
                                     "damaged)")
            if data["task"] != jsonable(task.identity()):
                raise CachedRowError("it was written for another task")
            return check_row(task, data["row"])
        # CachedRowError and JSON errors are ValueErrors; a TypeError is a value of a shape
        # the checks did not expect (an unhashable name in nan_metrics, say).
        except (OSError, ValueError, TypeError) as exc:
            self.rejected.append((path, str(exc)))
            warnings.warn(f"rejected cached episode {path}: {exc}; running it again",
                          RuntimeWarning, stacklevel=2)
            return None

    def store(self, task: EpisodeTask, row: EpisodeRow) -> None:
        identity, data = jsonable(task.identity()), row_to_dict(row)
        payload = {"task": identity, "row": data, "checksum": checksum(identity, data)}
        atomic_write(self.path(task), json.dumps(payload, indent=1))
