"""The front-end wrapper hands the inner agent the front end's features and seeds both."""

from __future__ import annotations

import numpy as np

from baselines.frontend import FrontEndAgent


class _Doubler:
    def __init__(self):
        self.seeds = []

    def reset(self, seed=None):
        self.seeds.append(seed)

    def __call__(self, observation, info):
        return {"pixels": 2 * observation["image"]}

    def stats(self):
        return {"frames": 1}


class _Echo:
    def __init__(self):
        self.seeds = []

    def reset(self, seed=None):
        self.seeds.append(seed)

    def act(self, observation, info):
        return observation["pixels"]


def test_front_end_agent_feeds_inner_agent_and_resets_both():
    front, inner = _Doubler(), _Echo()
    agent = FrontEndAgent(front, inner)
    agent.reset(7)
    action = agent.act({"image": np.array([1.0, 2.0])}, {})
    np.testing.assert_array_equal(action, [2.0, 4.0])
    assert front.seeds == [7] and inner.seeds == [7]
    assert agent.stats() == {"frames": 1}
    assert agent.position_estimate() is None
    inner.position_estimate = lambda: np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(agent.position_estimate(), [1.0, 2.0, 3.0])
