"""The docking environments in JAX: ``reset(rng) -> state``, ``step(state, action) -> state``.

A functional twin of ``auv_envs/DockingStation-v1`` and
``auv_envs/LampArrayDocking-v1`` for ``jit`` and ``vmap``: one environment's
functions, batched by :func:`jax.vmap` (:class:`auv_envs.batched.vector.DockingVectorEnv`
does it and speaks NumPy to Gymnasium). Nothing of the task is written
twice: the plant is :class:`auv_envs.batched.docking.DockingPlantMJX` (the
env's MJCF on MuJoCo MJX, the same hull wrench); the camera projection is
:func:`auv_envs.core.camera.project_point`; the pose, sensors, docking test,
failures and reward are :class:`auv_envs.tasks.docking_rules.DockingRules`,
all evaluated on JAX arrays through :func:`auv_envs.core.ops.jax_ops`; the
lines of sight to the lights are MJX's ray casts against the same scenery
(``mujoco.mj_ray`` on the CPU).

The interface follows MuJoCo Playground's ``MjxEnv``: :attr:`observation_size`,
:attr:`action_size`, :attr:`dt`, :attr:`mj_model`, :attr:`mjx_model`, and a
:class:`State` with ``data``, ``obs``, ``reward``, ``done``, ``metrics`` and
``info``. Unlike Playground's environments, :meth:`DockingMJX.step` resets a
finished episode itself (``auto_reset=True``, the default): the returned
state then holds the new episode's first observation, and
``info["final_obs"]`` and ``metrics`` the one that ended. ``data`` is the
plant state ``(qpos, qvel)``, not a full ``mjx.Data``.

Every argument of the CPU environment applies: both scenarios (the
``current`` scenario's current and sensor noise) and every ``difficulty``
level with its disturbances (the Gauss–Markov current, the per-episode
perturbation of the simulated vehicle, the thruster lag) and its water (lamp
detection, failed lamps, passing occluders), each through the CPU env's own
code (:mod:`auv_envs.core.sea`, :mod:`auv_envs.core.vehicle`,
:mod:`auv_envs.core.optics`) given JAX's draws. What differs from the CPU
environment: the episodes' random draws come from JAX's generator, so a seed
gives other episodes than the CPU env's (the distributions are the same);
everything runs in float32; the hull has no contacts (MJX has no
ellipsoid-box collision), so where the CPU hull would touch the station's
structure the batched one passes through it. ``image`` is not built.
"""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from auv_envs.batched.docking import DockingPlantMJX
from auv_envs.core import frames
from auv_envs.core.camera import project_point
from auv_envs.core.ops import jax_ops
from auv_envs.core.optics import LampOutages, lamp_detections
from auv_envs.core.sea import current_components
from auv_envs.core.vehicle import PlantPerturbation, lagged_thrust, thruster_lag_gain
from auv_envs.tasks.docking import (
    SCENARIO_CURRENT_SPEED,
    START_HEADING_SPREAD_DEG,
    START_SURGE,
)
from auv_envs.tasks.docking_rules import FAILURE_REASONS

#: The observation modes the batched environment builds.
OBS_MODES = ("state", "features")
#: ``info`` metrics carried every step (the CPU env's ``metric_keys`` that are numbers).
STEP_METRICS = ("distance_to_entrance", "longitudinal_error", "lateral_error", "vertical_error",
                "heading_error", "lights_visible", "is_success")


@jax.tree_util.register_dataclass
@dataclasses.dataclass
class State:
    """One environment's state (a batch of them under ``vmap``), as Playground's.

    Attributes:
        data: the plant state, ``{"qpos": (7,), "qvel": (6,)}``.
        obs: the observation (an array for ``state``, a dict for ``features``).
        reward: the last step's reward.
        done: whether the last step ended the episode (terminated or truncated).
        metrics: the last step's metrics (:data:`STEP_METRICS`), its reward terms
            (``reward_<term>``) and the episode's summary so far (``episode_*``).
        info: the episode's bookkeeping (``rng``, ``steps``, ...), ``terminated``,
            ``truncation`` and ``final_obs`` (the observation that ended the
            episode; the present one otherwise).
    """

    data: dict
    obs: object
    reward: jax.Array
    done: jax.Array
    metrics: dict
    info: dict

    def replace(self, **changes) -> State:
        return dataclasses.replace(self, **changes)


