"""A leaderboard that lasts: what a board in an output directory holds, kept across runs.

Every run writes ``board.json`` beside its pages: the episodes (tasks) the page
shows and the agent modules they need. The next run into the same directory
merges into it (:func:`merge`): a row (environment, obs mode, arguments, agent)
that the new run evaluates is replaced by the new run's episodes; every other
row of the board is kept, its episodes read from the validated cache (or run
again when the code changed since). A page therefore shows one board, never a
mix of one run's tables and another's plots, and a second, narrower run loses
nothing.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from pathlib import Path

from baselines.evaluation.episodes import EpisodeTask, jsonable
from baselines.fileio import atomic_write

BOARD_FILE = "board.json"
#: Version of the board file's format.
BOARD_FORMAT = 1


class BoardError(ValueError):
    """A board file that cannot be merged into; the message says why and what to do."""


def row_key(task: EpisodeTask) -> tuple:
    """The leaderboard row an episode belongs to: (env, obs mode, arguments, agent)."""
    return task.env_id, task.obs_mode, task.env_kwargs, task.agent


def _task_from(data) -> EpisodeTask:
    fields = {"env_id": str, "obs_mode": str, "agent": str, "seed": int, "env_kwargs": dict}
    if not isinstance(data, dict) or set(data) != set(fields) or any(
            not isinstance(data[k], t) or isinstance(data[k], bool) for k, t in fields.items()):
        raise BoardError(f"not a task: {data!r:.120}")
    kwargs = tuple(sorted((k, tuple(v) if isinstance(v, list) else v)
                          for k, v in data["env_kwargs"].items()))
    return EpisodeTask(data["env_id"], data["obs_mode"], data["agent"], data["seed"], kwargs)


def read(out_dir: str | Path) -> tuple[list[EpisodeTask], list[str]]:
    """``(tasks, agent_modules)`` of the board in ``out_dir``; ``([], [])`` when none.

    Raises:
        BoardError: the file is unreadable or not a board of this format.
    """
    path = Path(out_dir) / BOARD_FILE
    if not path.exists():
        return [], []
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict) or data.get("format") != BOARD_FORMAT:
            raise BoardError(f"format {data.get('format') if isinstance(data, dict) else None}"
                             f", expected {BOARD_FORMAT}")
        modules = data["agent_modules"]
        if not (isinstance(modules, list) and all(isinstance(m, str) for m in modules)):
            raise BoardError("agent_modules must be a list of names")
        return [_task_from(t) for t in data["tasks"]], modules
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BoardError(f"cannot merge into the board {path}: {exc}; start a new board "
                         f"with --new-board (its episodes stay cached)") from exc


def write(out_dir: str | Path, tasks: Sequence[EpisodeTask],
          agent_modules: Iterable[str]) -> Path:
    """Record the board's tasks and the agent modules they need (atomically)."""
    path = Path(out_dir) / BOARD_FILE
    data = {"format": BOARD_FORMAT, "agent_modules": list(dict.fromkeys(agent_modules)),
            "tasks": [jsonable({"env_id": t.env_id, "obs_mode": t.obs_mode, "agent": t.agent,
                                "seed": t.seed, "env_kwargs": t.kwargs}) for t in tasks]}
    atomic_write(path, json.dumps(data, indent=1))
    return path


def merge(earlier: Sequence[EpisodeTask], tasks: Sequence[EpisodeTask]) -> list[EpisodeTask]:
    """This run's ``tasks`` after the ``earlier`` board's episodes of the rows it does not
    evaluate (a row it evaluates is replaced, not pooled with the old seeds)."""
    replaced = {row_key(t) for t in tasks}
    kept = [t for t in earlier if row_key(t) not in replaced]
    return list(dict.fromkeys([*kept, *tasks]))
