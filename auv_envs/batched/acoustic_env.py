"""The acoustic tracking environment in JAX: ``reset(rng)``, ``step(state, action)``.

The transition of ``auv_envs/AcousticTracking-v2``
(:mod:`auv_envs.tasks.acoustic.transition`, the very functions the CPU environment
calls) evaluated on JAX arrays for ``jit`` and
``vmap``. What this shell adds: the rig is the CPU environment's own MuJoCo model on
MJX with MuJoCo's ellipsoid fluid model written in JAX
(:class:`~auv_envs.batched.acoustic_plant.RigPlantMJX`), the episode's draws come from
a JAX key (:class:`~auv_envs.batched.functional.KeyDraws`), and every step simulates its
own sample period (``block=1``; the CPU env simulates 50 at a time, the same model).
The interface is :class:`~auv_envs.batched.functional.FunctionalEnv`'s (MuJoCo
Playground's ``MjxEnv``), with the same auto-reset.

Built: ``state`` and ``measurements`` (the padded detection sets with their mask and,
with dropouts, the node mask), both trajectories, every ``disturbance`` and
``difficulty`` (multipath, clutter, dropouts, propagation delay, wander, fading). The
detections are drawn in the measurement model's fixed-shape order (``noise_draws=
"fixed"``: every candidate's noise drawn, the first K of the shuffled candidates kept),
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

from auv_envs.batched.acoustic_plant import RigPlantMJX
from auv_envs.batched.functional import FunctionalEnv, KeyDraws, State
from auv_envs.core.acoustics import FIXED_DRAWS, Measurements
from auv_envs.core.ops import Backend, jax_ops
from auv_envs.tasks.acoustic import transition
from auv_envs.tasks.acoustic.env import AcousticTrackingEnv
from auv_envs.tasks.acoustic.randomization import AcousticRandomization

# The detection sets are a JAX pytree of their arrays (registered when this module loads).
jax.tree_util.register_dataclass(Measurements, data_fields=["values", "mask", "origin",
                                                            "dropped"], meta_fields=[])


class _Rig(NamedTuple):
    """The transition's plant in the batched env, a function of the rig's MJX data
    (:mod:`auv_envs.core.task`): :class:`RigPlantMJX` simulating ``model``, the env's
    world's, one sample period a call."""

    plant: RigPlantMJX
    model: Any

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


