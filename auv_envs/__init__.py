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

#: Every environment id this package registers, with its entry point.
ENVIRONMENTS = {
    "auv_envs/DockingStation-v2": "auv_envs.tasks.docking.env:DockingStationEnv",
    "auv_envs/LampArrayDocking-v2": "auv_envs.tasks.docking.env:LampArrayDockingEnv",
    "auv_envs/AcousticTracking-v2": "auv_envs.tasks.acoustic.env:AcousticTrackingEnv",
    "auv_envs/LARSCapture-v0": "auv_envs.tasks.lars.env:LARSCaptureEnv",
    "auv_envs/DockingMission-v0": "auv_envs.tasks.docking.mission:DockingMissionEnv",
}

#: The v0 docking plant: semi-implicit Euler, two 0.05 s steps per control period.
_DOCKING_V0_PLANT = {"integrator": "euler", "physics_substeps": 2, "plant": "mujoco"}
#: The v1 docking plant: MuJoCo's RK4 staged with the hull wrench at every stage,
#: throughout (v2 compiles the hull away from the scenery: the same equations).
_DOCKING_V1_PLANT = {"plant": "mujoco"}
#: Acoustic tracking v0: the rig integrated by implicitfast in one step a period (v1: Euler
#: in two), the measurement noise drawn for every path before the detections (v1: for
#: the kept detections only) and the detections drawn in every mode (v1: when observed or
#: rendered).
_ACOUSTIC_V0 = {"integrator": "implicitfast", "physics_substeps": 1, "noise_draws": "all",
                "draw_detections": True, "planner": "tabulated"}
#: Acoustic tracking v1: the carrier's route drawn by the sequential planner (v2: drawn
#: per segment, every draw made, by the same code on NumPy and JAX).
_ACOUSTIC_V1 = {"planner": "tabulated"}

#: Superseded versions, still registered so that published results stay
#: reproducible: id -> (entry point, the keywords that give the old behaviour).
#: Agents, the leaderboard and the tests use :data:`ENVIRONMENTS`.
PREVIOUS_VERSIONS = {
    "auv_envs/DockingStation-v0": (
        "auv_envs.tasks.docking.env:DockingStationEnv", _DOCKING_V0_PLANT
    ),
    "auv_envs/LampArrayDocking-v0": (
        "auv_envs.tasks.docking.env:LampArrayDockingEnv", _DOCKING_V0_PLANT
    ),
    "auv_envs/DockingStation-v1": (
        "auv_envs.tasks.docking.env:DockingStationEnv", _DOCKING_V1_PLANT
    ),
    "auv_envs/LampArrayDocking-v1": (
        "auv_envs.tasks.docking.env:LampArrayDockingEnv", _DOCKING_V1_PLANT
    ),
    "auv_envs/AcousticTracking-v0": (
        "auv_envs.tasks.acoustic.env:AcousticTrackingEnv", _ACOUSTIC_V0
    ),
    "auv_envs/AcousticTracking-v1": (
        "auv_envs.tasks.acoustic.env:AcousticTrackingEnv", _ACOUSTIC_V1
    ),
}

#: Steps in each family's default episode: its default ``time_limit`` divided
#: by its step period (docking 100 s at 0.1 s, LARS 30 s at 0.04 s, acoustic
#: 60 s at 0.01 s, the docking mission 600 s at 0.1 s; a test checks them against the
#: classes). Registered as
#: ``max_episode_steps``, so ``TimeLimit``-aware tools see them.
MAX_EPISODE_STEPS = {
    "DockingStation": 1000,
    "LampArrayDocking": 1000,
    "AcousticTracking": 6000,
    "LARSCapture": 750,
    "DockingMission": 6000,
}

#: Applied by ``gym.make`` above its ``TimeLimit``: the episode summary on a
#: truncation from outside the env (``auv_envs.core.env.EpisodeSummary``).
_SUMMARY = WrapperSpec("EpisodeSummary", "auv_envs.core.env:EpisodeSummary", {})


def max_episode_steps(env_id: str) -> int:
    """The registered episode length of ``env_id`` (any version), in steps."""
    return MAX_EPISODE_STEPS[env_id.split("/")[-1].rsplit("-v", 1)[0]]


for _env_id, (_entry_point, _kwargs) in {
    **{env_id: (entry, {}) for env_id, entry in ENVIRONMENTS.items()},
    **PREVIOUS_VERSIONS,
}.items():
    if _env_id not in registry:
        # Each env also truncates at its own time_limit (writing its episode
        # summary); TimeLimit truncates on the same step by default.
        register(id=_env_id, entry_point=_entry_point, kwargs=_kwargs, disable_env_checker=False,
                 max_episode_steps=max_episode_steps(_env_id), additional_wrappers=(_SUMMARY,))


#: The batched JAX twins of the CPU environments (``pip install -e ".[jax]"``):
#: ``gym.make_vec(id, num_envs=N)`` only (:mod:`auv_envs.batched.vector`).
BATCHED_ENVIRONMENTS = {
    "auv_envs/DockingStationMJX-v2": "auv_envs.batched.vector:docking_station",
    "auv_envs/LampArrayDockingMJX-v2": "auv_envs.batched.vector:lamp_array_docking",
    "auv_envs/DockingMissionMJX-v0": "auv_envs.batched.vector:docking_mission",
    "auv_envs/LARSCaptureMJX-v0": "auv_envs.batched.vector:lars_capture",
    "auv_envs/AcousticTrackingMJX-v2": "auv_envs.batched.vector:acoustic_tracking",
}


def cpu_id(batched_id: str) -> str:
    """The CPU id a batched id twins (``auv_envs/DockingStationMJX-v2`` ->
    ``auv_envs/DockingStation-v2``)."""
    return batched_id.replace("MJX", "")


for _env_id, _vector_entry_point in BATCHED_ENVIRONMENTS.items():
    if _env_id not in registry:
        register(id=_env_id, vector_entry_point=_vector_entry_point,
                 max_episode_steps=max_episode_steps(cpu_id(_env_id)))


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


def env_class(env_id: str):
    """The class (or creator function) Gymnasium has registered for ``env_id``.

    Raises:
        KeyError: ``env_id`` is not registered with Gymnasium.
    """
    import gymnasium as gym

    try:
        entry_point = gym.spec(env_id).entry_point
    except gym.error.Error as exc:
        raise KeyError(f"unknown environment {env_id!r}") from exc
    if isinstance(entry_point, str):
        entry_point = gym.envs.registration.load_env_creator(entry_point)
    return entry_point
