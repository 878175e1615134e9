"""What a cached episode's result depends on besides its task: the format version and the code.

:data:`CACHE_FORMAT` and :func:`code_fingerprint` enter every
:meth:`~baselines.evaluation.episodes.EpisodeTask.key`, so that an episode
cached by older code (or in an older format) runs again instead of being
served stale.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Sequence
from pathlib import Path

import auv_envs
from auv_envs.core.assets import asset_root, sha256_file

#: Version of the cached episode format and of the episode protocol in
#: :func:`~baselines.evaluation.episodes.run_episode`; bumping it invalidates
#: every cached episode (2: rows carry a checksum and ``nan_metrics``).
CACHE_FORMAT = 2

#: Files that cannot change an episode's result, left out of :func:`code_fingerprint`
#: (the leaderboard's tables and plots, ``baselines/leaderboard.py``), relative to the
#: package roots.
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