class DockingMJX:
    """A docking environment as pure JAX functions of one episode.

    Args:
        env_id: ``"auv_envs/DockingStation-v1"`` or ``"auv_envs/LampArrayDocking-v1"``
            (the RK4 plant; the v0 ids integrate with Euler and are refused).
        obs_mode: ``"state"`` or ``"features"``.
        auto_reset: reset an episode inside :meth:`step` when it ends.
        **env_kwargs: the CPU environment's arguments (``scenario``,
            ``current_direction``, ``image_size``, ``time_limit``, ...); they are
            checked by building that environment, whose model, calibration and
            rules this one uses.
    """

    def __init__(self, env_id: str = "auv_envs/DockingStation-v1", obs_mode: str = "features",
                 auto_reset: bool = True, **env_kwargs):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"the batched environment builds obs_mode {OBS_MODES}, got "
                             f"{obs_mode!r}")
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
        self._thrust = jnp.asarray(cal.thrust_limits, dtype=jnp.float32)
        #: The level's disturbances and water (the CPU env's, resolved from ``difficulty``).
        self.disturbances, self.optics = cal.disturbances, cal.optics
        self._thruster_gain = thruster_lag_gain(self.disturbances.thruster_time_constant,
                                                cal.control_period)
        lights = np.asarray(self.rules.lights, dtype=np.float32)
        self._lights = tuple(jnp.asarray(lights[:, k]) for k in range(3))
        self._n_lights = len(lights)
        if obs_mode == "features":
            space = cpu.observation_space["pixels"]
            self._pixel_bounds = (jnp.asarray(space.low), jnp.asarray(space.high))
        # The scenery the lines of sight are cast against: static geoms, placed once.
        physics = cpu.physics
        # Compiled: run eagerly, op by op, this forward pass took 24 s on 2 CPU cores, 5 compiled.
        self._ray_data = jax.jit(mjx.forward)(self.plant.model, self.plant.rest_data)
        self._ray_groups = tuple(int(g) for g in physics.ray_groups)
        self._hull_body = int(physics.hull_body)

    # ------------------------------------------------------------------ Playground's interface
    @property
    def dt(self) -> float:
        return self.calibration.control_period

    @property
    def action_size(self) -> int:
        return 4

    @property
    def observation_size(self):
        space = self.observation_space
        if isinstance(space, gym.spaces.Dict):
            return {key: value.shape for key, value in space.items()}
        return space.shape[0]

    @property
    def mj_model(self):
        return self.cpu_env.physics.model

    @property
    def mjx_model(self):
        return self.plant.model

    # ------------------------------------------------------------------ episodes
    def reset(self, rng: jax.Array) -> State:
        """A new episode drawn from ``rng`` (the CPU env's start distribution)."""
        rng, key = jax.random.split(rng)
        keys = jax.random.split(key, 7)
        lay = self.layout
        x = jax.random.uniform(keys[0], (), minval=lay.start_x[0], maxval=lay.start_x[1])
        y = jax.random.uniform(keys[1], (), minval=lay.start_y[0], maxval=lay.start_y[1])
        z = jax.random.uniform(keys[2], (), minval=lay.start_z[0], maxval=lay.start_z[1])
        yaw = jnp.arctan2(-y, -x) + jax.random.uniform(keys[3], (), minval=-1.0, maxval=1.0) \
            * math.radians(START_HEADING_SPREAD_DEG)
        surge = jax.random.uniform(keys[4], (), minval=START_SURGE[0], maxval=START_SURGE[1])
        qpos, qvel = self.start_state(x, y, z, yaw, surge)
        varying = self.disturbances.current
        if self.scenario == "current" or varying.active:
            speed = SCENARIO_CURRENT_SPEED if self.scenario == "current" else 0.0
            direction = (jnp.float32(math.radians(self.current_direction))
                         if self.current_direction is not None
                         else jax.random.uniform(keys[5], (), maxval=2.0 * math.pi))
            polar = (speed, direction)
            if varying.active:
                polar = varying.start_from(speed, direction,
                                           *jax.random.normal(keys[6], (2,)), self.ops)
            mean = (speed, direction)
        else:
            polar = mean = (0.0, 0.0)
        return self.reset_to(qpos, qvel, rng, current_polar=polar, current_mean=mean)

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
        ops = self.ops
        qpos, qvel = jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32)
        polar = jnp.asarray(current_polar, jnp.float32)
        mean = polar if current_mean is None else jnp.asarray(current_mean, jnp.float32)
        rng, vehicle_key, lamp_key, obs_key = jax.random.split(rng, 4)
        zero, false = jnp.float32(0.0), jnp.bool_(False)
        info = {
            "rng": rng, "steps": jnp.int32(0), "current_polar": polar, "current_mean": mean,
            "current": jnp.stack(current_components(polar[0], polar[1], ops)).astype(jnp.float32),
            "lost_time": zero, "success": false, "failure": jnp.int32(0),
            "docking_time": jnp.float32(jnp.nan), "fov_violations": jnp.int32(0),
            "control_effort": zero, "terminated": false, "truncation": false,
        }
        plant = self.disturbances.plant
        if plant.active and plant_draws is not None:
            info["plant"] = {
                "mass_scale": jnp.float32(plant_draws["mass_scale"]),
                "damping_scale": jnp.asarray([*plant_draws["linear_damping_scale"],
                                              *plant_draws["quadratic_damping_scale"]],
                                             jnp.float32),
                "net_buoyancy_offset": jnp.float32(plant_draws["net_buoyancy_offset"]),
            }
        elif plant.active:
            keys = jax.random.split(vehicle_key, 3)
            info["plant"] = {
                "mass_scale": jax.random.uniform(keys[0], (), minval=1.0 - plant.mass,
                                                 maxval=1.0 + plant.mass),
                "damping_scale": jax.random.uniform(keys[1], (12,), minval=1.0 - plant.damping,
                                                    maxval=1.0 + plant.damping),
                "net_buoyancy_offset": jax.random.uniform(
                    keys[2], (), minval=-plant.net_buoyancy, maxval=plant.net_buoyancy),
            }
        if self._thruster_gain != 1.0:
            info["thrust"] = jnp.zeros(4, jnp.float32)
        if self.optics is not None:
            failed_key, occluded_key = jax.random.split(lamp_key)
            n = self._n_lights
            info["failed"] = jax.random.uniform(failed_key, (n,)) \
                < self.optics.lamp_failure_probability
            info["occluded"] = jax.random.uniform(occluded_key, (n,)) \
                < LampOutages.occluded_share(self.optics)
        truth = self._truth(qpos, qvel)
        obs = self._observation(truth, info, obs_key)
        info.update(prev_potential=self.rules.potential(truth),
                    min_lights_visible=truth["n_visible"], final_obs=obs)
        metrics = self._metrics(truth, info, {term: zero for term in self.cpu_env.reward_terms})
        return State({"qpos": qpos, "qvel": qvel}, obs, zero, false, metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        """One control period under the normalised action (clipped to [-1, 1])."""
        info = dict(state.info)
        ops = self.ops
        rng, current_key, lamp_key, obs_key, reset_key = jax.random.split(info["rng"], 5)
        action = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        force = action * self._thrust
        if self._thruster_gain != 1.0:  # first-order thrusters: the force moves to the command
            force = lagged_thrust(info["thrust"], force, self._thruster_gain)
            info["thrust"] = force
        varying = self.disturbances.current
        if varying.active:
            polar = varying.relax(info["current_polar"][0], info["current_polar"][1],
                                  info["current_mean"][0], info["current_mean"][1], self.dt,
                                  *jax.random.normal(current_key, (2,)), ops)
            info["current_polar"] = jnp.stack(polar).astype(jnp.float32)
            info["current"] = jnp.stack(current_components(*polar, ops)).astype(jnp.float32)
        tau = jnp.stack([force[0], force[1], force[2], 0.0, 0.0, force[3]])
        qpos, qvel = self.plant.advance(state.data["qpos"], state.data["qvel"], tau,
                                        info["current"], self._vehicle(info))
        truth = self._truth(qpos, qvel)
        rules = self.rules
        steps = info["steps"] + 1
        fov_violation = truth["n_visible"] < rules.min_visible
        lost_time = rules.lights_lost_time(info["lost_time"], fov_violation, ops)
        docked = rules.docked(truth)
        flags = rules.failures(truth, docked, lost_time, ops)
        code = jnp.asarray(rules.failure_index(flags, ops), jnp.int32)
        potential = rules.potential(truth)
        terms = rules.reward_terms(info["prev_potential"], potential,
                                   tuple(action[k] for k in range(4)), fov_violation, docked,
                                   code > 0, ops)
        reward = sum(terms.values())
        terminated = docked | (code > 0)
        truncated = jnp.logical_not(terminated) & (steps >= self.max_episode_steps)
        if self.optics is not None and self.obs_mode == "features":  # occluders pass
            u = jax.random.uniform(lamp_key, (self._n_lights,))
            info["occluded"] = LampOutages.occlusions_after(info["occluded"], self.optics,
                                                            self.dt, u, xp=jnp)
        obs = self._observation(truth, info, obs_key)
        info.update({
            "rng": rng, "steps": steps, "lost_time": lost_time,
            "prev_potential": potential, "success": info["success"] | docked,
            "failure": code,
            "docking_time": jnp.where(docked, steps * self.dt, info["docking_time"]),
            "fov_violations": info["fov_violations"] + fov_violation,
            "min_lights_visible": jnp.minimum(info["min_lights_visible"], truth["n_visible"]),
            "control_effort": info["control_effort"] + jnp.sum(force * force) * self.dt,
            "terminated": terminated, "truncation": truncated, "final_obs": obs,
        })
        done = terminated | truncated
        stepped = State({"qpos": qpos, "qvel": qvel}, obs, reward, done,
                        self._metrics(truth, info, terms), info)
        if not self.auto_reset:
            return stepped
        fresh = self.reset(reset_key)
        fresh = fresh.replace(
            reward=reward, done=done, metrics=stepped.metrics,
            info={**fresh.info, "terminated": terminated, "truncation": truncated,
                  "final_obs": obs})
        return jax.tree_util.tree_map(lambda new, old: jnp.where(done, new, old), fresh, stepped)

    # ------------------------------------------------------------------ internals
    def _truth(self, qpos, qvel) -> dict:
        ops = self.ops
        rotation = frames.rotation_rows_from_quat(qpos[3], qpos[4], qpos[5], qpos[6])
        truth = self.rules.kinematics(tuple(qpos[k] for k in range(3)), rotation,
                                      tuple(qvel[k] for k in range(6)), ops)
        cx, cy, cz = truth["camera_position"]
        lx, ly, lz = self._lights
        u, v, inside = project_point(self.calibration.intrinsics, lx - cx, ly - cy, lz - cz,
                                     truth.pop("camera_rows"), ops)
        visible = inside & self._line_of_sight(jnp.stack([cx, cy, cz]))
        pixels = jnp.stack([u, v], axis=-1)
        truth.update(pixels=pixels, visible=visible,
                     visible_pixels=jnp.where(visible[:, None], pixels, 0.0),
                     n_visible=jnp.sum(visible.astype(jnp.int32)))
        return truth

    def _line_of_sight(self, origin: jax.Array) -> jax.Array:
        """Per light: nothing of the scenery between ``origin`` and it (MJX's ray cast)."""
        targets = jnp.stack(self._lights, axis=-1)

        def clear(target):
            distance, _ = mjx.ray(self.plant.model, self._ray_data, origin, target - origin,
                                  self._ray_groups, True, self._hull_body)
            # In units of the ray's length: below 1, something is hit before the light.
            return jnp.logical_not((distance >= 0.0) & (distance < 1.0 - 1e-6))

        return jax.vmap(clear)(targets)

    def _vehicle(self, info: dict):
        """The episode's simulated vehicle (None: the env's own)."""
        if "plant" not in info:
            return None
        draws = info["plant"]
        return PlantPerturbation.apply(self.plant.hull.params, draws["mass_scale"],
                                       draws["damping_scale"], draws["net_buoyancy_offset"])

    def _observation(self, truth: dict, info: dict, key):
        if self.obs_mode == "state":
            current = info["current"]
            return jnp.stack(self.rules.state_observation(
                truth, tuple(current[k] for k in range(3)), self.ops)).astype(jnp.float32)
        cal = self.calibration
        pixel_key, sensor_key, lamp_key, centroid_key = jax.random.split(key, 4)
        noise = None
        if cal.velocity_noise_std > 0:
            noise = tuple(jax.random.normal(sensor_key, (7,)))
        velocity, attitude = self.rules.sensor_readings(truth, noise, (
            cal.velocity_noise_std, cal.yaw_rate_noise_std, cal.attitude_noise_std))
        visible = truth["visible"]
        pixels = truth["visible_pixels"]
        low, high = self._pixel_bounds
        if cal.pixel_noise_std > 0:  # as the CPU env: noise, masked again, clipped
            pixels = pixels + cal.pixel_noise_std * jax.random.normal(pixel_key, pixels.shape)
            pixels = jnp.clip(jnp.where(visible[:, None], pixels, 0.0), low, high)
        if self.optics is not None:  # the lamps the camera detects through the water
            lights = jnp.stack(self._lights, axis=-1)
            distance = jnp.linalg.norm(lights - jnp.stack(truth["camera_position"]), axis=-1)
            pixels, visible = lamp_detections(
                pixels, visible, distance, info["failed"] | info["occluded"], self.optics,
                cal.intrinsics.fy, jax.random.uniform(lamp_key, (self._n_lights,)),
                jax.random.normal(centroid_key, (self._n_lights, 2)), xp=jnp)
            pixels = jnp.clip(pixels, low, high)
        return {"pixels": pixels.astype(jnp.float32), "visible": visible.astype(jnp.int8),
                "velocity": jnp.stack(velocity).astype(jnp.float32),
                "attitude": jnp.stack(attitude).astype(jnp.float32)}

    def _metrics(self, truth: dict, info: dict, terms: dict) -> dict:
        return {
            "distance_to_entrance": truth["distance"],
            "longitudinal_error": truth["longitudinal"],
            "lateral_error": truth["lateral"],
            "vertical_error": truth["vertical"],
            "heading_error": truth["heading"],
            "lights_visible": truth["n_visible"],
            "is_success": info["success"],
            **{f"reward_{term}": jnp.float32(value) for term, value in terms.items()},
            "episode_success": info["success"],
            "episode_failure": info["failure"],
            "episode_steps": info["steps"],
            "episode_docking_time": info["docking_time"],
            "episode_fov_violation_steps": info["fov_violations"],
            "episode_min_lights_visible": info["min_lights_visible"],
            "episode_control_effort": info["control_effort"],
        }


def failure_reason(code: int, success: bool) -> str:
    """The CPU env's ``failure_reason`` episode metric for a batched episode's failure code."""
    if code:
        return FAILURE_REASONS[code - 1]
    return "" if success else "time_limit"
