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
generator; the distributions are the same); everything runs in float32; MJX's
constraint solver is not MuJoCo's, so an arm at a joint limit moves slightly
differently (the equivalence tests bound the difference).
"""

from __future__ import annotations

import copy
import dataclasses

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from auv_envs.batched.functional import FunctionalEnv, KeyDraws, State
from auv_envs.core.ops import jax_ops
from auv_envs.core.sea import FloatingAnalog, WashOver
from auv_envs.tasks.lars import transition
from auv_envs.tasks.lars.env import FRAME_SKIP, LARSCaptureEnv
from auv_envs.tasks.lars.scene import AUVMotion
from auv_envs.tasks.lars.sea import EpisodeSea, GlintField
from auv_envs.tasks.lars.waves import HarmonicSeries, WaveRealisation

#: The observation modes the batched environment builds.
OBS_MODES = ("state", "features")
#: The ``difficulty`` levels it builds (a literal: docs/env_pages.py reads it from the
#: source, without importing JAX).
LEVELS = ("easy", "paper", "hard")
#: ``info`` metrics carried every step (the CPU env's that are numbers).
STEP_METRICS = ("capture_error", "relative_speed", "marker_visible", "marker_occluded",
                "distractors_in_view", "is_success", "collision", "violation_workspace")


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


#: MJX's Newton solver on the arm: at most three iterations from the warm start (the
#: previous step's accelerations), up to 4 line-search steps each; the CPU model allows
#: 100 and 50 to a tolerance of 1e-8. The arm's only constraints are its three joint
#: limits, and three iterations reach the CPU solution there: from the same state, one
#: control period of arms driven into their limits ends within 7e-6 rad of MuJoCo's on
#: the CPU, as with 100 and 50; two iterations end up to 1.3e-4 rad off, one 0.6 rad
#: (``tests/test_batched_lars.py``). Under ``vmap`` on the CPU the solver was most of
#: a step: each lane's 3 x 3 Newton system is a LAPACK call (docs/speed.md).
SOLVER_ITERATIONS = 3
LINE_SEARCH_ITERATIONS = 4


class ArmPlantMJX:
    """The LARS arm on MJX: the CPU environment's model with contacts off (the CPU
    model has them disabled too), MJX's solver settings (:data:`SOLVER_ITERATIONS`) and
    its sparse mass-matrix factorisation (MJX's own arithmetic: the dense one is a LAPACK
    call per arm on the CPU), stepped ``FRAME_SKIP`` physics steps a control period.

    ``control="torque"``: the action is the actuators' control. ``"position"``:
    [LTAT]'s computed-torque loop (eqs. 29-30) at the physics rate, as
    :class:`auv_envs.tasks.lars.env._MujocoArm` runs it on the CPU: the mass matrix
    and bias forces of each physics step's positions and velocities give its control,
    and the step goes on from them (``mjx.step``'s stages, its position and velocity
    stages once).
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
        model.opt.iterations = SOLVER_ITERATIONS
        model.opt.ls_iterations = LINE_SEARCH_ITERATIONS
        model.opt.jacobian = mujoco.mjtJacobian.mjJAC_SPARSE
        self.model = mjx.put_model(model)
        #: An MJX data of the model at rest (the template a reset fills).
        self.rest_data = mjx.make_data(model)
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

    def advance(self, data: mjx.Data, action, effort):
        """One control period under ``action`` (3,): ``(data, effort)``, the running
        control effort with the period's added."""
        model = self.model
        if self.torque_mode:
            data = data.replace(ctrl=action)
            for _ in range(FRAME_SKIP):
                data = mjx.step(model, data)
            return data, effort + jnp.sum(action * action) * self.dt
        target = self.q_mid + action * self.q_half
        for _ in range(FRAME_SKIP):
            # mjx.step without its sensors (the model has none), the position and
            # velocity stages, which the control does not enter, run once.
            data = mjx.fwd_velocity(model, mjx.fwd_position(model, data))
            accel = self.kp * (target - data.qpos) - self.kd * data.qvel
            tau = mjx.mul_m(model, data, accel) + data.qfrc_bias
            ctrl = jnp.clip(tau / self.limits, -1.0, 1.0)
            effort = effort + jnp.sum(ctrl * ctrl) * self.timestep
            data = mjx.fwd_acceleration(model, mjx.fwd_actuation(model,
                                                                 data.replace(ctrl=ctrl)))
            data = mjx.euler(model, mjx.solve(model, data))
        return data, effort


