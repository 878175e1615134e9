"""The command lines the README and the documentation give, and a check of each.

:func:`commands` extracts every ``python evaluate.py``, ``python train.py``, ``python -m``
(of this project's packages), ``python scripts/...``, ``python benchmarks/...`` and
``auv-*`` command line from the Markdown (fenced blocks and inline code, continuation
lines joined). :func:`check` parses one with the program's own argument parser (the
program runs up to its ``parse_args`` and stops there) and checks that the environment
ids, agents and files it names exist. Run as a script it checks the command lines given
as JSON on stdin and prints the failures as JSON, so that the programs' imports and
global settings stay out of the test process.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import runpy
import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The pages whose commands are checked: the README and every documentation page.
PAGES = (ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")))

_FENCE = re.compile(r"```[^\n]*\n(.*?)```", re.S)
_INLINE = re.compile(r"`([^`]+)`")
_PROGRAM = re.compile(r"^(?:[A-Z_]+=\S+\s+)*(python3?\s+(?:-m\s+\S+|\S+\.py)|auv-[a-z-]+)"
                      r"(?=\s|$)")
#: Console scripts (pyproject.toml's [project.scripts]) by the module they run.
CONSOLE = {"auv-evaluate": "baselines.commands.evaluate", "auv-train": "baselines.commands.train",
           "auv-record": "auv_envs.record", "auv-lars-dataset": "auv_envs.datasets.lars"}
#: Placeholders the pages write for a value the reader chooses, and a value of their type.
PLACEHOLDERS = {"S": "0", "N": "1", "F": "docking", "LEVEL": "paper",
                "ENV": "DockingStation-v2"}
#: Dated report pages: their commands ran on the ids of their day, which stay registered.
HISTORY = ROOT / "docs" / "reports"
#: Paths a command writes or reads from an earlier command's output: not checked to exist.
OUTPUT_ROOTS = ("runs", "results", "data", "videos", "site", "RUN", "DIR", "R")


def commands(text: str) -> list[str]:
    """The project's command lines in one Markdown page (shell separators split them)."""
    lines = []
    for block in _FENCE.findall(text):
        lines += re.sub(r"\\\n\s*", " ", block).splitlines()
    rest = _FENCE.sub("", text)
    # Indented code blocks (four spaces), continuation lines joined.
    indented = re.sub(r"\\\n\s*", " ", "\n".join(
        line for line in rest.splitlines() if line.startswith("    ")))
    lines += [line.strip() for line in indented.splitlines()]
    lines += [m.group(1) for m in _INLINE.finditer(rest)]
    out = []
    for line in lines:
        line = re.sub(r"\s+", " ", line)
        for part in re.split(r"\s*(?:&&|;|\|\||\|)\s*", line):
            part = part.strip().removeprefix("$ ").strip()
            match = _PROGRAM.match(part)
            if not match or part[match.end():].startswith(":"):  # "prog: error: ..." output
                continue
            program = match.group(1)
            if program.startswith("python") and "-m" in program.split():
                module = program.split()[-1]
                if not module.startswith(("auv_envs", "baselines")):
                    continue  # pip, venv, pytest, mkdocs: not this project's commands
            out.append(part)
    return out


def page_commands() -> list[tuple[str, str, bool]]:
    """``(page, command, history)`` for every command of :data:`PAGES`; ``history``: the
    page is a dated report (:data:`HISTORY`)."""
    return [(str(page.relative_to(ROOT)), command, HISTORY in page.parents)
            for page in PAGES for command in commands(page.read_text())]


def _arguments(command: str) -> tuple[str, list[str]]:
    """The program (``evaluate.py``, ``-m module``, a script path) and its arguments."""
    command = re.sub(r"\s#.*$", "", command)  # a trailing comment
    command = re.sub(r"\[[^\]]*\]", "", command)  # [optional arguments]
    command = re.sub(r"<[^>]+>", "X", command)  # <placeholder>
    words = shlex.split(command)
    while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):
        words.pop(0)
    words = [PLACEHOLDERS.get(w, re.sub(r"(?<=-s)S$", "0", w)) for w in words]
    if words[0] in CONSOLE:
        program, argv = f"-m {CONSOLE[words[0]]}", words[1:]
    elif words[1] == "-m":
        program, argv = f"-m {words[2]}", words[3:]
    else:
        program, argv = words[1], words[2:]
    kept = []
    for word in argv:  # "--opt ...": the reader's choice of values, not a command's
        if word in ("...", "…"):
            if kept and kept[-1].startswith("--"):
                kept.pop()
            continue
        kept.append(word)
    # A program named alone, in prose or as a reference: its --help must work.
    return program, kept or ["--help"]


