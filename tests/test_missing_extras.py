"""A missing optional dependency: the command lines print one line naming the extra to
install and exit with status 2; the library raises MissingExtra, an ImportError, without
the import's chained traceback. Each case runs in a fresh interpreter where the module is
made unimportable (None in sys.modules)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

CASES = [
    ("jax", "train.py", ["--algo", "cppo", "--env", "DockingStation-v2", "--run-dir", "{tmp}"],
     "jax"),
    ("ray", "evaluate.py", ["--backend", "ray", "--envs", "LARSCapture-v0", "--agents",
                            "random", "--difficulty", "paper", "--episodes", "1",
                            "--no-video", "--out", "{tmp}"], "ray"),
    ("minari", "-m baselines.datasets", ["record", "--agent", "random", "--env",
                                         "LARSCapture-v0", "--episodes", "1", "--out",
                                         "{tmp}"], "datasets"),
]


def _run(blocked: str, program: str, argv: list[str]) -> subprocess.CompletedProcess:
    runner = (f"import runpy, sys; sys.modules[{blocked!r}] = None; "
              + (f"sys.argv = [{program.split()[-1]!r}, *sys.argv[1:]]; "
                 f"runpy.run_module({program.split()[-1]!r}, run_name='__main__')"
                 if program.startswith("-m") else
                 f"sys.argv = [{program!r}, *sys.argv[1:]]; "
                 f"runpy.run_path({program!r}, run_name='__main__')"))
    return subprocess.run([sys.executable, "-c", runner, *argv], capture_output=True,
                          text=True, cwd=ROOT, timeout=300)


@pytest.mark.parametrize("blocked, program, argv, extra", CASES, ids=[c[0] for c in CASES])
def test_a_command_names_the_missing_extra_in_one_line(blocked, program, argv, extra,
                                                       tmp_path):
    result = _run(blocked, program, [a.format(tmp=tmp_path / "out") for a in argv])
    lines = [line for line in result.stderr.splitlines() if line.strip()
             and "cpu_aot_loader" not in line]  # XLA's own log lines are not ours
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1, result.stderr
    assert "error:" in lines[0] and f'pip install -e ".[{extra}]"' in lines[0]
    assert "Traceback" not in result.stderr


def test_the_library_raises_missing_extra_without_the_chain():
    code = ("import sys; sys.modules['jax'] = None\n"
            "import gymnasium as gym, auv_envs\n"
            "from auv_envs.extras import MissingExtra\n"
            "try:\n"
            "    gym.make_vec('auv_envs/DockingStationMJX-v2', num_envs=2)\n"
            "except MissingExtra as exc:\n"
            "    assert exc.extra == 'jax' and exc.__cause__ is None, exc\n"
            "    assert exc.__suppress_context__\n"
            "    print(exc)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            cwd=ROOT, timeout=300)
    assert result.returncode == 0, result.stderr
    assert 'pip install -e ".[jax]"' in result.stdout