class _ArmCursor:
    """The transition's plant in one traced call: the arm's MJX data, advanced by
    :class:`ArmPlantMJX`."""

    def __init__(self, plant: ArmPlantMJX, ops, data=None):
        self.plant, self.ops, self.data = plant, ops, data

    def place(self, q) -> None:
        self.data = self.plant.place(q)

    def advance(self, action, effort):
        self.data, effort = self.plant.advance(self.data, action, effort)
        return effort

    def joints(self) -> tuple:
        return self.ops.unpack(self.data.qpos), self.ops.unpack(self.data.qvel)

    def truth(self, params, scene, steps, ops) -> dict:
        return transition.truth(params, scene, steps, *self.joints(), ops)


class LARSMJX(FunctionalEnv):
    """The LARS capture environment as pure JAX functions of one episode.

    Args:
        obs_mode: ``"state"`` or ``"features"``.
        auto_reset: reset an episode inside :meth:`step` when it ends.
        **env_kwargs: the CPU environment's arguments (``sea_state``, ``control``,
            ``image_size``, ``pixel_noise_std``, ``time_limit``, ...); they are checked
            by building that environment, whose model, calibration and transition
            parameters this one uses.

    Raises:
        ValueError: for what is not built yet (module docstring).
    """

    def __init__(self, obs_mode: str = "features", auto_reset: bool = True, **env_kwargs):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"the batched LARS environment builds obs_mode {OBS_MODES}, got "
                             f"{obs_mode!r}")
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

    # ------------------------------------------------------------------ episodes
    def reset(self, rng: jax.Array) -> State:
        """A new episode drawn from ``rng`` (the CPU env's start distribution)."""
        rng, key = jax.random.split(rng)
        plant = _ArmCursor(self.plant, self.ops)
        episode, truth, obs = transition.reset(
            self.params, transition.Backend(self.ops, KeyDraws(key), plant))
        return self._first(rng, plant, episode, truth, obs)

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
        plant = _ArmCursor(self.plant, ops)
        plant.place(tuple(jnp.float32(v) for v in q))
        truth = transition.truth(self.params, scene, ops.integer(0), *plant.joints(), ops)
        episode = transition.first_state(scene, truth, ops)
        episode, obs = transition.observe(
            self.params, episode, truth, transition.Backend(ops, KeyDraws(rng), plant))
        return self._first(rng, plant, episode, truth, obs)

    def _first(self, rng, plant, episode, truth, obs) -> State:
        terms = {term: jnp.float32(0.0) for term in self.cpu_env.reward_terms}
        return self._started(rng, plant.data, episode, obs,
                             self._metrics(truth, episode, None, terms))

    def _step(self, state: State, action: jax.Array) -> State:
        """One control period under the action (clipped to [-1, 1]):
        :func:`auv_envs.tasks.lars.transition.step` on JAX."""
        rng, key, _ = self._keys(state)
        plant = _ArmCursor(self.plant, self.ops, state.plant)
        episode, truth, obs, judged = transition.step(
            self.params, state.episode, self._action(action),
            transition.Backend(self.ops, KeyDraws(key), plant))
        return self._conclude(state, rng, plant.data, episode, obs, judged.terms,
                              judged.terminated, self._metrics(truth, episode, judged,
                                                               judged.terms))

    def truth(self, state: State) -> dict:
        """The ground truth of ``state`` (:func:`auv_envs.tasks.lars.transition.truth`)."""
        plant = _ArmCursor(self.plant, self.ops, state.plant)
        return transition.truth_now(self.params, state.episode, plant, self.ops)

    # ------------------------------------------------------------------ internals
    def _metrics(self, truth: dict, episode, judged, terms: dict) -> dict:
        """The step's metrics (:data:`STEP_METRICS`), its reward terms (``reward_<term>``)
        and the episode's summary so far (``episode_<key>``,
        :func:`~auv_envs.tasks.lars.transition.summary`)."""
        false = jnp.bool_(False)
        step = {
            "capture_error": truth["capture_error"],
            "relative_speed": truth["relative_speed"],
            "marker_visible": truth["n_visible"],
            "marker_occluded": jnp.asarray(truth["occluded"], jnp.bool_),
            "distractors_in_view": jnp.asarray(truth["distractors"], jnp.int32),
            "is_success": episode.success,
            "collision": false if judged is None else judged.collision,
            "violation_workspace": false if judged is None else judged.workspace,
        }
        return {
            **step,
            **{f"reward_{term}": jnp.float32(value) for term, value in terms.items()},
            **{f"episode_{key}": value for key, value in
               transition.summary(self.params, episode, truth, self.ops).items()},
        }
