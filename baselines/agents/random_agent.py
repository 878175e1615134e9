"""Uniform random actions: the floor of every leaderboard."""

from __future__ import annotations

import numpy as np


class RandomAgent:
    """Samples the action space uniformly from its own seeded generator."""

    def __init__(self, env):
        self._space = env.action_space
        self._rng = np.random.default_rng()

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(seed)

    def act(self, observation, info: dict) -> np.ndarray:
        low, high = self._space.low, self._space.high
        return self._rng.uniform(low, high).astype(self._space.dtype)
