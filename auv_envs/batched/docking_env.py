"""The docking environments in JAX: ``reset(rng) -> state``, ``step(state, action) -> state``.

The transition of ``auv_envs/DockingStation-v2`` and ``auv_envs/LampArrayDocking-v2``
(:mod:`auv_envs.tasks.docking.transition`, the very functions the CPU environment
calls) evaluated on JAX arrays for ``jit`` and ``vmap``: one environment's
functions, batched by :func:`jax.vmap` (:class:`auv_envs.batched.vector.TransitionVectorEnv`
does it and speaks NumPy to Gymnasium). What this shell adds: the plant is
:class:`auv_envs.batched.docking.DockingPlantMJX` (the env's MJCF on MuJoCo
MJX, the same hull wrench), the lines of sight to the lights are the CPU env's
(:func:`auv_envs.core.rays.blocked`, ``mj_ray``'s verdicts) on JAX, and the episode's draws
come from a JAX key (:class:`KeyDraws`, NumPy's ``Generator`` interface).

The interface follows MuJoCo Playground's ``MjxEnv``: :attr:`observation_size`,
:attr:`action_size`, :attr:`dt`, :attr:`mj_model`, :attr:`mjx_model`, and a
:class:`State` with ``data``, ``obs``, ``reward``, ``done``, ``metrics`` and
``info``. Unlike Playground's environments, :meth:`DockingMJX.step` resets a
finished episode itself (``auto_reset=True``, the default): the returned
state then holds the new episode's first observation, and
``info["final_obs"]`` and ``metrics`` the one that ended. ``data`` is the
plant state ``(qpos, qvel)``, not a full ``mjx.Data``.

Every argument of the CPU environment applies: both scenarios and every
``difficulty`` level with its disturbances and water. What differs from the
CPU environment: the episodes' random draws come from JAX's generator, so a
seed gives other episodes than the CPU env's (the distributions are the same);
everything runs in float32; the hull has no contacts (MJX has no
ellipsoid-box collision), so where the CPU hull would touch the station's
structure the batched one passes through it. ``image`` is not built.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from auv_envs.batched.docking import DockingPlantMJX
from auv_envs.batched.functional import FunctionalEnv, KeyDraws, State
from auv_envs.core import frames, rays
from auv_envs.core.camera import project_point
from auv_envs.core.ops import jax_ops
from auv_envs.core.vehicle import PlantPerturbation
from auv_envs.tasks.docking import transition
from auv_envs.tasks.docking.randomization import DockingRandomization
from auv_envs.tasks.docking.rules import failure_reason
from auv_envs.tasks.docking.station import CHASE_CAMERA


class DockingMJX(FunctionalEnv):
    """A docking environment as pure JAX functions of one episode.

    Args:
        env_id: ``"auv_envs/DockingStation-v2"``, ``"auv_envs/LampArrayDocking-v2"`` or
            ``"auv_envs/DockingMission-v0"`` (the RK4 plant; the v0 ids integrate with
            Euler and are refused).
        obs_mode: ``"state"``, ``"features"``, ``"nav"`` or ``"nav_features"``.
        auto_reset: reset an episode inside :meth:`step` when it ends.
        privileged: observations ``{"state": <obs_mode's>, "privileged_state": <the
            16-entry state vector>}``, for an asymmetric critic
            (:class:`~auv_envs.batched.functional.FunctionalEnv`).
        randomization: the domain randomiser :meth:`randomize` draws worlds with (None:
            the shipped :class:`~auv_envs.tasks.docking.randomization.DockingRandomization`).
            The env simulates the nominal world unless given others (Playground's
            ``wrap_for_brax_training(..., randomization_fn=...)``, ``gym.make_vec(...,
            randomize=True)``).
        **env_kwargs: the CPU environment's arguments (``scenario``,
            ``current_direction``, ``image_size``, ``time_limit``, ...); they are
            checked by building that environment, whose model, calibration and
            rules this one uses.
    """

    STEP_METRICS = transition.STEP_METRICS
    end_reason = staticmethod(failure_reason)
    render_camera = CHASE_CAMERA

    def __init__(self, env_id: str = "auv_envs/DockingStation-v2", obs_mode: str = "features",
                 auto_reset: bool = True, privileged: bool = False,
                 randomization: DockingRandomization | None = None, **env_kwargs):
        self._served(env_id, obs_mode)
        self._use_randomization(randomization, DockingRandomization)
        cpu = gym.make(env_id, obs_mode=obs_mode, **env_kwargs).unwrapped
        self.cpu_env = cpu
        self.env_id = env_id
        self.obs_mode = obs_mode
        self.auto_reset = auto_reset
        self.plant = DockingPlantMJX(cpu)
        self.rules = cpu.rules
        self.calibration = cal = cpu.calibration
        self.layout = cpu.layout
        self.scenario = cpu.scenario
        self.current_direction = env_kwargs.get("current_direction")
        self.max_episode_steps = cpu.max_episode_steps
        self.observation_space = cpu.observation_space
        self.action_space = cpu.action_space
        self.ops = jax_ops()
        #: The level's disturbances and water (the CPU env's, resolved from ``difficulty``).
        self.disturbances, self.optics = cal.disturbances, cal.optics
        lights = np.asarray(self.rules.lights, dtype=np.float32)
        self._lights = tuple(jnp.asarray(lights[:, k]) for k in range(3))
        bounds = cpu.params.pixel_bounds
        #: The CPU env's transition parameters, its arrays in float32.
        self.params = dataclasses.replace(
            cpu.params, light_positions=jnp.asarray(lights),
            pixel_bounds=None if bounds is None else tuple(jnp.asarray(b, jnp.float32)
                                                           for b in bounds))
        # The scenery the lines of sight are cast against: static geoms, placed once.
        physics = cpu.physics
        self._scenery = rays.static_primitives(physics.model, physics.data,
                                               physics.ray_groups, physics.hull_body)
        self._offer_privileged(privileged)

    # ------------------------------------------------------------------ episodes
    def reset(self, rng: jax.Array) -> State:
        """A new episode drawn from ``rng`` (the CPU env's start distribution)."""
        return self._begin(rng)

    @staticmethod
    def start_state(x, y, z, yaw, surge) -> tuple[jax.Array, jax.Array]:
        """The plant state of a vehicle at ``(x, y, z)``, level, heading ``yaw``, surging."""
        zero = jnp.zeros_like(yaw)
        quat = frames.quat_from_euler(zero, zero, yaw, xp=jnp)
        qpos = jnp.concatenate([jnp.stack([x, y, z]), quat])
        qvel = jnp.stack([surge * jnp.cos(yaw), surge * jnp.sin(yaw), zero, zero, zero, zero])
        return qpos, qvel

    def reset_to(self, qpos, qvel, rng: jax.Array, current_polar=(0.0, 0.0),
                 current_mean=None, plant_draws: dict | None = None) -> State:
        """An episode starting from the plant state ``(qpos, qvel)``.

        ``current_polar``: the current's (speed m/s, direction rad) now,
        ``current_mean`` the mean it varies about (default: the same);
        ``plant_draws``: the simulated vehicle's draws as the CPU env reports them
        (``info["plant"]`` at reset: ``mass_scale``, ``linear_damping_scale``,
        ``quadratic_damping_scale``, ``net_buoyancy_offset``), for a level with a
        plant perturbation. The rest of the episode's draws (the vehicle when
        not given, the lamps out) come from ``rng``. The equivalence tests start
        the CPU and the batched env alike this way.
        """
        polar = jnp.asarray(current_polar, jnp.float32)
        mean = polar if current_mean is None else jnp.asarray(current_mean, jnp.float32)
        start = transition.Start(None, None, None, None, None, polar, mean)
        vehicle = None
        if self.disturbances.plant.active and plant_draws is not None:
            vehicle = (jnp.float32(plant_draws["mass_scale"]),
                       jnp.asarray([*plant_draws["linear_damping_scale"],
                                    *plant_draws["quadratic_damping_scale"]], jnp.float32),
                       jnp.float32(plant_draws["net_buoyancy_offset"]))
        return self._begin(rng, start, vehicle, jnp.asarray(qpos, jnp.float32),
                           jnp.asarray(qvel, jnp.float32))

    def _begin(self, rng, start=None, vehicle=None, qpos=None, qvel=None) -> State:
        """:func:`auv_envs.tasks.docking.transition.reset` on JAX, as a :class:`State`."""
        rng, key = jax.random.split(rng)
        plant = _HullPlant(self, None if qpos is None else (qpos, qvel))
        body, episode, truth, obs, _ = transition.reset(
            self.params, transition.Backend(self.ops, KeyDraws(key), plant), start, vehicle)
        zero = jnp.float32(0.0)
        metrics = self._metrics(truth, episode, {term: zero for term in transition.REWARD_TERMS})
        return self._started(rng, body, episode, truth, obs, metrics)

    def _step(self, state: State, action: jax.Array) -> State:
        """One control period under the normalised action (clipped to [-1, 1]):
        :func:`auv_envs.tasks.docking.transition.step` on JAX."""
        rng, key, _ = self._keys(state)
        body, episode, truth, obs, judged = transition.step(
            self.params, state.plant, state.episode, self.ops.unpack(self._action(action)),
            transition.Backend(self.ops, KeyDraws(key), _HullPlant(self)))
        return self._conclude(state, rng, body, episode, truth, obs, judged.terms,
                              judged.terminated, self._metrics(truth, episode, judged.terms))

    # ------------------------------------------------------------------ internals
    def _state_observation(self, episode: transition.EpisodeState, truth: dict) -> jax.Array:
        """:func:`auv_envs.tasks.docking.transition.observe` in ``state`` mode (it draws
        nothing: no draws are given) for the privileged state."""
        return transition.observe(dataclasses.replace(self.params, obs_mode="state"), episode,
                                  truth, transition.Backend(self.ops, None, None))

    def _truth(self, qpos, qvel) -> dict:
        ops = self.ops
        rotation = frames.rotation_rows_from_quat(qpos[3], qpos[4], qpos[5], qpos[6])
        truth = self.rules.kinematics(tuple(qpos[k] for k in range(3)), rotation,
                                      tuple(qvel[k] for k in range(6)), ops)
        cx, cy, cz = truth["camera_position"]
        lx, ly, lz = self._lights
        u, v, inside = project_point(self.calibration.intrinsics, lx - cx, ly - cy, lz - cz,
                                     truth.pop("camera_rows"), ops)
        visible = inside & self._line_of_sight((cx, cy, cz))
        return transition.truth_with_lights(truth, jnp.stack([u, v], axis=-1), visible, ops)

    def _line_of_sight(self, camera) -> jax.Array:
        """Per light: nothing of the scenery between the ``camera`` centre (3 scalars) and
        it (:func:`auv_envs.core.rays.blocked`, as the CPU env's compiled truth)."""
        return jnp.logical_not(rays.blocked(self._scenery, camera, self._lights, self.ops))

    def _vehicle(self, draws, physics):
        """The episode's simulated vehicle (None: the env's own): the level's draws for the
        episode composed with the world's ``physics`` (factors multiply, offsets add)."""
        if physics is not None:
            world = (physics["mass_scale"], physics["damping_scale"], physics["buoyancy_offset"])
            draws = world if draws is None else (draws[0] * world[0],
                                                 jnp.asarray(draws[1]) * world[1],
                                                 draws[2] + world[2])
        if draws is None:
            return None
        return PlantPerturbation.apply(self.plant.hull.params, *draws)

    def _metrics(self, truth: dict, episode: transition.EpisodeState, terms: dict) -> dict:
        """The step's metrics, its reward terms (``reward_<term>``) and the episode's
        summary so far (``episode_<key>``, :func:`~auv_envs.tasks.docking.transition.summary`)."""
        return {
            **transition.step_metrics(truth, episode),
            **{f"reward_{term}": jnp.float32(value) for term, value in terms.items()},
            **{f"episode_{key}": value
               for key, value in transition.summary(episode, truth).items()},
        }


class _HullPlant(NamedTuple):
    """The transition's plant in the batched env, a function of the free joint's state
    ``{"qpos": (7,), "qvel": (6,)}`` (:mod:`auv_envs.core.task`): advanced by
    :class:`~auv_envs.batched.docking.DockingPlantMJX` in the env's world; ``given``, the
    ``(qpos, qvel)`` an episode starts from instead of its drawn start
    (:meth:`DockingMJX.reset_to`)."""

    env: DockingMJX
    given: tuple | None = None

    def place(self, start: transition.Start, vehicle, failed) -> dict:
        if self.given is None:
            qpos, qvel = self.env.start_state(start.x, start.y, start.z, start.yaw, start.surge)
        else:
            qpos, qvel = self.given
        return {"qpos": qpos, "qvel": qvel}

    def advance(self, body: dict, tau, current, vehicle) -> dict:
        env = self.env
        tau = jnp.asarray(tau, jnp.float32)
        physics = env.mjx_model.physics
        if physics is not None:  # the world's thrusters and unmodelled current
            tau = tau * physics["thrust_scale"]
            current = jnp.asarray(current) + physics["current"]
        qpos, qvel = env.plant.advance(body["qpos"], body["qvel"], tau, current,
                                       env._vehicle(vehicle, physics))
        return {"qpos": qpos, "qvel": qvel}

    def truth(self, body: dict) -> dict:
        return self.env._truth(body["qpos"], body["qvel"])
