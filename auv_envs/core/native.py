"""CasADi functions as machine code: the system C compiler, CasADi's virtual machine where
there is none.

A compiled step (:class:`auv_envs.core.plant.CompiledFunction`) evaluates a CasADi
``Function`` on CasADi's virtual machine. CasADi also writes the same function as C
(``Function.generate``); built by the system's C compiler and loaded with
``casadi.external`` it runs the same operations in the same order as machine code, an
order of magnitude faster (``docs/speed.md``).

The same numbers, to the bit: the C code is CasADi's own, compiled without
floating-point licence (no ``-ffast-math``, no contraction into fused multiply-adds),
and the elementary functions (``sin``, ``atan2``, ``sqrt``...) are the C library's, as
on the virtual machine. Each loaded function is checked against the virtual machine on
inputs drawn once (:func:`machine_code`); a function that differs, a compiler that is
missing or fails, or a library that does not load leaves the virtual machine in use,
with the same results. ``tests/test_native.py`` checks each shipped function.

Built libraries are kept under :func:`cache_dir` (``<user cache>/native/<host key>``,
:mod:`auv_envs.core.cache`: one directory per kind of host, so a node sharing the cache
never loads a library built for other CPU features), each named by the SHA-256 of
its C source, the compiler's identity and the flags: a changed function is a new file,
never a stale one. ``AUV_ENVS_NATIVE=0`` turns machine code off.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import numpy as np

from auv_envs.core.cache import host_cache

#: The flags: optimised, position-independent, no contraction into fused multiply-adds
#: (which would round once where the virtual machine rounds twice); CasADi's helpers
#: (``casadi_fabs``, ``casadi_sq``, ...) inlined, not called through the library's
#: symbol table (``-fno-semantic-interposition``: the same arithmetic, no calls).
FLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math",
         "-fno-semantic-interposition")

#: Loaded machine code by its library's path: each library is loaded once a process.
_loaded: dict[str, object] = {}


def enabled() -> bool:
    """Whether machine code is wanted (``AUV_ENVS_NATIVE`` not ``0``)."""
    return os.environ.get("AUV_ENVS_NATIVE", "1") != "0"


def cache_dir() -> Path:
    """Where this host's built libraries are kept (see the module's docstring)."""
    return host_cache("native")


def compiler() -> str | None:
    """The C compiler: ``$CC``, else ``cc`` on the path; None where there is none."""
    return shutil.which(os.environ.get("CC", "cc"))


def machine_code(function):
    """``function`` (a ``casadi.Function`` of dense inputs) as machine code, checked equal to
    the virtual machine's evaluation; ``function`` itself where machine code is off,
    unavailable or not equal (then with a warning saying why)."""
    if not enabled():
        return function
    cc = compiler()
    if cc is None:
        return function
    try:
        native = _load(function, cc)
    except (OSError, RuntimeError, subprocess.SubprocessError) as error:
        warnings.warn(f"{function.name()}: no machine code ({error}); CasADi's virtual "
                      "machine evaluates it, to the same numbers", RuntimeWarning, stacklevel=2)
        return function
    if not _same_numbers(function, native):
        warnings.warn(f"{function.name()}: the compiled library's numbers differ from "
                      "CasADi's virtual machine's; using the virtual machine",
                      RuntimeWarning, stacklevel=2)
        return function
    return native


def library(function, cc: str) -> tuple[Path, bytes]:
    """Where ``function``'s library built by ``cc`` is kept, and its C source."""
    import casadi

    name = function.name()
    generator = casadi.CodeGenerator(f"{name}.c")
    generator.add(function)
    code = generator.dump().encode()
    key = hashlib.sha256(b"\0".join([code, _compiler_identity(cc).encode(),
                                     " ".join(FLAGS).encode(),
                                     casadi.__version__.encode()])).hexdigest()
    return cache_dir() / f"{name}-{key[:32]}.so", code


def _load(function, cc: str):
    """Build (or find) and load ``function``'s library."""
    import casadi

    name = function.name()
    path, code = library(function, cc)
    # Threads loading the same library at once each load it (the loader shares it): no lock.
    if str(path) in _loaded:
        return _loaded[str(path)]
    if not path.exists():
        _build(code, path, name, cc)
    try:
        native = casadi.external(name, str(path))
    except RuntimeError:  # a damaged file: build it again, once
        _build(code, path, name, cc)
        native = casadi.external(name, str(path))
    return _loaded.setdefault(str(path), native)


def _build(code: bytes, library: Path, name: str, cc: str) -> None:
    """Compile ``code`` into ``library``, written under a temporary name and renamed (another
    process building the same file at once leaves one whole file)."""
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent) as scratch:
        source = Path(scratch) / f"{name}.c"
        source.write_bytes(code)
        built = Path(scratch) / library.name
        subprocess.run([cc, *FLAGS, str(source), "-o", str(built), "-lm"], check=True,
                       capture_output=True, timeout=300)
        os.replace(built, library)


def _compiler_identity(cc: str) -> str:
    """The compiler's path and first line of ``--version``."""
    try:
        out = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30)
        return f"{cc}: {out.stdout.splitlines()[0] if out.stdout else out.returncode}"
    except (OSError, subprocess.SubprocessError):
        return cc


def _same_numbers(function, native, trials: int = 4) -> bool:
    """Whether ``native`` and ``function`` give the same bits (NaN equal to NaN) on
    ``trials`` inputs of standard normals (a generator of its own, seeded)."""
    rng = np.random.default_rng(20261128)
    vm_buffer, vm_eval = function.buffer()
    native_buffer, native_eval = native.buffer()
    inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
    outputs = [[np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
               for _ in range(2)]
    for buffer, outs in ((vm_buffer, outputs[0]), (native_buffer, outputs[1])):
        for i, array in enumerate(inputs):
            buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(outs):
            buffer.set_res(i, memoryview(array))
    for _ in range(trials):
        for array in inputs:
            array[:] = rng.standard_normal(array.size)
        vm_eval()
        native_eval()
        for mine, theirs in zip(*outputs, strict=True):
            if not np.array_equal(mine.view(np.int64), theirs.view(np.int64)):
                if not np.array_equal(mine, theirs, equal_nan=True):
                    return False
    return True
