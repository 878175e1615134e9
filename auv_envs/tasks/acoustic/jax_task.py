"""The acoustic tracking task on JAX: the transition and the rig on MJX, for the one
batched shell (:class:`auv_envs.batched.functional.FunctionalEnv`).

The transition of ``auv_envs/AcousticTracking-v2``
(:mod:`auv_envs.tasks.acoustic.transition`, the very functions the CPU environment
calls) evaluated on JAX arrays for ``jit`` and
``vmap``. What this task adds: the rig is the CPU environment's own MuJoCo model on
MJX with MuJoCo's ellipsoid fluid model written in JAX
(:class:`~auv_envs.tasks.acoustic.mjx_plant.RigPlantMJX`), the episode's draws come from
a JAX key (:class:`~auv_envs.batched.functional.KeyDraws`), and every step simulates its
own sample period (the plant's ``block=1``; the CPU env simulates 50 at a time, the
same model).
The detection sets become a JAX pytree when this module loads (JAX is an optional extra:
the CPU environment never imports it).

Built: ``state`` and ``measurements`` (the padded detection sets with their mask and,
with dropouts, the node mask), both trajectories, every ``disturbance`` and
``difficulty`` (multipath, clutter, dropouts, propagation delay, wander, fading). The
detections are drawn in the measurement model's fixed-shape order (the plant's
``noise_draws="fixed"``: every candidate's noise drawn, the first K of the shuffled
candidates kept),
the same model as the CPU's draws of the kept detections only.

What differs from the CPU environment: a seed gives other episodes (JAX's generator;
the distributions are the same); everything runs in float32 (the detections too,
float64 on the CPU); the state keeps the
running sum of squared errors, not every estimate, so the episode's metrics are
``rmse``, ``steps`` and ``success`` (the CPU summary's ``max_error``, ``tfc``,
``tcfe`` and the rest need the whole record).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from auv_envs.core.acoustics import FIXED_DRAWS
from auv_envs.core.ops import Backend, jax_ops
from auv_envs.core.pytree import register_declared
from auv_envs.core.task import Transition
from auv_envs.tasks.acoustic import transition
from auv_envs.tasks.acoustic.config import AcousticSetup
from auv_envs.tasks.acoustic.mjx_plant import RigPlantMJX
from auv_envs.tasks.acoustic.plant import AcousticPhysics
from auv_envs.tasks.acoustic.randomization import AcousticRandomization

# The detection sets (a pytree declared beside their class) registered with JAX
register_declared()


class AcousticJax:
    """The acoustic tracking task on JAX (what
    :class:`~auv_envs.batched.functional.FunctionalEnv` serves for
    ``auv_envs/AcousticTracking-v2``).

    Args:
        setup: the task's parameters (:func:`auv_envs.tasks.acoustic.config.params` of an
            :class:`~auv_envs.tasks.acoustic.config.AcousticTrackingConfig`; ``obs_mode``
            ``"state"`` or ``"measurements"``).

    Raises:
        ValueError: for what is not built (module docstring), or a ``planner`` other
            than ``"segments"`` (the tabulated route of v0/v1 is drawn in NumPy only).
    """

    transition = transition
    randomization_class = AcousticRandomization
    render_camera = ("rig/carrier", 6.0)

    def __init__(self, setup: AcousticSetup):
        if setup.params.planner != "segments":
            raise ValueError("the batched acoustic environment draws the v2 route "
                             f"(planner='segments'), got planner={setup.params.planner!r}")
        self.setup = setup
        self.params = setup.params
        self.calibration = setup.calibration
        self.dt = self.params.dt
        self.ops = jax_ops()
        physics = AcousticPhysics(setup.model)
        physics.substeps = setup.config.physics_substeps
        self.plant = RigPlantMJX(physics)
        self.observation_space, self.action_space = setup.observation_space, setup.action_space
        self.max_episode_steps = setup.max_episode_steps
        #: The task's MuJoCo model (the tank's) and its MJCF.
        self.mj_model, self.model_source = setup.model, setup.model_source

    @staticmethod
    def end_reason(code, success) -> str:
        """Never called: an acoustic episode only times out (it has no ``failure``)."""
        raise NotImplementedError("acoustic tracking episodes only time out")

    # ------------------------------------------------------------------ the protocol
    def reset(self, draws, world) -> Transition:
        """:func:`auv_envs.tasks.acoustic.transition.reset` on JAX in ``world``."""
        return transition.reset(self.params, self._backend(draws, world))

    def step(self, plant, episode, action, draws, world) -> Transition:
        """Score the estimate ``action`` (clipped to the tank) and move on one sample
        period: :func:`auv_envs.tasks.acoustic.transition.step` on JAX in ``world``."""
        return transition.step(self.params, plant, episode, action,
                               self._backend(draws, world))

    def metrics(self, truth: dict, episode, judged) -> tuple[dict, dict]:
        """The step's scores (:func:`~auv_envs.tasks.acoustic.transition.scores`) and the
        episode's running summary made of them: ``rmse``, ``steps`` and ``success`` (the
        state keeps the running sum of squared errors, not the record the CPU summary
        reads)."""
        scores = transition.scores(self.params, episode, truth, self.ops)
        return scores, {"rmse": scores["running_rmse"], "steps": episode.steps,
                        "success": scores["is_success"]}

    def state_observation(self, episode, truth: dict) -> jax.Array:
        """:func:`auv_envs.tasks.acoustic.transition.observe` in ``state`` mode (the source's
        position and velocity and the current; it takes no draws) for the privileged
        state."""
        del truth  # the episode's block holds the truth
        return transition.observe(dataclasses.replace(self.params, obs_mode="state"), episode,
                                  self.ops.xp)

    def reset_to(self, plan: transition.Plan, rng: jax.Array, *, world):
        """The episode of ``plan`` (a CPU environment's
        :class:`~auv_envs.tasks.acoustic.transition.Plan`, its numbers in float32): ``(rng,
        transition)``. The equivalence tests start the CPU and the batched environment
        alike this way."""
        from auv_envs.batched.functional import KeyDraws

        plan = jax.tree_util.tree_map(lambda leaf: jnp.asarray(leaf, jnp.float32)
                                      if jnp.issubdtype(jnp.asarray(leaf).dtype, jnp.floating)
                                      else jnp.asarray(leaf), plan)
        return rng, transition.begin(self.params, plan, self._backend(KeyDraws(rng), world))

    def _backend(self, draws, world) -> Backend:
        return Backend(self.ops, draws, _Rig(self.plant, world.mjx))


class _Rig(NamedTuple):
    """The transition's plant on JAX, a function of the rig's MJX data
    (:mod:`auv_envs.core.task`): :class:`~auv_envs.tasks.acoustic.mjx_plant.RigPlantMJX`
    simulating ``model``, the shell's world's, one sample period a call; its state keeps
    no record and its detections are drawn in the fixed-shape order (how the plants
    differ: :mod:`auv_envs.tasks.acoustic.plant`)."""

    plant: RigPlantMJX
    model: Any

    #: One sample period simulated and measured a step.
    block = 1
    #: No record of the estimates (the state keeps the running sum of squared errors).
    record = False
    #: The measurement model's fixed-shape draw order.
    noise_draws = FIXED_DRAWS

    def place(self, carrier, arm):
        return self.plant.place(carrier, arm, self.model)

    def follow(self, rig, carrier_ref, carrier_vel, arm_ref, current, start):
        """One period's ``(rig, position, velocity)``, (1, 3) each (the transition's blocks
        are one period long here); period 0 is the rig as placed."""
        if isinstance(start, int) and start == 0:
            position, velocity = self.plant.source(rig, self.model)
        else:
            rig, position, velocity = self.plant.period(
                rig, carrier_ref[0], carrier_vel[0], arm_ref[0], current[0], self.model)
        return rig, position[None], velocity[None]
