"""Docking ``difficulty`` presets: each level's disturbances and optics reach the plant."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from auv_envs.tasks.docking.env import DockingDisturbances
from auv_envs.tasks.docking.optics import WaterOptics

DOCKING_IDS = ("auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2",
               "auv_envs/DockingStation-v0", "auv_envs/LampArrayDocking-v0")


def _calibration(env_id: str, **kwargs):
    env = gym.make(env_id, obs_mode="features", **kwargs)
    try:
        return env.unwrapped.calibration, env.unwrapped.difficulty
    finally:
        env.close()


@pytest.mark.parametrize("env_id", DOCKING_IDS)
@pytest.mark.parametrize("level", ["paper", "hard"])
def test_preset_reaches_the_calibration(env_id, level):
    preset = auv_envs.task_class(env_id).difficulty_presets[level]
    cal, difficulty = _calibration(env_id, difficulty=level)
    assert difficulty == level
    assert cal.disturbances == preset["disturbances"]
    assert cal.optics == preset["optics"]
    assert cal.disturbances != DockingDisturbances()
    assert cal.optics is not None


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_easy_sets_nothing(env_id):
    for kwargs in ({}, {"difficulty": "easy"}):
        cal, difficulty = _calibration(env_id, **kwargs)
        assert difficulty == "easy"
        assert cal.disturbances == DockingDisturbances()
        assert cal.optics is None


def test_hard_is_harder_than_paper():
    for env_id in DOCKING_IDS[:2]:
        presets = auv_envs.task_class(env_id).difficulty_presets
        paper, hard = presets["paper"]["disturbances"], presets["hard"]["disturbances"]
        assert hard.current.max_speed > paper.current.max_speed
        assert hard.plant.damping > paper.plant.damping
        assert hard.thruster_time_constant > paper.thruster_time_constant
        assert (presets["hard"]["optics"].lamp_failure_probability
                > presets["paper"]["optics"].lamp_failure_probability)


def test_given_keyword_overrides_the_preset():
    clear = WaterOptics.jerlov("IB")
    still = DockingDisturbances()
    env_id = DOCKING_IDS[0]
    preset = auv_envs.task_class(env_id).difficulty_presets["hard"]
    cal, _ = _calibration(env_id, difficulty="hard", optics=clear)
    assert cal.optics == clear
    assert cal.disturbances == preset["disturbances"]
    cal, _ = _calibration(env_id, difficulty="hard", disturbances=still)
    assert cal.disturbances == still
    assert cal.optics == preset["optics"]


def _rollout(env_id: str, seed: int, steps: int, **kwargs) -> np.ndarray:
    env = gym.make(env_id, obs_mode="features", scenario="current", **kwargs)
    try:
        _, info = env.reset(seed=seed)
        rows = [np.concatenate([info["true_position"], info["current"]])]
        for _ in range(steps):
            _, _, terminated, truncated, info = env.step(np.array([0.3, 0.0, 0.0, 0.0],
                                                                  dtype=np.float32))
            rows.append(np.concatenate([info["true_position"], info["current"]]))
            if terminated or truncated:
                break
        return np.array(rows)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", DOCKING_IDS[:2])
def test_paper_differs_from_easy_in_a_seeded_rollout(env_id):
    easy = _rollout(env_id, 7, 20)
    assert np.array_equal(easy, _rollout(env_id, 7, 20, difficulty="easy"))
    paper = _rollout(env_id, 7, 20, difficulty="paper")
    assert np.array_equal(paper, _rollout(env_id, 7, 20, difficulty="paper"))
    assert paper.shape == easy.shape
    assert not np.allclose(paper, easy)


@pytest.mark.parametrize("level", ["Paper", "extreme", ""])
def test_bad_level_raises(level):
    with pytest.raises(ValueError, match="difficulty"):
        gym.make(DOCKING_IDS[1], difficulty=level)


def test_ofnmpc_state_reference_docks_and_needs_the_state():
    from baselines.evaluation import run_episode
    from baselines.registry import agent_spec

    spec = agent_spec("ofnmpc-state")
    assert spec.obs_mode == "state"
    env_id = DOCKING_IDS[0]
    env = gym.make(env_id, obs_mode="state", scenario="current", current_direction=90.0)
    try:
        result = run_episode(env, spec.factory(env.unwrapped), 100_000, env_id, "ofnmpc-state")
    finally:
        env.close()
    assert result.success
    features = gym.make(env_id, obs_mode="features")
    try:
        with pytest.raises(ValueError, match="state"):
            spec.factory(features.unwrapped)
    finally:
        features.close()
