"""JAX's persistent compilation cache for the batched environments and the compiled PPO.

Compiling a batched docking step takes most of a minute on 2 CPU cores; kept on
disk, a later process with the same program (same environment, level, batch
size, JAX version and device) loads it instead. The cache is keyed on all of
these, so a stale entry is never used; deleting the directory is always safe.
The compiled PPO (:mod:`baselines.rl.compiled`) compiles its iteration, reset
and evaluation in about 90 s on 2 CPU cores; from a warm cache a later run
(another seed) starts in about 33 s, most of it tracing
(``benchmarks/compiled_startup.py``).
"""

from __future__ import annotations

import os
from pathlib import Path

import jax


def default_compilation_cache() -> Path:
    """``$XDG_CACHE_HOME/auv_envs/jax`` (``~/.cache/auv_envs/jax`` without it)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "auv_envs" / "jax"


def use_compilation_cache(directory: Path | None = None) -> Path:
    """Keep compiled programs in ``directory`` (default :func:`default_compilation_cache`)
    and return it. Where the user has set a JAX cache directory already (``jax.config``
    or ``JAX_COMPILATION_CACHE_DIR``) and no ``directory`` is given, that one is kept."""
    configured = jax.config.jax_compilation_cache_dir
    if directory is None and configured:
        return Path(configured)
    directory = Path(directory or default_compilation_cache())
    directory.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(directory))
    # Cache the env's smaller programs too (JAX's default skips those under 1 s).
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return directory
