"""Import structure: ``baselines`` has no import cycle, and listing the agents stays light.

``evaluate.py --list`` reads every agent's declaration (and the shipped
policies' manifests) but builds none, so it must import neither torch nor JAX.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from baselines.rl.agents import policy_directories

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "baselines"

#: Runs ``evaluate.py --list`` in this interpreter, then names the heavy modules it imported.
_LIST_AND_REPORT = """
import runpy, sys
sys.argv = ["evaluate.py", "--list"]
try:
    runpy.run_path("evaluate.py", run_name="__main__")
except SystemExit as exc:
    if exc.code:
        raise
print("heavy:", sorted(m for m in ("torch", "jax") if m in sys.modules))
"""


def test_listing_agents_imports_neither_torch_nor_jax():
    result = subprocess.run([sys.executable, "-c", _LIST_AND_REPORT], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[-1] == "heavy: []", result.stdout[-2000:]
    listed = [line for line in lines if line.startswith("  ") and "obs modes:" in line]
    names = {line.split()[0] for line in listed}
    assert {"random", "pd-state", "gmphd-gci"} <= names, result.stdout[-2000:]
    shipped = {directory.name for directory in policy_directories()}
    assert shipped <= names, sorted(shipped - names)  # read from their manifests


def _modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the package (a package is its ``__init__``)."""
    modules = {}
    for path in (ROOT / PACKAGE).rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def _imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that importing ``name`` runs, directly.

    Imports inside functions count: a deferred import that closes a loop is a
    cycle all the same, only hidden from the interpreter. Importing ``a.b.c``
    also runs the packages ``a.b`` and ``a`` unless ``name`` is inside them
    (then they are already being imported).
    """
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    targets = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, *([node.module] if node.module else [])])
            # ``from a import b`` imports the module ``a.b`` when there is one.
            targets += [f"{base}.{alias.name}" for alias in node.names] + [base]
    edges = set()
    for target in targets:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        while target and not f"{name}.".startswith(f"{target}."):
            edges.add(target)
            target = target.rpartition(".")[0]
    return edges


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in sorted(graph[node]):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_cycle_finder_sees_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]


def test_baselines_has_no_import_cycle():
    modules = _modules()
    graph = {name: _imported(name, path, modules) for name, path in modules.items()}
    assert _cycles(graph) == []

