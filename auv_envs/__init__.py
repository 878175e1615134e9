"""auv_envs: Gymnasium + MuJoCo environments for AUV recovery.

Importing the package registers every environment::

    import gymnasium as gym
    import auv_envs  # noqa: F401
    env = gym.make("auv_envs/DockingStation-v2", obs_mode="features")
"""

from __future__ import annotations

import functools
import os
import sys

# MuJoCo picks its GL backend when first imported: default to headless EGL on
# Linux without a display, unless the user chose one already.
if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

from gymnasium.envs.registration import WrapperSpec, register, registry  # noqa: E402

__version__ = "0.1.0"

from auv_envs.families import FAMILIES, family  # noqa: E402

#: Every current environment id, with its task on the CPU (``"module:Class"``, a view of
#: :data:`FAMILIES`): ``gym.make(id)`` builds ``auv_envs.core.env.TaskEnv(task=<it>)``.
ENVIRONMENTS = {entry.env_id: entry.task for entry in FAMILIES}

#: Superseded versions, still registered so that published results stay
#: reproducible: id -> (its task, the keywords that give the old behaviour).
#: Agents, the leaderboard and the tests use :data:`ENVIRONMENTS`.
PREVIOUS_VERSIONS = {old: (entry.task, kwargs) for entry in FAMILIES
                     for old, kwargs in entry.previous.items()}

#: Applied by ``gym.make`` above its ``TimeLimit``: the episode summary on a
#: truncation from outside the env (``auv_envs.core.env.EpisodeSummary``).
_SUMMARY = WrapperSpec("EpisodeSummary", "auv_envs.core.env:EpisodeSummary", {})


def max_episode_steps(env_id: str) -> int:
    """The registered episode length of ``env_id`` (any version, or its batched twin), in
    steps."""
    return family(env_id).max_episode_steps


for _env_id, (_task, _kwargs) in {
    **{env_id: (entry, {}) for env_id, entry in ENVIRONMENTS.items()},
    **PREVIOUS_VERSIONS,
}.items():
    if _env_id not in registry:
        # Each env also truncates at its own time_limit (writing its episode
        # summary); TimeLimit truncates on the same step by default.
        register(id=_env_id, entry_point="auv_envs.core.env:TaskEnv",
                 kwargs={"task": _task, **_kwargs}, disable_env_checker=False,
                 max_episode_steps=max_episode_steps(_env_id), additional_wrappers=(_SUMMARY,))


#: The batched JAX twins of the CPU environments (``pip install -e ".[jax]"``): batched id
#: -> CPU id. ``gym.make_vec(id, num_envs=N)`` only (:mod:`auv_envs.batched.vector`).
BATCHED_ENVIRONMENTS = {entry.batched_id: entry.env_id for entry in FAMILIES}


def cpu_id(batched_id: str) -> str:
    """The CPU id a batched id twins (``auv_envs/DockingStationMJX-v2`` ->
    ``auv_envs/DockingStation-v2``)."""
    return BATCHED_ENVIRONMENTS[batched_id]


for _entry in FAMILIES:
    if _entry.batched_id not in registry:
        register(id=_entry.batched_id,
                 vector_entry_point="auv_envs.batched.vector:TransitionVectorEnv",
                 kwargs={"env_id": _entry.env_id, "obs_mode": _entry.batched_mode},
                 max_episode_steps=_entry.max_episode_steps)


def _prefix_hint(env_id: str, **kwargs):
    """What ``gym.make`` of an id without its ``auv_envs/`` namespace runs: an error that
    names the id to use (Gymnasium's own would say only that the name does not exist)."""
    import gymnasium as gym

    raise gym.error.NameNotFound(f"{env_id.split('/')[-1]!r} is registered as {env_id!r}: "
                                 f"gym.make({env_id!r}) (after `import auv_envs`)")


# Bare names, only where nothing else registered them: a hint, never an environment.
for _env_id in (*ENVIRONMENTS, *PREVIOUS_VERSIONS):
    if _env_id.split("/")[-1] not in registry:
        register(id=_env_id.split("/")[-1], entry_point=functools.partial(_prefix_hint, _env_id),
                 disable_env_checker=True)


def task_class(env_id: str):
    """The task class (:class:`auv_envs.core.env.CPUTask`) the env of ``env_id`` runs: its
    docstring, its signature (the env's arguments but ``task``), its ``obs_modes`` and
    ``difficulty_presets``.

    Raises:
        KeyError: ``env_id`` is not registered with Gymnasium, or not as a task.
    """
    import gymnasium as gym

    from auv_envs.core.env import load_task

    try:
        task = gym.spec(env_id).kwargs["task"]
    except (gym.error.Error, KeyError) as exc:
        raise KeyError(f"unknown environment {env_id!r}") from exc
    return load_task(task)
