"""The docking task on JAX: the transition, the plant on MJX and the lines of sight, for
the one batched shell (:class:`auv_envs.batched.functional.FunctionalEnv`).

The transition of ``auv_envs/DockingStation-v2``, ``auv_envs/LampArrayDocking-v2`` and
``auv_envs/DockingMission-v0`` (:mod:`auv_envs.tasks.docking.transition`, the very
functions the CPU environment calls) evaluated on JAX arrays for ``jit`` and ``vmap``.
What this task adds: the plant is :class:`auv_envs.tasks.docking.mjx_plant.DockingPlantMJX`
(the env's MJCF on MuJoCo MJX, the same hull wrench), the lines of sight to the lights are
the CPU env's (:func:`auv_envs.core.rays.blocked`, ``mj_ray``'s verdicts) on JAX, and the
episode's draws come from a JAX key (:class:`~auv_envs.batched.functional.KeyDraws`,
NumPy's ``Generator`` interface). The shell's ``data`` is the plant state ``{"qpos",
"qvel"}`` and the transition's ``EpisodeState``, not a full ``mjx.Data``.

Every argument of the CPU environment applies: both scenarios and every ``difficulty``
level with its disturbances and water. What differs from the CPU environment: the
episodes' random draws come from JAX's generator, so a seed gives other episodes than the
CPU env's (the distributions are the same); everything runs in float32; the hull has no
contacts (MJX has no ellipsoid-box collision), so where the CPU hull would touch the
station's structure the batched one passes through it. ``image`` is not built.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from auv_envs.core import frames, rays
from auv_envs.core.camera import project_point
from auv_envs.core.ops import jax_ops
from auv_envs.core.task import Transition
from auv_envs.core.vehicle import PlantPerturbation
from auv_envs.tasks.docking import transition
from auv_envs.tasks.docking.config import DockingSetup
from auv_envs.tasks.docking.mjx_plant import DockingPlantMJX
from auv_envs.tasks.docking.randomization import DockingRandomization
from auv_envs.tasks.docking.rules import failure_reason
from auv_envs.tasks.docking.station import CHASE_CAMERA, DockingPhysics


class DockingJax:
    """The docking task on JAX (what :class:`~auv_envs.batched.functional.FunctionalEnv`
    serves for the docking ids).

    Args:
        setup: the task's parameters (:func:`auv_envs.tasks.docking.config.params` of a
            :class:`~auv_envs.tasks.docking.config.DockingConfig`: any id, scenario and
            ``difficulty`` level); its ``integrator`` must be ``"rk4"`` (the v0 ids
            integrate with Euler and are refused) and its ``obs_mode`` one of
            ``"state"``, ``"features"``, ``"nav"`` or ``"nav_features"``.
    """

    transition = transition
    randomization_class = DockingRandomization
    render_camera = CHASE_CAMERA
    end_reason = staticmethod(failure_reason)

    def __init__(self, setup: DockingSetup):
        self.setup = setup
        self.plant = DockingPlantMJX(setup)
        self.rules = setup.rules
        self.calibration = cal = setup.calibration
        self.dt = cal.control_period
        self.ops = jax_ops()
        #: The level's disturbances (resolved from ``difficulty``).
        self.disturbances = cal.disturbances
        lights = np.asarray(self.rules.lights, dtype=np.float32)
        self._lights = tuple(jnp.asarray(lights[:, k]) for k in range(3))
        bounds = setup.params.pixel_bounds
        #: The transition's parameters, its arrays in float32.
        self.params = dataclasses.replace(
            setup.params, light_positions=jnp.asarray(lights),
            pixel_bounds=None if bounds is None else tuple(jnp.asarray(b, jnp.float32)
                                                           for b in bounds))
        self.observation_space, self.action_space = setup.observation_space, setup.action_space
        self.max_episode_steps = setup.max_episode_steps
        #: The task's MuJoCo model and its MJCF (:class:`~auv_envs.core.assets.MJCF`).
        self.mj_model, self.model_source = setup.model, setup.model_source
        # The scenery the lines of sight are cast against: static geoms, placed once.
        physics = DockingPhysics(setup.model, len(setup.layout.light_labels))
        self._scenery = rays.static_primitives(physics.model, physics.data,
                                               physics.ray_groups, physics.hull_body)

    # ------------------------------------------------------------------ the protocol
    def reset(self, draws, world) -> Transition:
        """:func:`auv_envs.tasks.docking.transition.reset` on JAX in ``world``."""
        return transition.reset(self.params, self._backend(draws, world))

    def step(self, plant, episode, action, draws, world) -> Transition:
        """:func:`auv_envs.tasks.docking.transition.step` on JAX in ``world`` (``action``
        the normalised command, already in the action box)."""
        return transition.step(self.params, plant, episode, self.ops.unpack(action),
                               self._backend(draws, world))

    def metrics(self, truth: dict, episode, judged) -> tuple[dict, dict]:
        """The step's metrics (:func:`~auv_envs.tasks.docking.transition.step_metrics`) and
        the episode's summary so far (:func:`~auv_envs.tasks.docking.transition.summary`)."""
        return transition.step_metrics(truth, episode), transition.summary(episode, truth)

    def state_observation(self, episode, truth: dict) -> jax.Array:
        """:func:`auv_envs.tasks.docking.transition.observe` in ``state`` mode (it draws
        nothing: no draws are given) for the privileged state."""
        return transition.observe(dataclasses.replace(self.params, obs_mode="state"), episode,
                                  truth, transition.Backend(self.ops, None, None))

    def reset_to(self, qpos, qvel, rng: jax.Array, current_polar=(0.0, 0.0),
                 current_mean=None, plant_draws: dict | None = None, *, world):
        """An episode starting from the plant state ``(qpos, qvel)``: ``(rng,
        transition)``, the key the state keeps and the episode's start.

        ``current_polar``: the current's (speed m/s, direction rad) now,
        ``current_mean`` the mean it varies about (default: the same);
        ``plant_draws``: the simulated vehicle's draws as the CPU env reports them
        (``info["plant"]`` at reset: ``mass_scale``, ``linear_damping_scale``,
        ``quadratic_damping_scale``, ``net_buoyancy_offset``), for a level with a
        plant perturbation. The rest of the episode's draws (the vehicle when
        not given, the lamps out) come from ``rng``. The equivalence tests start
        the CPU and the batched env alike this way.
        """
        from auv_envs.batched.functional import KeyDraws

        polar = jnp.asarray(current_polar, jnp.float32)
        mean = polar if current_mean is None else jnp.asarray(current_mean, jnp.float32)
        start = transition.Start(None, None, None, None, None, polar, mean)
        vehicle = None
        if self.disturbances.plant.active and plant_draws is not None:
            vehicle = (jnp.float32(plant_draws["mass_scale"]),
                       jnp.asarray([*plant_draws["linear_damping_scale"],
                                    *plant_draws["quadratic_damping_scale"]], jnp.float32),
                       jnp.float32(plant_draws["net_buoyancy_offset"]))
        rng, key = jax.random.split(rng)
        given = (jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))
        backend = transition.Backend(self.ops, KeyDraws(key), _HullPlant(self, world, given))
        return rng, transition.reset(self.params, backend, start, vehicle)

    # ------------------------------------------------------------------ internals
    def _backend(self, draws, world) -> transition.Backend:
        return transition.Backend(self.ops, draws, _HullPlant(self, world))

    @staticmethod
    def start_state(x, y, z, yaw, surge) -> tuple[jax.Array, jax.Array]:
        """The plant state of a vehicle at ``(x, y, z)``, level, heading ``yaw``, surging."""
        zero = jnp.zeros_like(yaw)
        quat = frames.quat_from_euler(zero, zero, yaw, xp=jnp)
        qpos = jnp.concatenate([jnp.stack([x, y, z]), quat])
        qvel = jnp.stack([surge * jnp.cos(yaw), surge * jnp.sin(yaw), zero, zero, zero, zero])
        return qpos, qvel

    def truth(self, plant: dict, episode, world) -> dict:
        """The ground truth of the vehicle at ``plant`` (``{"qpos", "qvel"}``)."""
        return self.hull_truth(plant["qpos"], plant["qvel"])

    def hull_truth(self, qpos, qvel) -> dict:
        """The transition's truth of the free joint at ``(qpos, qvel)``: the kinematics of
        :meth:`~auv_envs.tasks.docking.rules.DockingRules.kinematics` and the lights in
        view."""
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

    def vehicle(self, draws, physics):
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


