"""The LARS capture environment in JAX: ``reset(rng) -> state``, ``step(state, action) -> state``.

The transition of ``auv_envs/LARSCapture-v0`` (:mod:`auv_envs.tasks.lars.transition`,
the very functions the CPU environment calls) evaluated on JAX arrays for ``jit``
and ``vmap``. What this shell adds: the arm is the CPU environment's own MuJoCo
model on MJX (:class:`ArmPlantMJX`), and the episode's draws come from a JAX key
(:class:`~auv_envs.batched.functional.KeyDraws`). The interface is
:class:`~auv_envs.batched.docking_env.DockingMJX`'s (MuJoCo Playground's
``MjxEnv``), with the same auto-reset.

Built: ``state`` and ``features``, ``sea_state`` ``"calm"`` and ``"severe"``
(wash-over occlusion, the analogs), both ``control`` modes, every
``difficulty``: the [LTAT] sinusoidal sea of ``easy``, the irregular ``sea``
of ``paper`` and ``hard`` (its realisation drawn from the key, the AUV, the
analogs and the ship moving with it) and ``hard``'s sun glint on the marker's
corners. Not built, and refused with a ``ValueError``: the rendered ``stereo``
mode.

What differs from the CPU environment: a seed gives other episodes (JAX's
generator; the distributions are the same); everything runs in float32; the
joint limits' forces are the exact minimiser of MuJoCo's constraint problem
(:meth:`ArmPlantMJX.constrain`), where MuJoCo iterates to a tolerance (the
equivalence tests bound the difference).
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from auv_envs.batched.functional import FunctionalEnv, KeyDraws, State
from auv_envs.core.ops import jax_ops
from auv_envs.core.sea import FloatingAnalog, WashOver
from auv_envs.tasks.lars import transition
from auv_envs.tasks.lars.env import FRAME_SKIP, LARSCaptureEnv
from auv_envs.tasks.lars.randomization import LARSRandomization
from auv_envs.tasks.lars.scene import AUVMotion
from auv_envs.tasks.lars.sea import EpisodeSea, GlintField
from auv_envs.tasks.lars.waves import HarmonicSeries, WaveRealisation


def _register(cls, meta=()) -> None:
    """Make a frozen dataclass of an episode's draws a JAX pytree (once per process)."""
    fields = [f.name for f in dataclasses.fields(cls)]
    jax.tree_util.register_dataclass(cls, data_fields=[f for f in fields if f not in meta],
                                     meta_fields=list(meta))


def _register_attributes(cls, children: tuple, aux: tuple = ()) -> None:
    """Make a class of an episode's sea a JAX pytree of its attributes ``children``
    (``aux``: static), rebuilt without running its constructor."""

    def flatten(obj):
        return (tuple(getattr(obj, name) for name in children),
                tuple(getattr(obj, name) for name in aux))

    def unflatten(static, leaves):
        obj = object.__new__(cls)
        for name, value in (*zip(children, leaves, strict=True),
                            *zip(aux, static, strict=True)):
            object.__setattr__(obj, name, value)
        return obj

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)


for _cls, _meta in ((AUVMotion, ()), (FloatingAnalog, ()), (GlintField, ()),
                    (WashOver, ("sweep", "overtop", "half_size"))):
    _register(_cls, _meta)
_register_attributes(WaveRealisation, ("omega", "amplitude", "phase", "heading", "wavenumber"))
_register_attributes(HarmonicSeries, ("omega", "_matrix"), ("n_channels", "_xp", "_buffer"))
_register_attributes(EpisodeSea, ("_series",), ("_n_analogs",))


def _spd_solve(matrix, rhs):
    """``matrix^-1 rhs`` for a small symmetric positive definite ``matrix`` (n, n), by a
    Cholesky factorisation written out entry by entry (under ``vmap`` on the CPU, JAX's
    ``cho_factor`` is a LAPACK call per lane)."""
    n = rhs.shape[0]
    lower = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            rest = matrix[i, j] - sum(lower[i][k] * lower[j][k] for k in range(j))
            lower[i][j] = jnp.sqrt(rest) if i == j else rest / lower[j][j]
    y = []
    for i in range(n):
        y.append((rhs[i] - sum(lower[i][k] * y[k] for k in range(i))) / lower[i][i])
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(lower[k][i] * x[k] for k in range(i + 1, n))) / lower[i][i]
    return jnp.stack(x)


