"""Shared fixtures: the registry drives the generic tests.

Every registered environment class declares the contract these tests read:
``obs_modes``, ``reward_terms`` and ``metric_keys`` (class attributes), a
privileged ``info["true_position"]``, and its MuJoCo data at ``physics.data``.
"""

from __future__ import annotations

import fcntl
import tempfile
from pathlib import Path

import gymnasium as gym
import pytest

import auv_envs

ENV_IDS = tuple(auv_envs.ENVIRONMENTS)
#: One CPU id per JAX task of the family table (the docking ids share one), in the
#: table's order.
JAX_TASKS = tuple(entry.env_id for k, entry in enumerate(auv_envs.FAMILIES)
                       if all(entry.jax_task != e.jax_task for e in auv_envs.FAMILIES[:k]))
DOCKING_IDS = ("auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2")
#: Observation modes that render images; the tests shrink them.
IMAGE_MODES = ("image", "stereo")
#: Small images keep the image-mode tests fast; the pipeline is the same.
SMALL_IMAGE = (64, 48)


task_class = auv_envs.task_class


def obs_modes(env_id: str) -> tuple[str, ...]:
    modes = getattr(task_class(env_id), "obs_modes", None)
    if not modes:
        raise AssertionError(f"{env_id} does not declare its obs_modes")
    return tuple(modes)


ENV_MODE_PAIRS = [(e, m) for e in ENV_IDS for m in obs_modes(e)]


def make_env(env_id: str, obs_mode: str, **kwargs) -> gym.Env:
    if obs_mode in IMAGE_MODES:
        kwargs.setdefault("image_size", SMALL_IMAGE)
    return gym.make(env_id, obs_mode=obs_mode, **kwargs)


def leaves(obs):
    """The arrays of a (possibly nested ``Dict``) observation."""
    if isinstance(obs, dict):
        for value in obs.values():
            yield from leaves(value)
    else:
        yield obs


def fast_mode(env_id: str) -> str:
    """The first non-image observation mode of an environment."""
    return next(m for m in obs_modes(env_id) if m not in IMAGE_MODES and m != "state")


@pytest.fixture(params=ENV_MODE_PAIRS, ids=[f"{e.split('/')[1]}-{m}" for e, m in ENV_MODE_PAIRS])
def env_and_mode(request):
    env_id, mode = request.param
    env = make_env(env_id, mode)
    yield env_id, mode, env
    env.close()


@pytest.fixture(scope="module")
def array_of():
    """``make(config)``: the acoustic env's hydrophone array with another measurement
    configuration (:class:`auv_envs.core.acoustics.AcousticConfig`)."""
    from auv_envs.core.acoustics import HydrophoneArray

    env = gym.make("auv_envs/AcousticTracking-v2")
    base = env.unwrapped.calibration.array
    env.close()

    def make(config) -> HydrophoneArray:
        return HydrophoneArray(base.positions, base.surface_z, base.bottom_z, config)
    return make


@pytest.fixture(scope="module")
def one_ray_cluster_at_a_time():
    """Hold this machine's lock for Ray while a test (or a module) uses it, a local
    cluster or a Ray started in the test's process: the test processes (``pytest -n``)
    never run two Ray instances side by side on the same cores, whose daemons and
    workers would starve each other."""
    with open(Path(tempfile.gettempdir()) / "auv-envs-ray-cluster-tests.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield
