"""Finished episodes on disk: rows as JSON, and the per-episode cache.

:class:`EpisodeCache` writes every finished episode at once (one JSON file per
episode, atomic, named by :meth:`~baselines.evaluation.episodes.EpisodeTask.key`),
so a rerun skips it and an interrupted run loses only the episodes in flight.
Failed rows are not cached, so a rerun retries them. The atomic write is
:func:`baselines.fileio.atomic_write`.
"""

from __future__ import annotations

import dataclasses
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