class _Parsed(Exception):
    def __init__(self, namespace):
        super().__init__()
        self.namespace = namespace


#: Arguments cheap enough to run the program with for real (it must exit with 0).
CHEAP = (["--list"],)


def parse(command: str) -> argparse.Namespace:
    """Run the command's program up to its argument parser's answer (to its end for the
    :data:`CHEAP` ones); raise ``ValueError`` with the parser's message where it refuses
    the arguments or is never reached."""
    program, argv = _arguments(command)
    original = argparse.ArgumentParser.parse_args
    cheap = argv in CHEAP

    def stop(self, args=None, namespace=None):
        namespace = original(self, args, namespace)
        if cheap:
            return namespace
        raise _Parsed(namespace)

    err = io.StringIO()
    argparse.ArgumentParser.parse_args = stop
    saved = sys.argv
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            if program.startswith("-m "):
                module = program[3:]
                sys.argv = [module, *argv]
                runpy.run_module(module, run_name="__main__", alter_sys=True)
            else:
                path = ROOT / program
                if not path.is_file():
                    raise ValueError(f"no such file: {program}")
                sys.argv = [str(path), *argv]
                sys.path.insert(0, str(path.parent))  # as Python runs a script
                try:
                    runpy.run_path(str(path), run_name="__main__")
                finally:
                    sys.path.remove(str(path.parent))
    except _Parsed as parsed:
        return parsed.namespace
    except SystemExit as exc:
        if exc.code in (0, None) and (cheap or "-h" in argv or "--help" in argv):
            return argparse.Namespace()
        raise ValueError(err.getvalue().strip().splitlines()[-1] if err.getvalue()
                         else f"exited with {exc.code}") from None
    finally:
        argparse.ArgumentParser.parse_args = original
        sys.argv = saved
    if cheap:
        return argparse.Namespace()  # it ran to its end
    raise ValueError("the program ran without parsing any arguments")


def _names(values) -> list[str]:
    """An argument's names (a string or a list of them; other values name nothing)."""
    values = [values] if isinstance(values, str) else values
    return [v for v in values if isinstance(v, str)] if isinstance(values, list) else []


def _given(args: argparse.Namespace, keys, command: str) -> list[str]:
    """The names the command itself gives for ``keys`` (not the program's defaults)."""
    words = set(re.split(r"[\s=]+", command))
    return [name for key in keys for name in _names(getattr(args, key, None))
            if name in words]


def check(command: str, history: bool = False) -> str | None:
    """What is wrong with one command line, or None. ``history``: a dated report's
    command, whose ids need only be registered (any version), not today's."""
    import gymnasium as gym

    import auv_envs
    from baselines.registry import agent_names, group_members

    try:
        args = parse(command)
    except ValueError as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - a program that fails before parsing
        return f"{type(exc).__name__}: {exc}"
    problems = []
    valid = set(gym.registry) if history else set(auv_envs.ENVIRONMENTS)
    for given in _given(args, ("env", "envs", "env_id"), command):
        env_id = given.split(":")[0]  # the benchmarks' id:mode
        env_id = env_id if "/" in env_id else f"auv_envs/{env_id}"
        if env_id.replace("MJX", "") not in valid:
            problems.append(f"{given}: not a registered id of today "
                            f"({', '.join(auv_envs.ENVIRONMENTS)})")
    known = set(agent_names())
    custom = getattr(args, "agent_module", None)  # the reader's own agents
    given = [] if custom else _given(args, ("agent", "agents", "teacher"), command)
    for name in (part for value in given for part in value.split(",")):  # or "a,b"
        if name not in known and not group_members(name):
            problems.append(f"no agent {name!r}")
    for key in ("hyperparams_dir", "agent_module_dir"):
        value = getattr(args, key, None)
        if isinstance(value, str) and not (ROOT / value).exists():
            problems.append(f"--{key.replace('_', '-')} {value}: no such directory")
    return "; ".join(problems) or None


def main() -> None:
    sys.path.insert(0, str(ROOT))
    failures = {}
    for command, history in json.load(sys.stdin):
        problem = check(command, history)
        if problem:
            failures[command] = problem
    print(json.dumps(failures))


if __name__ == "__main__":
    main()
