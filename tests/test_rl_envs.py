"""The training env stack's FlattenObservation gives Gymnasium's flat vectors."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from baselines.rl.config import TrainConfig, resolve_config
from baselines.rl.detections import DetectionFixes
from baselines.rl.envs import FlattenObservation, wrap_env
from baselines.rl.marker_estimate import MarkerEstimate
from tests.conftest import make_env


class _FixedObservations(gym.Env):
    """An env that returns given observations (reset: the first, then one per step)."""

    def __init__(self, observation_space: spaces.Space, observations: list):
        self.observation_space = observation_space
        self.action_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self._observations = observations
        self._i = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._i = 0
        return self._observations[0], {}

    def step(self, action):
        self._i += 1
        return self._observations[self._i], 0.0, False, False, {}


def _flat_vectors(space: spaces.Space, observations: list) -> list[np.ndarray]:
    env = FlattenObservation(_FixedObservations(space, observations))
    assert env.observation_space == spaces.flatten_space(space)
    plain = all(isinstance(s, spaces.Box | spaces.MultiBinary) for s in space.spaces.values())
    assert env.concatenates == plain  # the one-concatenate path is the one under test
    out = [env.reset()[0]]
    out += [env.step(np.zeros(1, np.float32))[0] for _ in observations[1:]]
    return out


def _assert_same_as_gymnasium(space: spaces.Space, observations: list) -> None:
    for obs, flat in zip(observations, _flat_vectors(space, observations), strict=True):
        expected = spaces.flatten(space, obs)
        assert flat.dtype == expected.dtype and flat.shape == expected.shape
        np.testing.assert_array_equal(flat, expected)


def test_flatten_equals_gymnasium_on_lars_features():
    env = gym.make("auv_envs/LARSCapture-v0", obs_mode="features")
    try:
        observations = [env.reset(seed=3)[0]]
        actions = np.random.default_rng(0).uniform(-1, 1, (40, 3)).astype(np.float32)
        for action in actions:
            obs, _, terminated, truncated, _ = env.step(action)
            observations.append(obs)
            if terminated or truncated:
                observations.append(env.reset()[0])
        space = env.observation_space
    finally:
        env.close()
    assert any(o["visible"].any() for o in observations)
    assert any(not o["visible"].all() for o in observations)
    _assert_same_as_gymnasium(space, observations)


def test_flatten_equals_gymnasium_on_mixed_dtypes_and_shapes():
    space = spaces.Dict({
        "b": spaces.Box(-2.0, 2.0, (2, 3, 2), dtype=np.float32),
        "a": spaces.MultiBinary((2, 3)),
        "c": spaces.Box(-np.inf, np.inf, (3,), dtype=np.float64),
    })
    space.seed(0)
    observations = [space.sample() for _ in range(20)]
    _assert_same_as_gymnasium(space, observations)
    flat = _flat_vectors(space, observations)[0]
    assert flat.dtype == np.float64
    # Key order of the space (Dict sorts plain-dict keys), each key in C order.
    expected = np.concatenate([observations[0][k].ravel() for k in ("a", "b", "c")])
    np.testing.assert_array_equal(flat, expected)


def test_flatten_other_spaces_take_gymnasium_path():
    space = spaces.Dict({"d": spaces.Discrete(4), "x": spaces.Box(0.0, 1.0, (2,))})
    space.seed(1)
    observations = [space.sample() for _ in range(10)]
    _assert_same_as_gymnasium(space, observations)


def test_wrap_env_uses_the_flatten_wrapper():
    env = wrap_env(gym.make("auv_envs/LARSCapture-v0", obs_mode="features"), flatten_obs=True)
    try:
        assert isinstance(env, FlattenObservation)
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


@pytest.mark.parametrize(("env_id", "obs_mode", "front_end", "wrapper"), [
    ("auv_envs/AcousticTracking-v2", "measurements", "detection_fixes", DetectionFixes),
    ("auv_envs/LARSCapture-v0", "features", "marker_estimate", MarkerEstimate),
])
def test_configs_written_before_a_front_end_read_with_it_off(env_id, obs_mode, front_end,
                                                             wrapper):
    config = resolve_config("ppo", env_id)
    old = config.to_dict()
    del old["run"][front_end]
    again = TrainConfig.from_dict(old)
    assert again.run[front_end] is False and again.digest() == config.digest()
    assert not isinstance(wrap_env(make_env(env_id, obs_mode).unwrapped), wrapper)