class ArmPlantMJX:
    """The LARS arm on MJX: the CPU environment's model with contacts off (the CPU
    model has them disabled too) and MJX's sparse mass-matrix factorisation (MJX's own
    arithmetic: the dense one is a LAPACK call per arm on the CPU), stepped
    ``FRAME_SKIP`` physics steps a control period, the joint limits' forces solved
    exactly (:meth:`constrain`) instead of by MJX's iterative solver.

    ``control="torque"``: the action is the actuators' control. ``"position"``:
    [LTAT]'s computed-torque loop (eqs. 29-30) at the physics rate, as
    :class:`auv_envs.tasks.lars.env._MujocoArm` runs it on the CPU: the mass matrix
    and bias forces of each physics step's positions and velocities give its control.
    """

    def __init__(self, env: LARSCaptureEnv):
        model = copy.deepcopy(env.physics.model)
        model.geom_contype[:] = 0
        model.geom_conaffinity[:] = 0
        if model.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER:
            raise ValueError("the batched arm steps MuJoCo's Euler integrator; the model "
                             f"has integrator {model.opt.integrator}")
        if model.nsensor:
            raise ValueError("the batched arm steps without MJX's sensor stages; the model "
                             f"has {model.nsensor} sensors")
        limited = np.isin(model.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE,
                                           mujoco.mjtJoint.mjJNT_SLIDE)) & model.jnt_limited
        if (model.neq or model.ntendon or np.any(model.dof_frictionloss)
                or not np.all(limited) or np.any(model.dof_damping)):
            raise ValueError("the batched arm's constraint solve takes hinge and slide joint "
                             "limits only (no equality, tendon, friction loss) and no joint "
                             "damping")
        model.opt.jacobian = mujoco.mjtJacobian.mjJAC_SPARSE
        # Without joint damping, MuJoCo's Euler step has nothing to integrate implicitly:
        # MJX's would factorise the mass matrix again to find the same accelerations.
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
        self._active_sets = tuple(itertools.product((0.0, 1.0), repeat=model.njnt))
        self.model = mjx.put_model(model)
        #: An MJX data of the model at rest (the template a reset fills).
        self.rest_data = mjx.make_data(model)
        if self.rest_data._impl.efc_J.shape[0] != model.njnt:
            raise ValueError("expected one MJX constraint row per joint limit")
        self.torque_mode = env.control == "torque"
        self.dt = float(env.dt)
        self.q_mid = jnp.asarray(env.params.joint_mid, jnp.float32)
        self.q_half = jnp.asarray(env.params.joint_half, jnp.float32)
        self.limits = jnp.asarray(env.calibration.torque_limits, jnp.float32)
        self.kp, self.kd = env.calibration.position_gains
        self.timestep = float(model.opt.timestep)

    def place(self, q) -> mjx.Data:
        """The arm at rest at joint angles ``q`` (three scalars)."""
        return self.rest_data.replace(qpos=jnp.stack([jnp.asarray(v, jnp.float32) for v in q]))

    def constrain(self, data: mjx.Data, model: mjx.Model) -> mjx.Data:
        """``mjx.solve`` for this arm (simulating ``model``): the accelerations, joint-limit
        forces and constraint force MuJoCo's solver converges to, computed exactly.

        MuJoCo's constraint problem here is convex and piecewise quadratic (the Gauss
        term ``(a - a0)^T M (a - a0) / 2`` and ``D jar^2 / 2`` for each limit row with
        ``jar = J a - aref < 0``). Its minimiser solves the quadratic of its own active
        set, so it is the cheapest of the solutions of all ``2^rows`` active sets (each
        a small linear system), which is what is computed: no iteration, no LAPACK call
        under ``vmap``. The rows (``efc_J``, ``efc_D``, ``efc_aref``) are MJX's, from
        ``mjx.make_constraint`` (a row away from its limit is zero).
        """
        impl = data._impl  # MJX keeps the constraint rows in its implementation's fields
        jac, stiffness, aref = impl.efc_J, impl.efc_D, impl.efc_aref
        mass = mjx.full_m(model, data)
        smooth = data.qacc_smooth
        pushed = mass @ smooth
        best = None
        for active in self._active_sets:
            weight = stiffness * jnp.asarray(active, stiffness.dtype)
            qacc = _spd_solve(mass + (jac.T * weight) @ jac, pushed + jac.T @ (weight * aref))
            jar = jac @ qacc - aref
            force = -stiffness * jar * (jar < 0.0)
            change = qacc - smooth
            cost = 0.5 * change @ (mass @ change) - 0.5 * jnp.sum(force * jar)
            if best is None:
                best = (cost, qacc, force)
            else:
                take = cost < best[0]
                best = tuple(jnp.where(take, new, old) for new, old in
                             zip((cost, qacc, force), best, strict=True))
        _, qacc, force = best
        return data.replace(qacc=qacc, qfrc_constraint=jac.T @ force).tree_replace(
            {"_impl.efc_force": force})

    def _physics_step(self, data: mjx.Data, model: mjx.Model, control=None) -> mjx.Data:
        """``mjx.step`` of ``model`` (which has no sensors) with :meth:`constrain` for MJX's
        iterative solver; ``control`` (a function of the position and velocity stages'
        data) sets ``ctrl`` after them."""
        data = mjx.fwd_velocity(model, mjx.fwd_position(model, data))
        if control is not None:
            data = data.replace(ctrl=control(data))
        data = mjx.fwd_acceleration(model, mjx.fwd_actuation(model, data))
        return mjx.euler(model, self.constrain(data, model))

    def advance(self, data: mjx.Data, action, effort, model: mjx.Model):
        """One control period under ``action`` (3,) of the arm simulated by ``model`` (the
        env's world's: :class:`~auv_envs.batched.functional.World`): ``(data, effort)``, the
        running control effort with the period's added. The computed-torque loop of
        ``control="position"`` reads the simulated arm's mass matrix and bias forces, as on
        the CPU; its commands reach the joints through the world's motors."""
        # The FRAME_SKIP physics steps as a loop, not unrolled: XLA compiles the step
        # once instead of FRAME_SKIP times (docs/speed.md).
        if self.torque_mode:
            data = jax.lax.fori_loop(0, FRAME_SKIP,
                                     lambda _, now: self._physics_step(now, model),
                                     data.replace(ctrl=action))
            return data, effort + jnp.sum(action * action) * self.dt
        target = self.q_mid + action * self.q_half

        def control(now):  # computed torque from this step's mass matrix and bias
            accel = self.kp * (target - now.qpos) - self.kd * now.qvel
            tau = mjx.mul_m(model, now, accel) + now.qfrc_bias
            return jnp.clip(tau / self.limits, -1.0, 1.0)

        def physics_step(_, carry):
            now, effort = carry
            now = self._physics_step(now, model, control)
            return now, effort + jnp.sum(now.ctrl * now.ctrl) * self.timestep

        return jax.lax.fori_loop(0, FRAME_SKIP, physics_step, (data, effort))


