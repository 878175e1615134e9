"""Where built artefacts are kept: one directory per kind of artefact and kind of host.

Three things are built on first use and kept on disk: the compiled C steps
(:mod:`auv_envs.core.native`), the OFNMPC agents' compiled solvers
(:mod:`baselines.docking.control.ofnmpc`) and JAX's compiled programs
(:mod:`auv_envs.batched.compile_cache`). All live under :func:`user_cache`:
``$AUV_ENVS_CACHE`` where set, else ``$XDG_CACHE_HOME/auv_envs``, else
``~/.cache/auv_envs``.

Cluster nodes often share that directory (a home directory on a network file
system), and they need not share a CPU: code built for one CPU's features can
crash or compute otherwise on another. So each kind of artefact is kept per kind of
host, ``<user cache>/<kind>/<host key>`` (:func:`host_cache`): hosts with other CPU
features (:func:`host_key`) never see each other's files, and hosts of the same kind
share them. Deleting any of these directories is always safe.
"""

from __future__ import annotations

import hashlib
import os
import platform
from pathlib import Path


def user_cache() -> Path:
    """The root of every cache (module docstring)."""
    if os.environ.get("AUV_ENVS_CACHE"):
        return Path(os.environ["AUV_ENVS_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "auv_envs"


def cpu_features() -> str:
    """This host's CPU feature flags (``/proc/cpuinfo``'s first ``flags``, or the
    processor's name where there is none)."""
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.startswith(("flags", "Features")):
                    return " ".join(sorted(line.split(":", 1)[1].split()))
    except OSError:
        pass
    return platform.processor() or platform.machine()


def host_key() -> str:
    """``<machine>-<12 hex digits of the CPU features>``: hosts whose built code may differ
    (another architecture or other CPU features) get different keys."""
    digest = hashlib.sha256(cpu_features().encode()).hexdigest()[:12]
    return f"{platform.machine()}-{digest}"


def host_cache(kind: str) -> Path:
    """``<user cache>/<kind>/<host key>``: where this kind of host keeps ``kind``'s
    artefacts (``"native"``, ``"casadi"``, ``"jax"``)."""
    return user_cache() / kind / host_key()
