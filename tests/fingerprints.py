"""Seeded rollout fingerprints: what an environment did, in a few numbers per step.

``tests/data/release_fingerprints.json`` holds the fingerprints of every
registered id and non-image observation mode as released before the
``difficulty`` presets existed; ``tests/test_difficulty.py`` checks that the
default and ``difficulty="easy"`` still produce them.
``tests/data/level_fingerprints.json`` holds those of the ``paper`` and
``hard`` levels (recorded when the LARS and acoustic episodes
became transitions; :func:`level_cases`). Regenerate only when a behaviour
change is intended (and bump the id's version):

    python -m tests.fingerprints tests/data/release_fingerprints.json
    python -m tests.fingerprints --levels tests/data/level_fingerprints.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

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
    "DockingMission": {"layout": "lamp_array"},
}


def cases() -> list[tuple[str, str, dict]]:
    """(id, obs mode, keywords) of every registered id's non-image modes, plain and varied."""
    out = []
    for env_id in auv_envs.ENVIRONMENTS:
        family = env_id.split("/")[1].split("-")[0]
        for mode in auv_envs.task_class(env_id).obs_modes:
            if mode not in IMAGE_MODES:
                out += [(env_id, mode, {}), (env_id, mode, VARIANTS[family])]
    return out


#: The levels beyond the release that :func:`level_cases` fingerprints.
LEVELS = ("paper", "hard")


def level_cases() -> list[tuple[str, str, dict]]:
    """(id, obs mode, keywords) of every levelled id's non-image modes at each of
    :data:`LEVELS`, plain and varied."""
    return [(env_id, mode, {**kwargs, "difficulty": level})
            for env_id, mode, kwargs in cases()
            if hasattr(auv_envs.task_class(env_id), "difficulty_presets")
            for level in LEVELS]


def key(env_id: str, mode: str, kwargs: dict, seed: int) -> str:
    return "|".join([env_id, mode, json.dumps(kwargs, sort_keys=True), str(seed)])


def record(levels: bool = False) -> dict:
    """Every case's fingerprints: the release's (both seeds), or with ``levels`` the
    levels' (the first seed)."""
    if levels:
        return {key(env_id, mode, kwargs, SEEDS[0]): fingerprint(env_id, mode, SEEDS[0], **kwargs)
                for env_id, mode, kwargs in level_cases()}
    return {key(env_id, mode, kwargs, seed): fingerprint(env_id, mode, seed, **kwargs)
            for env_id, mode, kwargs in cases() for seed in SEEDS}


if __name__ == "__main__":
    levels = "--levels" in sys.argv[1:]
    path = Path([a for a in sys.argv[1:] if a != "--levels"][0])
    # Keep what is recorded for the ids no longer in ``auv_envs.ENVIRONMENTS`` (older
    # versions, still registered and still tested against their record).
    fingerprints = json.loads(path.read_text()) if path.exists() else {}
    fingerprints.update(record(levels))
    with open(path, "w") as f:
        json.dump(fingerprints, f, indent=0)