class AcousticMJX(FunctionalEnv):
    """The acoustic tracking environment as pure JAX functions of one episode.

    Args:
        env_id: ``"auv_envs/AcousticTracking-v2"`` (or its batched id).
        obs_mode: ``"state"`` or ``"measurements"``.
        auto_reset: reset an episode inside :meth:`step` when it ends.
        privileged: observations ``{"state": <obs_mode's>, "privileged_state": <the
            9-entry state vector>}``, for an asymmetric critic
            (:class:`~auv_envs.batched.functional.FunctionalEnv`).
        randomization: the domain randomiser :meth:`randomize` draws worlds with (None:
            the shipped :class:`~auv_envs.tasks.acoustic.randomization.AcousticRandomization`);
            the env simulates the nominal rig unless given other worlds.
        **env_kwargs: the CPU environment's arguments (``disturbance``, ``trajectory``,
            ``time_limit``, ``difficulty``, ...); they are checked by building that
            environment, whose model, calibration and transition parameters this one uses.

    Raises:
        ValueError: for what is not built (module docstring), or a ``planner`` other
            than ``"segments"`` (the tabulated route of v0/v1 is drawn in NumPy only).
    """

    STEP_METRICS = transition.STEP_METRICS
    render_camera = ("rig/carrier", 6.0)

    def __init__(self, env_id: str = "auv_envs/AcousticTracking-v2", obs_mode: str = "state",
                 auto_reset: bool = True, privileged: bool = False,
                 randomization: AcousticRandomization | None = None, **env_kwargs):
        self._served(env_id, obs_mode)
        self._use_randomization(randomization, AcousticRandomization)
        cpu = AcousticTrackingEnv(obs_mode=obs_mode, **env_kwargs)
        if cpu.params.planner != "segments":
            raise ValueError("the batched acoustic environment draws the v2 route "
                             f"(planner='segments'), got planner={cpu.params.planner!r}")
        self.cpu_env = cpu
        self.obs_mode = obs_mode
        self.auto_reset = auto_reset
        self.params = dataclasses.replace(cpu.params, block=1, record=False,
                                          noise_draws=FIXED_DRAWS)
        self.calibration = cpu.calibration
        self.max_episode_steps = cpu.max_episode_steps
        self.observation_space = cpu.observation_space
        self.action_space = cpu.action_space
        self.ops = jax_ops()
        self.plant = RigPlantMJX(cpu.physics)
        self._offer_privileged(privileged)

    @property
    def dt(self) -> float:
        return self.params.dt

    # ------------------------------------------------------------------ episodes
    def reset(self, rng: jax.Array) -> State:
        """A new episode drawn from ``rng`` (the CPU env's start distribution)."""
        rng, key = jax.random.split(rng)
        rig, episode, now, obs, _ = transition.reset(
            self.params, Backend(self.ops, KeyDraws(key), self._rig()))
        return self._first(rng, rig, episode, now, obs)

    def reset_to(self, plan: transition.Plan, rng: jax.Array) -> State:
        """The episode of ``plan`` (a CPU environment's
        :class:`~auv_envs.tasks.acoustic.transition.Plan`, its numbers in float32); the
        equivalence tests start the CPU and the batched environment alike this way."""
        plan = jax.tree_util.tree_map(lambda leaf: jnp.asarray(leaf, jnp.float32)
                                      if jnp.issubdtype(jnp.asarray(leaf).dtype, jnp.floating)
                                      else jnp.asarray(leaf), plan)
        rig, episode, now, obs, _ = transition.begin(
            self.params, plan, Backend(self.ops, KeyDraws(rng), self._rig()))
        return self._first(rng, rig, episode, now, obs)

    def _rig(self) -> _Rig:
        """The transition's plant: the rig in the env's world."""
        return _Rig(self.plant, self.mjx_model.mjx)

    def _first(self, rng, rig, episode, now, obs) -> State:
        terms = {term: jnp.float32(0.0) for term in transition.REWARD_TERMS}
        return self._started(rng, rig, episode, now, obs, self._metrics(episode, now, terms))

    def _step(self, state: State, action: jax.Array) -> State:
        """Score the estimate ``action`` (clipped to the tank) and move on one sample
        period: :func:`auv_envs.tasks.acoustic.transition.step` on JAX."""
        rng, key, _ = self._keys(state)
        rig, episode, now, obs, judged = transition.step(
            self.params, state.plant, state.episode, self._action(action),
            Backend(self.ops, KeyDraws(key), self._rig()))
        return self._conclude(state, rng, rig, episode, now, obs, judged.terms,
                              judged.terminated, self._metrics(episode, now, judged.terms))

    # ------------------------------------------------------------------ internals
    def _state_observation(self, episode: transition.EpisodeState, truth: dict) -> jax.Array:
        """:func:`auv_envs.tasks.acoustic.transition.observe` in ``state`` mode (the source's
        position and velocity and the current; it takes no draws) for the privileged
        state."""
        del truth  # the episode's block holds the truth
        return transition.observe(dataclasses.replace(self.params, obs_mode="state"), episode,
                                  self.ops.xp)

    def _metrics(self, episode, now: dict, terms: dict) -> dict:
        """The step's scores (:func:`~auv_envs.tasks.acoustic.transition.scores`), its
        reward terms (``reward_<term>``) and the episode's running summary
        (``episode_rmse``, ``episode_steps``, ``episode_success``)."""
        scores = transition.scores(self.params, episode, now, self.ops)
        return {
            **scores,
            **{f"reward_{term}": jnp.float32(value) for term, value in terms.items()},
            "episode_rmse": scores["running_rmse"],
            "episode_steps": episode.steps,
            "episode_success": scores["is_success"],
        }
