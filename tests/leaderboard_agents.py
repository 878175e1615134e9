"""Agents that exist only for the evaluation tests (imported as an ``--agent-module``).

Importing this module registers them, in the test process and in every
evaluation worker that is told to import it.
"""

from __future__ import annotations

import numpy as np

from baselines.agents.random_agent import RandomAgent
from baselines.registry import AgentSpec, register_agent

#: The step on which :class:`RaisingAgent` raises.
RAISE_AT_STEP = 5


class RaisingAgent:
    """Random actions, then a ``RuntimeError`` on step :data:`RAISE_AT_STEP`."""

    def __init__(self, env):
        self._inner = RandomAgent(env)
        self._steps = 0

    def reset(self, seed: int | None = None) -> None:
        self._inner.reset(seed)
        self._steps = 0

    def act(self, observation, info: dict) -> np.ndarray:
        self._steps += 1
        if self._steps == RAISE_AT_STEP:
            raise RuntimeError(f"deliberate failure at step {RAISE_AT_STEP}")
        return self._inner.act(observation, info)


register_agent(AgentSpec("test-raises", RaisingAgent, "state", None,
                         "raises on its fifth step (evaluation tests)"))


def _position_random(env) -> RandomAgent:
    if env.control != "position":
        raise ValueError(f"test-position needs control='position', got {env.control!r}")
    return RandomAgent(env)


register_agent(AgentSpec("test-position", _position_random, "state", ("auv_envs/LARSCapture-v0",),
                         "random joint-position targets (evaluation tests)",
                         env_kwargs={"control": "position"}))
