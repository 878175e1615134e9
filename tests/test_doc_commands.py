"""Every command line the README and the documentation give parses with its program's own
arguments and names environment ids, agents and directories that exist (tests/doc_commands.py;
the checks run in one subprocess, so that the programs' imports stay out of this one)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests import doc_commands

ROOT = Path(__file__).resolve().parents[1]


def _check(commands: list[tuple[str, bool]]) -> dict[str, str]:
    result = subprocess.run([sys.executable, str(Path(doc_commands.__file__))],
                            input=json.dumps(commands), capture_output=True, text=True,
                            cwd=ROOT, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_commands_are_found_in_blocks_inline_and_across_continuation_lines():
    page = """Run `python evaluate.py --list` first, or
```bash
pip install -e . && python train.py --algo cppo \\
    --env DockingMission-v0 --seed S   # a comment
python train.py: error: gamma must be a finite number
pytest -q
```
then `auv-record --env LARSCapture-v0 --agent ckf-pd` and `python -m pip install x`."""
    assert doc_commands.commands(page) == [
        "python train.py --algo cppo --env DockingMission-v0 --seed S # a comment",
        "python evaluate.py --list",
        "auv-record --env LARSCapture-v0 --agent ckf-pd"]


def test_the_pages_give_commands_of_every_kind():
    found = doc_commands.page_commands()
    programs = {command.split()[1] if command.startswith("python") else command.split()[0]
                for _, command, _ in found}
    assert {"evaluate.py", "train.py", "-m", "auv-record"} <= programs
    assert any("scripts/" in c for _, c, _ in found) and any("benchmarks/" in c
                                                             for _, c, _ in found)
    assert any(page == "README.md" for page, _, _ in found)


def test_the_check_refuses_dead_ids_unknown_agents_and_bad_arguments():
    failures = _check([
        ("python evaluate.py --envs DockingStation-v1 --agents pd-state", False),
        ("python evaluate.py --envs DockingStation-v1 --agents pd-state", True),
        ("python evaluate.py --envs DockingStation-v2 --agents no-such-agent", False),
        ("python train.py --algo cppo --env DockingStation-v2 --no-such-flag", False),
        ("python scripts/no_such_script.py", False),
        ("python train.py --algo cppo --env DockingStation-v2 --seed S", False),
        ("python evaluate.py --list", False),
    ])
    assert set(failures) == {
        "python evaluate.py --envs DockingStation-v1 --agents pd-state",
        "python evaluate.py --envs DockingStation-v2 --agents no-such-agent",
        "python train.py --algo cppo --env DockingStation-v2 --no-such-flag",
        "python scripts/no_such_script.py"}
    assert "not a registered id of today" in failures[
        "python evaluate.py --envs DockingStation-v1 --agents pd-state"]
    assert "no-such-agent" in failures[
        "python evaluate.py --envs DockingStation-v2 --agents no-such-agent"]
    assert "unrecognized arguments" in failures[
        "python train.py --algo cppo --env DockingStation-v2 --no-such-flag"]


def test_every_documented_command_parses_and_names_what_exists():
    """User pages must name today's ids; dated reports (docs/reports/) ids still
    registered. A failure lists each dead command with its page."""
    found = doc_commands.page_commands()
    failures = _check(sorted({(command, history) for _, command, history in found}))
    pages = {}
    for page, command, _ in found:
        pages.setdefault(command, set()).add(page)
    assert not failures, "\n".join(f"{', '.join(sorted(pages[c]))}: {c}\n    -> {why}"
                                   for c, why in failures.items())
