"""Shared fixtures: the registry drives the generic tests."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import pytest  # noqa: E402

import auv_envs  # noqa: E402

ENV_IDS = tuple(auv_envs.ENVIRONMENTS)
#: Small images keep the image-mode tests fast; the pipeline is the same.
SMALL_IMAGE = (64, 48)


def obs_modes(env_id: str) -> tuple[str, ...]:
    env = gym.make(env_id)
    try:
        from auv_envs.tasks import docking

        if isinstance(env.unwrapped, docking.DockingEnv):
            return docking.OBS_MODES
        raise AssertionError(f"no obs-mode list known for {env_id}")
    finally:
        env.close()


ENV_MODE_PAIRS = [(e, m) for e in ENV_IDS for m in obs_modes(e)]


def make_env(env_id: str, obs_mode: str, **kwargs) -> gym.Env:
    if obs_mode == "image":
        kwargs.setdefault("image_size", SMALL_IMAGE)
    return gym.make(env_id, obs_mode=obs_mode, **kwargs)


@pytest.fixture(params=ENV_MODE_PAIRS, ids=[f"{e.split('/')[1]}-{m}" for e, m in ENV_MODE_PAIRS])
def env_and_mode(request):
    env_id, mode = request.param
    env = make_env(env_id, mode)
    yield env_id, mode, env
    env.close()