class _Arm(NamedTuple):
    """The transition's plant in the batched env, a function of the arm's MJX data
    (:mod:`auv_envs.core.task`): :class:`ArmPlantMJX` simulating ``model``, the env's
    world's."""

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


class LARSMJX(FunctionalEnv):
    """The LARS capture environment as pure JAX functions of one episode.

    Args:
        env_id: ``"auv_envs/LARSCapture-v0"`` (or its batched id).
        obs_mode: ``"state"`` or ``"features"``.
        auto_reset: reset an episode inside :meth:`step` when it ends.
        privileged: observations ``{"state": <obs_mode's>, "privileged_state": <the
            24-entry state vector>}``, for an asymmetric critic
            (:class:`~auv_envs.batched.functional.FunctionalEnv`).
        randomization: the domain randomiser :meth:`randomize` draws worlds with (None:
            the shipped :class:`~auv_envs.tasks.lars.randomization.LARSRandomization`); the
            env simulates the nominal arm unless given other worlds.
        **env_kwargs: the CPU environment's arguments (``sea_state``, ``control``,
            ``image_size``, ``pixel_noise_std``, ``time_limit``, ...); they are checked
            by building that environment, whose model, calibration and transition
            parameters this one uses.

    Raises:
        ValueError: for what is not built yet (module docstring).
    """

    STEP_METRICS = transition.STEP_METRICS
    end_reason = staticmethod(transition.end_reason)

    def __init__(self, env_id: str = "auv_envs/LARSCapture-v0", obs_mode: str = "features",
                 auto_reset: bool = True, privileged: bool = False,
                 randomization: LARSRandomization | None = None, **env_kwargs):
        self._served(env_id, obs_mode)
        self._use_randomization(randomization, LARSRandomization)
        cpu = LARSCaptureEnv(obs_mode=obs_mode, **env_kwargs)
        self.cpu_env = cpu
        self.obs_mode = obs_mode
        self.auto_reset = auto_reset
        self.params = cpu.params
        self.calibration = cpu.calibration
        self.max_episode_steps = cpu.max_episode_steps
        self.observation_space = cpu.observation_space
        self.action_space = cpu.action_space
        self.ops = jax_ops()
        self.plant = ArmPlantMJX(cpu)
        self._offer_privileged(privileged)

    # ------------------------------------------------------------------ episodes
    def reset(self, rng: jax.Array) -> State:
        """A new episode drawn from ``rng`` (the CPU env's start distribution)."""
        rng, key = jax.random.split(rng)
        arm, episode, truth, obs, _ = transition.reset(
            self.params, transition.Backend(self.ops, KeyDraws(key), self._arm()))
        return self._first(rng, arm, episode, truth, obs)

    def reset_to(self, scene: transition.Scene, q, rng: jax.Array) -> State:
        """An episode in ``scene`` (a CPU environment's
        :class:`~auv_envs.tasks.lars.transition.Scene`, its numbers in float32) with
        the arm at rest at joint angles ``q``; the equivalence tests start the CPU and
        the batched environment alike this way."""
        ops = self.ops
        as32 = lambda tree: jax.tree_util.tree_map(  # noqa: E731
            lambda leaf: jnp.asarray(leaf, jnp.float32), tree)
        waves = scene.waves
        if waves is not None:
            waves = WaveRealisation(*(jnp.asarray(getattr(waves, name), jnp.float32)
                                      for name in ("omega", "amplitude", "phase", "heading")))
        scene = transition.scene_of(self.params, as32(scene.motion), waves, as32(scene.wash),
                                    as32(scene.analogs), as32(scene.glint), ops=ops)
        plant = self._arm()
        arm = plant.place(tuple(jnp.float32(v) for v in q))
        truth = plant.truth(arm, self.params, scene, ops.integer(0), ops)
        episode = transition.first_state(scene, truth, ops)
        episode, obs = transition.observe(
            self.params, episode, truth, transition.Backend(ops, KeyDraws(rng), plant))
        return self._first(rng, arm, episode, truth, obs)

    def _arm(self) -> _Arm:
        """The transition's plant: the arm in the env's world."""
        return _Arm(self.plant, self.ops, self.mjx_model.mjx)

    def _first(self, rng, arm, episode, truth, obs) -> State:
        terms = {term: jnp.float32(0.0) for term in transition.REWARD_TERMS}
        return self._started(rng, arm, episode, truth, obs,
                             self._metrics(truth, episode, None, terms))

    def _step(self, state: State, action: jax.Array) -> State:
        """One control period under the action (clipped to [-1, 1]):
        :func:`auv_envs.tasks.lars.transition.step` on JAX."""
        rng, key, _ = self._keys(state)
        arm, episode, truth, obs, judged = transition.step(
            self.params, state.plant, state.episode, self._action(action),
            transition.Backend(self.ops, KeyDraws(key), self._arm()))
        return self._conclude(state, rng, arm, episode, truth, obs, judged.terms,
                              judged.terminated, self._metrics(truth, episode, judged,
                                                               judged.terms))

    def truth(self, state: State) -> dict:
        """The ground truth of ``state`` (:func:`auv_envs.tasks.lars.transition.truth`)."""
        return transition.truth_now(self.params, state.plant, state.episode, self._arm(),
                                    self.ops)

    # ------------------------------------------------------------------ internals
    def _state_observation(self, episode: transition.EpisodeState, truth: dict) -> jax.Array:
        """:func:`auv_envs.tasks.lars.transition.observe` in ``state`` mode (it draws
        nothing: no draws are given) for the privileged state."""
        _, obs = transition.observe(dataclasses.replace(self.params, obs_mode="state"),
                                    episode, truth, transition.Backend(self.ops, None, None))
        return obs

    def _metrics(self, truth: dict, episode, judged, terms: dict) -> dict:
        """The step's metrics (:func:`~auv_envs.tasks.lars.transition.step_metrics`), its
        reward terms (``reward_<term>``) and the episode's summary so far (``episode_<key>``,
        :func:`~auv_envs.tasks.lars.transition.summary`)."""
        return {
            **transition.step_metrics(episode, truth, judged, self.ops),
            **{f"reward_{term}": jnp.float32(value) for term, value in terms.items()},
            **{f"episode_{key}": value for key, value in
               transition.summary(self.params, episode, truth, self.ops).items()},
        }
