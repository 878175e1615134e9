"""Episode lengths in the registry: ``max_episode_steps``, ``TimeLimit`` and SB3 see them."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

import auv_envs
from tests.conftest import ENV_IDS

ALL_IDS = (*ENV_IDS, *auv_envs.PREVIOUS_VERSIONS)


def _zero(env: gym.Env) -> np.ndarray:
    return np.zeros(env.action_space.shape, dtype=env.action_space.dtype)


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_registered_length_is_the_default_time_limit(env_id):
    env = gym.make(env_id, obs_mode="state")
    try:
        own = env.unwrapped.max_episode_steps
        assert gym.spec(env_id).max_episode_steps == own == auv_envs.max_episode_steps(env_id)
        assert env.spec.max_episode_steps == own
        # time_limit / step period, rounded as the env counts its steps.
        assert own * env.unwrapped.dt == pytest.approx(
            env.unwrapped.spec.kwargs.get("time_limit", _default_time_limit(env_id)))
    finally:
        env.close()


def _default_time_limit(env_id: str) -> float:
    import inspect

    return inspect.signature(auv_envs.task_class(env_id)).parameters["time_limit"].default


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_max_episode_steps_override_truncates_with_the_episode_summary(env_id):
    env = gym.make(env_id, obs_mode="state", max_episode_steps=4)
    try:
        assert env.spec.max_episode_steps == 4
        env.reset(seed=11)
        for step in range(1, 5):
            _, _, terminated, truncated, info = env.step(_zero(env))
            if terminated:
                pytest.skip("the episode ended by itself first")
            assert truncated == (step == 4)
        summary = info["episode_metrics"]
        assert summary["steps"] == 4
        assert summary["success"] is False
        # The same keys the env writes when it ends an episode itself.
        short = gym.make(env_id, obs_mode="state", time_limit=4 * env.unwrapped.dt)
        short.reset(seed=11)
        for _ in range(4):
            *_, own_info = short.step(_zero(short))
        assert set(own_info["episode_metrics"]) == set(summary)
        assert own_info["episode_metrics"]["steps"] == 4
        short.close()
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ["auv_envs/DockingStation-v2", "auv_envs/LARSCapture-v0"])
def test_time_limit_keyword_still_sets_the_episode_length(env_id):
    default = gym.spec(env_id).max_episode_steps
    longer = gym.make(env_id, obs_mode="state", time_limit=2 * default * 0.1)
    try:
        own = longer.unwrapped.max_episode_steps
        assert own > default and longer.spec.max_episode_steps == own
    finally:
        longer.close()
    explicit = gym.make(env_id, obs_mode="state", time_limit=2 * default * 0.1,
                        max_episode_steps=3)
    try:
        assert explicit.spec.max_episode_steps == 3  # an explicit limit wins
    finally:
        explicit.close()


def test_sb3_sees_time_limit_truncation():
    env_id = "auv_envs/LARSCapture-v0"
    vec = DummyVecEnv([lambda: gym.make(env_id, obs_mode="state", max_episode_steps=3)])
    try:
        vec.seed(5)
        vec.reset()
        for step in range(1, 4):
            _, _, dones, infos = vec.step(np.zeros((1, 3), dtype=np.float32))
            if step < 3:
                assert not dones[0]
        assert dones[0]
        assert infos[0]["TimeLimit.truncated"] is True
        assert "terminal_observation" in infos[0]
        assert infos[0]["episode_metrics"]["steps"] == 3
    finally:
        vec.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gym_make_of_an_envs_spec_rebuilds_it(env_id):
    """The summary wrapper is recorded in the spec (with its arguments: none), so
    ``gym.make(env.spec)`` (as Minari's ``recover_environment`` does) rebuilds the env."""
    env = gym.make(env_id, time_limit=2.0)
    copy = gym.make(env.spec)
    try:
        assert isinstance(copy, auv_envs.core.env.EpisodeSummary)
        assert copy.spec.kwargs == env.spec.kwargs
        np.testing.assert_equal(copy.reset(seed=3)[0], env.reset(seed=3)[0])
    finally:
        env.close()
        copy.close()
