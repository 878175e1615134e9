"""JAX's persistent compilation cache for the batched environments and the compiled PPO.

Compiling a batched docking step takes most of a minute on 2 CPU cores; kept on
disk, a later process with the same program (same environment, level, batch
size, JAX version and device) loads it instead. The cache is keyed on all of
these, so a stale entry is never used; deleting the directory is always safe.

**Off by default on the CPU.** jaxlib's XLA:CPU loader crashes the process (a
segmentation fault, nothing to catch) on some large cached programs: with jaxlib
0.9.2 the second process to run the batched ``DockingMission`` rollout with the
privileged state dies loading it, every time. The same loader rejects every
entry's machine features with a logged error (jax-ml/jax#38445). So on the CPU
the default cache (:func:`cache_for`) is none, and a directory given explicitly
(``train.py --compilation-cache DIR``) is used with a warning. On a GPU or TPU the
default is :func:`default_compilation_cache`. Where it is safe, a warm cache shortens
the compiled PPO's start-up (``benchmarks/compiled_startup.py``, ``docs/training.md``).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import jax

from auv_envs.core.cache import host_cache

#: Backends whose cache loader we trust by default.
SAFE_PLATFORMS = ("gpu", "cuda", "rocm", "tpu")


def default_compilation_cache() -> Path:
    """``<user cache>/jax/<host key>`` (:func:`auv_envs.core.cache.host_cache`): one
    directory per kind of host, so that a cache shared between machines (a home
    directory on a cluster) never loads a program compiled for other CPU features."""
    return host_cache("jax")


def cache_for(platform: str | None = None) -> Path | None:
    """The default cache directory on ``platform`` (default: JAX's default backend):
    :func:`default_compilation_cache` on a GPU or TPU, None on the CPU (the module
    docstring says why)."""
    platform = platform or jax.default_backend()
    return default_compilation_cache() if platform in SAFE_PLATFORMS else None


def use_compilation_cache(directory: Path | None = None, *,
                          platform: str | None = None) -> Path | None:
    """Keep compiled programs in ``directory`` and return it.

    Without ``directory``: a JAX cache directory the user has set already
    (``jax.config`` or ``JAX_COMPILATION_CACHE_DIR``) is kept and returned; otherwise
    :func:`cache_for` ``platform`` (default: JAX's default backend) decides, and on the
    CPU nothing is set and None is returned. A ``directory`` given on the CPU is used,
    with a :class:`RuntimeWarning` that jaxlib may crash loading it."""
    configured = jax.config.jax_compilation_cache_dir
    if directory is None:
        if configured:
            return Path(configured)
        directory = cache_for(platform)
        if directory is None:
            return None
    elif (platform or jax.default_backend()) not in SAFE_PLATFORMS:
        warnings.warn(f"JAX's compilation cache at {directory} on the CPU: jaxlib's XLA:CPU "
                      "loader can crash the process on a large cached program "
                      "(auv_envs.batched.compile_cache)", RuntimeWarning, stacklevel=2)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(directory))
    # Cache the env's smaller programs too (JAX's default skips those under 1 s).
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return directory
