"""The family table: every task family of the package, listed once.

Each :class:`Family` names its current Gymnasium id, its task on the CPU (which the one
Gymnasium env, :class:`auv_envs.core.env.TaskEnv`, runs), its task on JAX (which the one
batched shell, :class:`auv_envs.batched.functional.FunctionalEnv`, serves),
its registered episode length and its superseded versions.
``import auv_envs`` registers the ids from this table (``gym.make``, and ``gym.make_vec``
of the batched twins), :func:`auv_envs.batched.load`, the compiled trainer, the docs'
environment pages and the tests read it; :data:`auv_envs.ENVIRONMENTS` and its siblings
are views of it. Importing this module imports no simulator.
"""

from __future__ import annotations

import dataclasses
import importlib


@dataclasses.dataclass(frozen=True)
class Family:
    """One task family.

    Attributes:
        env_id: the current CPU id, ``auv_envs/<Name>-v<N>``.
        task: its task on the CPU, ``"module:Class"`` (a
            :class:`~auv_envs.core.env.CPUTask`; ``gym.make`` builds
            ``TaskEnv(task=<it>, ...)``).
        config: the family's configuration module (``default_config(env_id)``,
            ``config_of(env_id, **arguments)`` and ``params(config)``, the task's parameters
            built without an environment).
        jax_task: its task on JAX (``"module:Class"``, built as ``Class(setup)`` from the
            configuration's ``params`` by
            :class:`~auv_envs.batched.functional.FunctionalEnv`; ``pip install -e
            ".[jax]"``).
        batched_modes: the observation modes the JAX task builds (the rendered ones are
            the CPU env's alone).
        batched_mode: the batched twin's default observation mode (what
            ``gym.make_vec`` builds unless told; Brax's networks read it flattened).
        max_episode_steps: steps in the default episode, its default ``time_limit``
            divided by its step period (a test checks them against the classes);
            registered as ``max_episode_steps``, so ``TimeLimit``-aware tools see them.
        previous: superseded ids of the family, still registered so that published
            results stay reproducible: id -> the keywords that give the old behaviour.
    """

    env_id: str
    task: str
    config: str
    jax_task: str
    batched_modes: tuple
    batched_mode: str
    max_episode_steps: int
    previous: dict = dataclasses.field(default_factory=dict)

    @property
    def name(self) -> str:
        """The id's name without namespace or version (``DockingStation``)."""
        return self.env_id.split("/")[-1].rsplit("-v", 1)[0]

    @property
    def batched_id(self) -> str:
        """The batched twin's id: the CPU id with ``MJX`` after the family's name."""
        namespace, name_version = self.env_id.split("/")
        name, version = name_version.rsplit("-v", 1)
        return f"{namespace}/{name}MJX-v{version}"

    def setup(self, env_id: str | None = None, **arguments):
        """The parameters of ``gym.make(env_id, **arguments)`` (its arguments but the
        rendering ones; ``env_id`` default: the current id) built without an environment:
        the configuration module's ``params(config_of(env_id, **arguments))``."""
        module = importlib.import_module(self.config)
        return module.params(module.config_of(env_id or self.env_id, **arguments))

    def task_class(self):
        """The task class on the CPU (a :class:`~auv_envs.core.env.CPUTask`): its
        docstring, signature, ``obs_modes`` and ``difficulty_presets`` describe the env."""
        from auv_envs.core.env import load_task

        return load_task(self.task)

    def jax_task_class(self):
        """The task class on JAX (imports JAX)."""
        module, name = self.jax_task.split(":")
        return getattr(importlib.import_module(module), name)


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

_DOCKING_BATCHED = ("auv_envs.tasks.docking.config",
                    "auv_envs.tasks.docking.jax_task:DockingJax",
                    ("state", "features", "nav", "nav_features"), "features")

#: Every family, in the order the docs and the tests list them. Episode lengths: docking
#: 100 s at 0.1 s, acoustic 60 s at 0.01 s, LARS 30 s at 0.04 s, the mission 600 s at 0.1 s.
FAMILIES = (
    Family("auv_envs/DockingStation-v2", "auv_envs.tasks.docking.env:DockingStationTask",
           *_DOCKING_BATCHED, 1000,
           {"auv_envs/DockingStation-v0": _DOCKING_V0_PLANT,
            "auv_envs/DockingStation-v1": _DOCKING_V1_PLANT}),
    Family("auv_envs/LampArrayDocking-v2", "auv_envs.tasks.docking.env:LampArrayDockingTask",
           *_DOCKING_BATCHED, 1000,
           {"auv_envs/LampArrayDocking-v0": _DOCKING_V0_PLANT,
            "auv_envs/LampArrayDocking-v1": _DOCKING_V1_PLANT}),
    Family("auv_envs/AcousticTracking-v2", "auv_envs.tasks.acoustic.env:AcousticTrackingTask",
           "auv_envs.tasks.acoustic.config", "auv_envs.tasks.acoustic.jax_task:AcousticJax",
           ("state", "measurements"), "measurements", 6000,
           {"auv_envs/AcousticTracking-v0": _ACOUSTIC_V0,
            "auv_envs/AcousticTracking-v1": _ACOUSTIC_V1}),
    Family("auv_envs/LARSCapture-v0", "auv_envs.tasks.lars.env:LARSCaptureTask",
           "auv_envs.tasks.lars.config", "auv_envs.tasks.lars.jax_task:LARSJax",
           ("state", "features"), "features", 750),
    Family("auv_envs/DockingMission-v0", "auv_envs.tasks.docking.mission:DockingMissionTask",
           *_DOCKING_BATCHED, 6000),
)


def family(env_id: str) -> Family:
    """The family of ``env_id``: its CPU id, its batched twin's, or a superseded one.

    Raises:
        KeyError: ``env_id`` is none of this package's ids.
    """
    for entry in FAMILIES:
        if env_id in (entry.env_id, entry.batched_id) or env_id in entry.previous:
            return entry
    raise KeyError(f"unknown environment {env_id!r}; the families are "
                   f"{[entry.env_id for entry in FAMILIES]}")
