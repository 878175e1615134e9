"""docs/tutorials/task.md's code, run as written: a task of one's own through the one
Gymnasium env, Gymnasium's checker and gym.make."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import gymnasium as gym
import numpy as np

TUTORIAL = Path(__file__).resolve().parents[1] / "docs" / "tutorials" / "task.md"


def _run_tutorial(module: types.ModuleType) -> dict:
    """The tutorial's code blocks, run in order as ``module`` (a module of the reader's)."""
    blocks = re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S)
    assert len(blocks) == 2, "the tutorial's two code blocks"
    for block in blocks:
        exec(compile(block, str(TUTORIAL), "exec"), module.__dict__)  # noqa: S102
    return module.__dict__


def test_the_tutorials_task_runs_checks_and_registers():
    module = sys.modules["tutorial_task"] = types.ModuleType("tutorial_task")
    try:
        ns = _run_tutorial(module)
        metrics = ns["info"]["episode_metrics"]
        # The whole 20 s, its PD controller holding the depth.
        assert metrics["steps"] == 200 and metrics["final_error"] < 1.0
        env = ns["env"]
        assert env.unwrapped.noise == 0.2 and type(env.unwrapped.task).__name__ == "HoldDepthTask"
        first = [env.reset(seed=3)[0]] + [env.step(np.zeros(1, np.float32))[0] for _ in range(5)]
        again = [env.reset(seed=3)[0]] + [env.step(np.zeros(1, np.float32))[0] for _ in range(5)]
        np.testing.assert_array_equal(first, again)  # the episode's generator, reseeded
    finally:
        gym.registry.pop("my_tasks/HoldDepth-v0", None)
        del sys.modules["tutorial_task"]