class _HullPlant(NamedTuple):
    """The transition's plant on JAX, a function of the free joint's state ``{"qpos": (7,),
    "qvel": (6,)}`` (:mod:`auv_envs.core.task`): advanced by
    :class:`~auv_envs.tasks.docking.mjx_plant.DockingPlantMJX` in ``world`` (the shell's
    :class:`~auv_envs.batched.functional.World`); ``given``, the ``(qpos, qvel)`` an
    episode starts from instead of its drawn start (:meth:`DockingJax.reset_to`)."""

    task: DockingJax
    world: object
    given: tuple | None = None

    def place(self, start: transition.Start, vehicle, failed) -> dict:
        if self.given is None:
            qpos, qvel = self.task.start_state(start.x, start.y, start.z, start.yaw,
                                               start.surge)
        else:
            qpos, qvel = self.given
        return {"qpos": qpos, "qvel": qvel}

    def advance(self, body: dict, tau, current, vehicle) -> dict:
        task, physics = self.task, self.world.physics
        tau = jnp.asarray(tau, jnp.float32)
        if physics is not None:  # the world's thrusters and unmodelled current
            tau = tau * physics["thrust_scale"]
            current = jnp.asarray(current) + physics["current"]
        qpos, qvel = task.plant.advance(body["qpos"], body["qvel"], tau, current,
                                        task.vehicle(vehicle, physics))
        return {"qpos": qpos, "qvel": qvel}

    def truth(self, body: dict) -> dict:
        return self.task.hull_truth(body["qpos"], body["qvel"])
