"""Files written whole: :func:`atomic_write` and the reproduction scripts' :func:`write_figures`.

A leaf (standard library only), so the evaluation, the leaderboard, the
training runs and the scripts share it without importing one another.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path


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
