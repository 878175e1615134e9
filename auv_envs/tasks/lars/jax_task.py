"""The LARS capture task on JAX: the transition and the arm on MJX, for the one batched
shell (:class:`auv_envs.batched.functional.FunctionalEnv`).

The transition of ``auv_envs/LARSCapture-v0`` (:mod:`auv_envs.tasks.lars.transition`, the
very functions the CPU environment calls) evaluated on JAX arrays for ``jit`` and
``vmap``. What this task adds: the arm is the CPU environment's own MuJoCo model on MJX
(:class:`~auv_envs.tasks.lars.mjx_plant.ArmPlantMJX`), and the episode's draws come from a
JAX key (:class:`~auv_envs.batched.functional.KeyDraws`). The episode's scene (the AUV's
motion, the sea, the sun) is a JAX pytree, declared beside its classes
(:mod:`auv_envs.core.pytree`) and registered when this module loads (JAX is an optional
extra: the CPU environment never imports it).

Built: ``state`` and ``features``, ``sea_state`` ``"calm"`` and ``"severe"`` (wash-over
occlusion, the analogs), both ``control`` modes, every ``difficulty``: the [LTAT]
sinusoidal sea of ``easy``, the irregular ``sea`` of ``paper`` and ``hard`` (its
realisation drawn from the key, the AUV, the analogs and the ship moving with it) and
``hard``'s sun glint on the marker's corners. Not built, and refused with a
``ValueError``: the rendered ``stereo`` mode.

What differs from the CPU environment: a seed gives other episodes (JAX's generator; the
distributions are the same); everything runs in float32; the joint limits' forces are the
exact minimiser of MuJoCo's constraint problem
(:meth:`~auv_envs.tasks.lars.mjx_plant.ArmPlantMJX.constrain`), where MuJoCo iterates to a
tolerance (the equivalence tests bound the difference).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from mujoco import mjx

from auv_envs.core.ops import jax_ops
from auv_envs.core.pytree import register_declared
from auv_envs.core.task import Transition
from auv_envs.tasks.lars import transition
from auv_envs.tasks.lars.config import LARSSetup
from auv_envs.tasks.lars.mjx_plant import ArmPlantMJX
from auv_envs.tasks.lars.randomization import LARSRandomization
from auv_envs.tasks.lars.waves import WaveRealisation

# The episode's scene (declared pytrees beside its classes) registered with JAX
register_declared()


class LARSJax:
    """The LARS capture task on JAX (what :class:`~auv_envs.batched.functional.FunctionalEnv`
    serves for ``auv_envs/LARSCapture-v0``).

    Args:
        setup: the task's parameters (:func:`auv_envs.tasks.lars.config.params` of a
            :class:`~auv_envs.tasks.lars.config.LARSConfig`; ``obs_mode`` ``"state"`` or
            ``"features"``).

    Raises:
        ValueError: for what is not built yet (module docstring).
    """

    transition = transition
    randomization_class = LARSRandomization
    render_camera = None
    end_reason = staticmethod(transition.end_reason)

    def __init__(self, setup: LARSSetup):
        self.setup = setup
        self.params = setup.params
        self.calibration = setup.calibration
        self.dt = setup.dt
        self.ops = jax_ops()
        self.plant = ArmPlantMJX(setup)
        self.observation_space, self.action_space = setup.observation_space, setup.action_space
        self.max_episode_steps = setup.max_episode_steps
        #: The task's MuJoCo model (the arm's) and its MJCF.
        self.mj_model, self.model_source = setup.model, setup.model_source

    # ------------------------------------------------------------------ the protocol
    def reset(self, draws, world) -> Transition:
        """:func:`auv_envs.tasks.lars.transition.reset` on JAX in ``world``."""
        return transition.reset(self.params, self._backend(draws, world))

    def step(self, plant, episode, action, draws, world) -> Transition:
        """:func:`auv_envs.tasks.lars.transition.step` on JAX in ``world``."""
        return transition.step(self.params, plant, episode, action,
                               self._backend(draws, world))

    def metrics(self, truth: dict, episode, judged) -> tuple[dict, dict]:
        """The step's metrics (:func:`~auv_envs.tasks.lars.transition.step_metrics`) and the
        episode's summary so far (:func:`~auv_envs.tasks.lars.transition.summary`)."""
        return (transition.step_metrics(episode, truth, judged, self.ops),
                transition.summary(self.params, episode, truth, self.ops))

    def state_observation(self, episode, truth: dict) -> jax.Array:
        """:func:`auv_envs.tasks.lars.transition.observe` in ``state`` mode (it draws
        nothing: no draws are given) for the privileged state."""
        _, obs = transition.observe(dataclasses.replace(self.params, obs_mode="state"),
                                    episode, truth, transition.Backend(self.ops, None, None))
        return obs

    def reset_to(self, scene: transition.Scene, q, rng: jax.Array, *, world):
        """An episode in ``scene`` (a CPU environment's
        :class:`~auv_envs.tasks.lars.transition.Scene`, its numbers in float32) with the arm
        at rest at joint angles ``q``: ``(rng, transition)``. The equivalence tests start
        the CPU and the batched environment alike this way."""
        from auv_envs.batched.functional import KeyDraws

        ops = self.ops
        as32 = lambda tree: jax.tree_util.tree_map(  # noqa: E731
            lambda leaf: jnp.asarray(leaf, jnp.float32), tree)
        waves = scene.waves
        if waves is not None:
            waves = WaveRealisation(*(jnp.asarray(getattr(waves, name), jnp.float32)
                                      for name in ("omega", "amplitude", "phase", "heading")))
        scene = transition.scene_of(self.params, as32(scene.motion), waves, as32(scene.wash),
                                    as32(scene.analogs), as32(scene.glint), ops=ops)
        backend = self._backend(KeyDraws(rng), world)
        arm = backend.plant.place(tuple(jnp.float32(v) for v in q))
        truth = backend.plant.truth(arm, self.params, scene, ops.integer(0), ops)
        episode, obs = transition.observe(self.params, transition.first_state(scene, truth, ops),
                                          truth, backend)
        return rng, Transition(arm, episode, truth, obs)

    def truth(self, plant, episode, world) -> dict:
        """The ground truth of the arm at ``plant`` in ``episode``
        (:func:`auv_envs.tasks.lars.transition.truth`)."""
        return transition.truth_now(self.params, plant, episode,
                                    self._backend(None, world).plant, self.ops)

    def _backend(self, draws, world) -> transition.Backend:
        return transition.Backend(self.ops, draws, _Arm(self.plant, self.ops, world.mjx))


class _Arm(NamedTuple):
    """The transition's plant on JAX, a function of the arm's MJX data
    (:mod:`auv_envs.core.task`): :class:`~auv_envs.tasks.lars.mjx_plant.ArmPlantMJX`
    simulating ``model``, the shell's world's."""

    plant: ArmPlantMJX
    ops: Any
    model: mjx.Model

    def place(self, q) -> mjx.Data:
        return self.plant.place(q)

    def advance(self, data: mjx.Data, action, effort) -> tuple:
        return self.plant.advance(data, action, effort, self.model)

    def truth(self, data: mjx.Data, params, scene, steps, ops) -> dict:
        return transition.truth(params, scene, steps, *joints(data, self.ops), ops)


def joints(data: mjx.Data, ops) -> tuple:
    """The arm's joint angles and rates at ``data``, three scalars each."""
    return ops.unpack(data.qpos), ops.unpack(data.qvel)
