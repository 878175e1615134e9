"""LARSCapture-v0's ``difficulty`` levels and the privileged ``ckf-pd-state`` reference."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from auv_envs.core.env import TaskEnv
from auv_envs.tasks.lars.env import (
    DEFAULT_PIXEL_NOISE_STD,
    HARD_PIXEL_NOISE_STD,
    HARD_SEA,
    PAPER_SEA,
    LARSCaptureTask,
)
from auv_envs.tasks.lars.sea import SunGlint
from auv_envs.tasks.lars.waves import SeaSpectrum
from baselines.evaluation import run_episode
from baselines.registry import agent_spec

ENV_ID = "auv_envs/LARSCapture-v0"


def _make(**kwargs):
    return gym.make(ENV_ID, obs_mode="features", **kwargs)


@pytest.mark.parametrize(("level", "sea", "noise"), [
    ("easy", None, DEFAULT_PIXEL_NOISE_STD),
    ("paper", PAPER_SEA, DEFAULT_PIXEL_NOISE_STD),
    ("hard", HARD_SEA, HARD_PIXEL_NOISE_STD),
])
def test_each_level_applies_its_parameters(level, sea, noise):
    env = _make(difficulty=level)
    try:
        cal = env.unwrapped.calibration
        assert env.unwrapped.difficulty == level
        assert (cal.sea is None) if sea is None else (cal.sea.spectrum == sea)
        assert cal.pixel_noise_std == noise
        # what pickling rebuilds from keeps the level
        assert pickle.loads(pickle.dumps(env.unwrapped)).calibration.sea == cal.sea
    finally:
        env.close()


def test_presets_are_the_documented_values():
    presets = LARSCaptureTask.difficulty_presets
    assert presets["paper"] == {"sea": SeaSpectrum(0.3, 9.0, "jonswap", 3.3)}
    assert presets["hard"] == {"sea": SeaSpectrum(0.4, 7.0, "jonswap", 3.3),
                               "pixel_noise_std": 3.0,
                               "glint": SunGlint((math.radians(40.0), math.radians(80.0)))}


def test_explicit_keywords_override_the_level():
    mine = SeaSpectrum(0.2, 6.0, "pierson-moskowitz")
    env = _make(difficulty="hard", sea=mine, pixel_noise_std=0.5)
    try:
        cal = env.unwrapped.calibration
        assert cal.sea.spectrum == mine and cal.pixel_noise_std == 0.5
    finally:
        env.close()
    env = _make(difficulty="hard", pixel_noise_std=0.0)  # an explicit 0 is not "unset"
    try:
        assert env.unwrapped.calibration.pixel_noise_std == 0.0
        assert env.unwrapped.calibration.sea.spectrum == HARD_SEA
    finally:
        env.close()


def _rollout(level: str, seed: int = 700001, steps: int = 10) -> np.ndarray:
    """The AUV's true positions under a few zero-torque steps (the arm sags, no matter)."""
    env = _make(difficulty=level)
    try:
        _, info = env.reset(seed=seed)
        rows = [info["true_position"]]
        for _ in range(steps):
            _, _, terminated, truncated, info = env.step(np.zeros(3, dtype=np.float32))
            rows.append(info["true_position"])
            if terminated or truncated:
                break
        return np.array(rows)
    finally:
        env.close()


def test_paper_differs_from_easy_and_is_seeded():
    easy, paper = _rollout("easy"), _rollout("paper")
    n = min(len(easy), len(paper))
    assert n > 5
    assert np.abs(easy[:n, 2] - paper[:n, 2]).max() > 1e-3  # the swell's heave, not the sinusoid
    np.testing.assert_array_equal(paper, _rollout("paper"))


@pytest.mark.parametrize("level", ["Paper", "extreme", ""])
def test_unknown_level_raises(level):
    with pytest.raises(ValueError, match="difficulty"):
        TaskEnv(LARSCaptureTask, difficulty=level)


def test_state_reference_agent_captures():
    spec = agent_spec("ckf-pd-state")
    assert spec.name.endswith("-state") and spec.obs_mode == "state"
    env = gym.make(ENV_ID, obs_mode="state", time_limit=12.0)
    try:
        agent = spec.factory(env.unwrapped)
        row = run_episode(env, agent, 700002, ENV_ID, spec.name)
        assert row.success, row.metrics
        assert row.metrics["final_capture_error"] <= 0.05
        with pytest.raises(ValueError, match="state"):
            agent.act({"pixels": np.zeros((2, 3, 2))}, {})
    finally:
        env.close()
