"""Name -> agent factory.

Every agent keeps one protocol: ``reset(seed)`` then ``act(observation, info)
-> action``. A factory takes the (unwrapped) environment it will act in, so it
can read the documented calibration, never MuJoCo internals.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from typing import Protocol

import gymnasium as gym
import numpy as np


class Agent(Protocol):
    def reset(self, seed: int | None = None) -> None: ...

    def act(self, observation, info: dict) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """How to build an agent and where it applies.

    Attributes:
        name: registry key.
        factory: ``factory(env) -> Agent`` with ``env`` the unwrapped env.
        obs_mode: the observation mode the agent needs.
        env_ids: environment ids it applies to (``None``: all).
        description: one line for tables and ``--help``.
    """

    name: str
    factory: Callable[[gym.Env], Agent]
    obs_mode: str
    env_ids: tuple[str, ...] | None
    description: str

    def applies_to(self, env_id: str) -> bool:
        return self.env_ids is None or env_id in self.env_ids


_REGISTRY: dict[str, AgentSpec] = {}


def register_agent(spec: AgentSpec) -> None:
    if spec.name in _REGISTRY:
        raise ValueError(f"agent {spec.name!r} is already registered")
    _REGISTRY[spec.name] = spec


def agent_spec(name: str) -> AgentSpec:
    _load_builtin()
    if name not in _REGISTRY:
        raise KeyError(f"unknown agent {name!r}; registered: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def agent_names() -> list[str]:
    _load_builtin()
    return sorted(_REGISTRY)


def make_agent(name: str, env: gym.Env) -> Agent:
    """Build agent ``name`` for ``env`` (wrapped or not)."""
    return agent_spec(name).factory(env.unwrapped)


#: Modules whose import registers the built-in agents (one line per module).
BUILTIN_AGENT_MODULES = (
    "baselines.agents.random_agent",
    "baselines.agents.pd_docking",
    "baselines.acoustic.agents",
)


def _load_builtin() -> None:
    for module in BUILTIN_AGENT_MODULES:
        importlib.import_module(module)
