"""Seeded rollout fingerprints: what an environment did, in a few numbers per step.

``tests/data/release_fingerprints.json`` holds the fingerprints of every
registered id and non-image observation mode as released before the
``difficulty`` presets existed; ``tests/test_difficulty.py`` checks that the
default and ``difficulty="easy"`` still produce them. Regenerate only when a
behaviour change is intended (and bump the id's version):

    python -m tests.fingerprints tests/data/release_fingerprints.json
"""

from __future__ import annotations

import json
import sys

import gymnasium as gym
import numpy as np

import auv_envs

SEEDS = (3, 101)
STEPS = 40
IMAGE_MODES = ("image", "stereo")


def _leaves(obs):
    if isinstance(obs, dict):
        for key in sorted(obs):
            yield from _leaves(obs[key])
    else:
        yield np.asarray(obs, dtype=np.float64)


def _summary(obs, reward, info) -> list[float]:
    values = np.concatenate([leaf.ravel() for leaf in _leaves(obs)])
    return [float(values.sum()), float(np.square(values).sum()), float(reward),
            *np.asarray(info["true_position"], dtype=np.float64).tolist()]


def fingerprint(env_id: str, obs_mode: str, seed: int, **kwargs) -> list[list[float]]:
    """Per step: sum and sum of squares of the observation, reward, true position."""
    env = gym.make(env_id, obs_mode=obs_mode, **kwargs)
    try:
        env.action_space.seed(seed)
        obs, info = env.reset(seed=seed)
        rows = [_summary(obs, 0.0, info)]
        for _ in range(STEPS):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            rows.append(_summary(obs, reward, info))
            if terminated or truncated:
                break
        return rows
    finally:
        env.close()


#: Each family's harder setting that predates the presets, fingerprinted too.
VARIANTS = {
    "DockingStation": {"scenario": "current"},
    "LampArrayDocking": {"scenario": "current"},
    "LARSCapture": {"sea_state": "severe"},
    "AcousticTracking": {"trajectory": "static"},
}


def cases() -> list[tuple[str, str, dict]]:
    """(id, obs mode, keywords) of every registered id's non-image modes, plain and varied."""
    out = []
    for env_id in auv_envs.ENVIRONMENTS:
        family = env_id.split("/")[1].split("-")[0]
        for mode in auv_envs.env_class(env_id).obs_modes:
            if mode not in IMAGE_MODES:
                out += [(env_id, mode, {}), (env_id, mode, VARIANTS[family])]
    return out


def key(env_id: str, mode: str, kwargs: dict, seed: int) -> str:
    return "|".join([env_id, mode, json.dumps(kwargs, sort_keys=True), str(seed)])


def record() -> dict:
    return {key(env_id, mode, kwargs, seed): fingerprint(env_id, mode, seed, **kwargs)
            for env_id, mode, kwargs in cases() for seed in SEEDS}


if __name__ == "__main__":
    with open(sys.argv[1], "w") as f:
        json.dump(record(), f, indent=0)
