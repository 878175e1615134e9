"""The backend convention: every function of the package takes its backend (``xp``, the
array module, or ``ops``, :mod:`auv_envs.core.ops`'s arithmetic) explicitly, never by
default, so that a forgotten argument cannot run NumPy inside a JAX trace."""

from __future__ import annotations

import ast
from pathlib import Path

import auv_envs

PACKAGE = Path(auv_envs.__file__).parent
BACKEND_NAMES = ("xp", "ops")


def defaulted_backends(source: str) -> list[tuple[int, str, str]]:
    """``(line, function, argument)`` of each backend argument given a default."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        arguments = node.args
        positional = arguments.posonlyargs + arguments.args
        pairs = list(zip(positional[len(positional) - len(arguments.defaults):],
                         arguments.defaults, strict=True))
        pairs += [(arg, default) for arg, default in
                  zip(arguments.kwonlyargs, arguments.kw_defaults, strict=True)
                  if default is not None]
        found += [(node.lineno, node.name, arg.arg) for arg, _ in pairs
                  if arg.arg in BACKEND_NAMES]
    return found


def test_the_finder_finds_a_defaulted_backend():
    source = ("def f(x, xp=np):\n    pass\n"
              "def g(x, *, ops=FLOATS):\n    pass\n"
              "def h(x, ops, y=1):\n    pass\n")
    assert defaulted_backends(source) == [(1, "f", "xp"), (3, "g", "ops")]


def test_no_function_of_the_package_defaults_its_backend():
    offenders = [f"{path.relative_to(PACKAGE)}:{line} {name}({arg}=...)"
                 for path in sorted(PACKAGE.rglob("*.py"))
                 for line, name, arg in defaulted_backends(path.read_text())]
    assert offenders == []
