"""Agents on image observations: a perception front end feeding a features agent.

A *front end* turns each image observation (``image`` or ``stereo`` obs mode)
into the ``features`` observation of the same environment; the inner agent
acts on that. This is how the classical pipelines split perception from
estimation and control ([LAMP]'s lamp tracker in front of [OFNMPC]'s
OFNMPC; [LTAT]'s LTAT in front of its CKF + PD).

A front end keeps the protocol::

    front_end.reset(seed)                    # new episode
    features = front_end(observation, info)  # one step; features obs layout

and may expose ``stats()`` (a dict of numbers) which the wrapper merges into
its own ``stats()`` for logging. The wrapper passes the inner agent's
``position_estimate()`` through, so the evaluator scores it as it would the
inner agent alone.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import gymnasium as gym
import numpy as np

from baselines.registry import AgentSpec, agent_spec


class FrontEndAgent:
    """``inner.act(front_end(observation, info), info)``."""

    def __init__(self, front_end, inner):
        self.front_end = front_end
        self.inner = inner

    def reset(self, seed: int | None = None) -> None:
        self.front_end.reset(seed)
        self.inner.reset(seed)

    def act(self, observation, info: dict) -> np.ndarray:
        return self.inner.act(self.front_end(observation, info), info)

    def position_estimate(self):
        """The inner agent's target-position estimate, when it keeps one (else None)."""
        estimate = getattr(self.inner, "position_estimate", None)
        return estimate() if callable(estimate) else None

    def stats(self) -> dict:
        out = {}
        for part in (self.front_end, self.inner):
            if hasattr(part, "stats"):
                out.update(part.stats())
        return out


@dataclasses.dataclass(frozen=True)
class FrontEndFactory:
    """``factory(env)``: :class:`FrontEndAgent` of ``front_end(env)`` before agent ``inner``
    (looked up when the agent is built, so the two may be declared in either order)."""

    front_end: Callable[[gym.Env], object]
    inner: str

    def __call__(self, env: gym.Env) -> FrontEndAgent:
        return FrontEndAgent(self.front_end(env), agent_spec(self.inner).factory(env))


def front_end_spec(
    name: str,
    inner: str,
    front_end: Callable[[gym.Env], object],
    obs_mode: str,
    env_ids: tuple[str, ...],
    description: str,
    heavy: bool = False,
) -> AgentSpec:
    """Agent ``name``: front end ``front_end(env)`` before agent ``inner``.

    ``heavy``: as :attr:`AgentSpec.heavy`.
    """
    return AgentSpec(name, FrontEndFactory(front_end, inner), obs_mode, env_ids, description,
                     heavy=heavy)
