"""The docking task's transition, written once for the CPU environment and the batched one.

An episode is :func:`reset` then :func:`step` (the protocol of :mod:`auv_envs.core.task`)
over a typed, immutable :class:`EpisodeState`; the static :class:`DockingParams` say which
task it is. Both take a :class:`~auv_envs.core.ops.Backend`: the arithmetic
(:mod:`auv_envs.core.ops`: Python floats and NumPy on the CPU, ``jax.numpy`` in the
batched env), the episode's random draws (anything with NumPy ``Generator``'s
``uniform``, ``standard_normal`` and ``random``: the env's own generator on the CPU,
:class:`auv_envs.batched.functional.KeyDraws` over a JAX key), and the plant (MuJoCo on
the CPU, MJX batched), a function of its state ``body``: ``place(start, vehicle_draws,
failed) -> body``, ``advance(body, tau, current, vehicle_draws) -> body`` and
``truth(body)`` (the kinematics of :meth:`DockingRules.kinematics` with ``pixels`` (n,
2), ``visible`` (n,), ``visible_pixels`` and ``n_visible``, :func:`truth_with_lights`).
The start draw, the order of the step (thrusters, current, plant, judgement, water,
observation), the reward terms, the termination, the observation, the step's metrics and
the episode summary exist here only; :class:`auv_envs.tasks.docking.env.DockingTask`
(Gymnasium) and :class:`auv_envs.tasks.docking.jax_task.DockingJax` (``jit``/``vmap``) are
shells around them.

On the CPU the draws come in the order the environment has always made them,
so its episodes are the released ones, bit for bit. The plant's state is MuJoCo's
``MjData`` on the CPU (integrated in place by MuJoCo), ``{"qpos", "qvel"}`` arrays in the
batched env.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

from auv_envs.core.camera import add_pixel_noise
from auv_envs.core.ops import Backend
from auv_envs.core.sea import current_components
from auv_envs.core.task import Transition
from auv_envs.core.vehicle import lagged_thrust
from auv_envs.tasks.docking.optics import LampOutages, WaterOptics, detect_lamps
from auv_envs.tasks.docking.rules import DockingRules

#: [OFNMPC] Scenario 2 current speed, m/s.
SCENARIO_CURRENT_SPEED = 0.3
#: The mission's phase metrics (NaN, or None in the CPU env's summary, without a hand-over
#: except ``path_length``).
MISSION_METRICS = ("path_length", "homing_time", "homing_path_length", "handover_range",
                   "handover_cross_track")
#: The observation modes that see the lights' pixels, and those with the navigation
#: sensors (:mod:`auv_envs.tasks.docking.navigation`) in place of the DVL/INS readings.
LIGHT_MODES = ("features", "nav_features")
NAV_MODES = ("nav", "nav_features")
#: The reward's terms, in the order they sum (each reported as ``info["reward_<term>"]``).
REWARD_TERMS = ("progress", "control", "visibility", "success", "failure")
#: The metrics of every step that are numbers (:func:`step_metrics`'s keys).
STEP_METRICS = ("distance_to_entrance", "longitudinal_error", "lateral_error", "vertical_error",
                "heading_error", "lights_visible", "is_success")
#: Start state: heading spread about the line of sight to the entrance (deg) and the
#: surge speed range (m/s), drawn uniformly.
START_HEADING_SPREAD_DEG = 10.0
START_SURGE = (0.0, 0.3)


@dataclasses.dataclass(frozen=True)
class MissionSpec:
    """The whole approach (``auv_envs/DockingMission-v0``): where it starts and when the
    lights take over.

    Attributes:
        start_range: ``(low, high)`` of the start's horizontal distance from the
            entrance, m, drawn uniformly at a bearing uniform around the station.
        start_height: ``(low, high)`` of the start's height above the seabed, m.
        handover_range: the hand-over happens on the first step with at least
            ``min_visible`` lights in view within this distance of the entrance (m): the
            range at which the water lets the camera detect a lamp half the time (the
            environment sets it from its water, ``WaterOptics.detection_range``).
        out_of_bounds: distance from the entrance beyond which the vehicle is out of
            bounds, m.
        behind_radius: passing the entrance plane fails within this distance of the
            entrance only (m): the vehicle may start behind the station and go round.
    """

    start_range: tuple = (100.0, 300.0)
    start_height: tuple = (3.0, 30.0)
    handover_range: float = math.inf
    out_of_bounds: float = 500.0
    behind_radius: float = 3.0


class MissionRecord(NamedTuple):
    """A mission's phases so far (scalars): where the vehicle was after the last step, the
    path it has run, and at the hand-over (the first step with the lights in view within
    ``handover_range``) the time, the path run, the nose's distance from the entrance and
    its distance from the docking axis (NaN before)."""

    x: Any
    y: Any
    z: Any
    path_length: Any
    handed_over: Any
    handover_time: Any
    homing_path_length: Any
    handover_range: Any
    handover_cross_track: Any


@dataclasses.dataclass(frozen=True)
class DockingParams:
    """What makes a docking task this one; fixed for the environment's life.

    Attributes:
        rules: the scene's geometry and the episode rules.
        start_box: ``(x, y, z)`` ranges of the start position, m.
        light_positions: ``(n, 3)`` light positions in the world (NumPy).
        obs_mode: ``"state"``, ``"features"``, ``"nav"`` or ``"nav_features"`` (the
            rendered ``image`` mode is the CPU shell's).
        scenario: ``"mismatch"`` or ``"current"``.
        current_direction: the scenario current's direction, deg; None: drawn.
        disturbances: the level's :class:`~auv_envs.tasks.docking.env.DockingDisturbances`.
        optics: the level's water (None: clear water, every lamp seen).
        thrust_limits: (X, Y, Z, N) at full command.
        thruster_gain: :func:`~auv_envs.core.vehicle.thruster_lag_gain` (1: no lag).
        noise: standard deviations of the pixel, velocity, yaw-rate and attitude noise.
        pixel_bounds: ``(low, high)`` of the ``features`` pixels (NumPy), or None.
        focal_px: the camera's vertical focal length, pixels.
        max_episode_steps: steps to the time limit.
        navigation: the navigation sensors in the scene
            (:class:`~auv_envs.tasks.docking.navigation.Navigation`) in the ``nav`` modes,
            else None.
        mission: the whole approach's :class:`MissionSpec` (``DockingMission``), else None.
        lamp_detection: the lights' observation through the water as one compiled call
            (:class:`~auv_envs.tasks.docking.optics.CompiledLampDetection`: the CPU's
            ``sensors="compiled"``), else None (NumPy's, in :func:`observe`).
    """

    rules: DockingRules
    start_box: tuple
    light_positions: Any
    obs_mode: str
    scenario: str
    current_direction: float | None
    disturbances: Any
    optics: WaterOptics | None
    thrust_limits: tuple
    thruster_gain: float
    noise: tuple
    pixel_bounds: tuple | None
    focal_px: float
    max_episode_steps: int
    navigation: Any = None
    mission: MissionSpec | None = None
    lamp_detection: Any = None

    @property
    def dt(self) -> float:
        return self.rules.control_period

    @property
    def n_lights(self) -> int:
        return len(self.rules.lights)


class EpisodeState(NamedTuple):
    """Everything an episode changes besides the plant; immutable (a JAX pytree as is).

    Numbers are Python scalars and tuples on the CPU and arrays in the batched
    env. ``failure`` is the index + 1 of the first failure in
    :data:`~auv_envs.tasks.docking.rules.FAILURE_REASONS` (0: none),
    ``docking_time`` NaN until docked; ``thrust`` is None without a thruster
    lag, ``plant`` (the simulated vehicle's draws: mass factor, 12 damping
    factors, net-buoyancy offset) without a plant perturbation, ``failed`` and
    ``occluded`` (per lamp) without ``optics``, ``nav`` (the navigation sensors'
    :class:`~auv_envs.tasks.docking.navigation.NavState`) outside the ``nav`` modes.
    """

    steps: Any
    lost_time: Any
    prev_potential: Any
    success: Any
    failure: Any
    docking_time: Any
    fov_violations: Any
    control_effort: Any
    min_lights_visible: Any
    current_polar: Any
    current_mean: Any
    current: Any
    thrust: Any = None
    plant: Any = None
    failed: Any = None
    occluded: Any = None
    nav: Any = None
    mission: Any = None

    @property
    def out(self):
        """Per lamp: failed or hidden now (``optics`` only)."""
        return self.failed | self.occluded


class Start(NamedTuple):
    """An episode's start: pose and surge, and the current (speed m/s, direction rad) now
    and its mean."""

    x: Any
    y: Any
    z: Any
    yaw: Any
    surge: Any
    current_polar: tuple
    current_mean: tuple


class Assessment(NamedTuple):
    """A step's judgement: reward terms, whether it ended, and the violations."""

    terms: dict
    terminated: Any
    fov_violation: Any
    behind_entrance: Any
    seabed: Any


# ------------------------------------------------------------------ reset
def draw_start(params: DockingParams, draws, ops) -> Start:
    """The start pose (uniform in the layout's box, heading towards the entrance within
    :data:`START_HEADING_SPREAD_DEG`, surge in :data:`START_SURGE`; with a ``mission``, at
    a distance, bearing and height of :class:`MissionSpec` and any heading) and the
    current."""
    mission = params.mission
    if mission is None:
        (x0, x1), (y0, y1), (z0, z1) = params.start_box
        x = draws.uniform(x0, x1)
        y = draws.uniform(y0, y1)
        z = draws.uniform(z0, z1)
        yaw = ops.atan2(-y, -x) + draws.uniform(-1.0, 1.0) * math.radians(
            START_HEADING_SPREAD_DEG)
    else:
        distance = draws.uniform(*mission.start_range)
        bearing = draws.uniform(-math.pi, math.pi)
        x, y = distance * ops.cos(bearing), distance * ops.sin(bearing)
        z = params.rules.seabed_z + draws.uniform(*mission.start_height)
        yaw = draws.uniform(-math.pi, math.pi)
    surge = draws.uniform(*START_SURGE)
    varying = params.disturbances.current
    if params.scenario == "current" or varying.active:
        speed = SCENARIO_CURRENT_SPEED if params.scenario == "current" else 0.0
        direction = (math.radians(params.current_direction)
                     if params.current_direction is not None
                     else draws.uniform(0.0, 2.0 * math.pi))
        polar = (speed, direction)
        if varying.active:
            polar = varying.start(speed, direction, draws, ops)
        mean = (speed, direction)
    else:
        polar = mean = (0.0, 0.0)
    return Start(x, y, z, yaw, surge, polar, mean)


def draw_vehicle(params: DockingParams, draws) -> tuple | None:
    """The simulated vehicle's draws ``(mass factor, 12 damping factors, net-buoyancy
    offset N)`` of :class:`~auv_envs.core.vehicle.PlantPerturbation`; None when inactive."""
    return params.disturbances.plant.draw_factors(draws)


def reset(params: DockingParams, backend: Backend, start: Start | None = None,
          vehicle: tuple | None = None) -> Transition:
    """A new episode (:class:`~auv_envs.core.task.Transition`, no judgement).

    ``start`` and ``vehicle`` (:func:`draw_vehicle`'s draws) given are used
    instead of drawn (the equivalence tests start both envs alike this way).
    """
    ops, draws, plant = backend
    if start is None:
        start = draw_start(params, draws, ops)
    if vehicle is None:
        vehicle = draw_vehicle(params, draws)
    failed = occluded = None
    if params.optics is not None:
        failed, occluded = LampOutages.draw_start(params.optics, params.n_lights, draws)
    body = plant.place(start, vehicle, failed)
    truth = plant.truth(body)
    real, integer = ops.real, ops.integer
    state = EpisodeState(
        steps=integer(0), lost_time=real(0.0), prev_potential=params.rules.potential(truth),
        success=ops.boolean(False), failure=integer(0), docking_time=real(math.nan),
        fov_violations=integer(0), control_effort=real(0.0),
        min_lights_visible=truth["n_visible"], current_polar=ops.vector(start.current_polar),
        current_mean=ops.vector(start.current_mean),
        current=ops.vector(current_components(*start.current_polar, ops)),
        thrust=ops.vector((0.0,) * 4) if params.thruster_gain != 1.0 else None,
        plant=vehicle, failed=failed, occluded=occluded)
    if params.navigation is not None:  # drawn last: the other modes' draws are unchanged
        state = state._replace(nav=params.navigation.start(truth, draws, ops))
    if params.mission is not None:
        nan = ops.real(math.nan)
        x, y, z = truth["position"]
        state = state._replace(mission=MissionRecord(
            x=x, y=y, z=z, path_length=ops.real(0.0), handed_over=ops.boolean(False),
            handover_time=nan, homing_path_length=nan, handover_range=nan,
            handover_cross_track=nan))
    return Transition(body, state, truth, observe(params, state, truth, backend))


# ------------------------------------------------------------------ step
def step(params: DockingParams, body, state: EpisodeState, action,
         backend: Backend) -> Transition:
    """One control period of the plant at ``body`` under ``action``, the normalised
    ``(X, Y, Z, N)`` command as 4 scalars already checked
    (:func:`auv_envs.core.env.clip_actions`); the judgement is an :class:`Assessment`."""
    ops, draws, plant = backend
    ax, ay, az, an = action
    tx, ty, tz, tn = params.thrust_limits
    force = (ax * tx, ay * ty, az * tz, an * tn)
    thrust = state.thrust
    if thrust is not None:  # first-order thrusters: the force moves towards the command
        force = tuple(lagged_thrust(thrust[k], force[k], params.thruster_gain)
                      for k in range(4))
        thrust = ops.vector(force)
    polar, current = state.current_polar, state.current
    varying = params.disturbances.current
    if varying.active:
        polar = varying.advance(polar[0], polar[1], state.current_mean[0],
                                state.current_mean[1], params.dt, draws, ops)
        current = ops.vector(current_components(*polar, ops))
        polar = ops.vector(polar)
    x, y, z, n = force
    body = plant.advance(body, (x, y, z, 0.0, 0.0, n), current, state.plant)
    truth = plant.truth(body)
    steps = state.steps + 1
    changes = {}  # the sensors' and the mission's parts, drawn in this order (assess draws none)
    lamps = params.lamp_detection
    if lamps is not None:  # occluders pass (compiled sensors: in Python floats)
        changes["occluded"] = lamps.occlusions(state.occluded, draws)
    elif params.optics is not None and params.obs_mode in LIGHT_MODES:
        changes["occluded"] = LampOutages.occlusions_drawn(state.occluded, params.optics,
                                                           params.dt, draws, ops.xp)
    if params.navigation is not None:
        changes["nav"] = params.navigation.advance(state.nav, truth, steps * params.dt, draws,
                                                   ops)
    if params.mission is not None:
        changes["mission"] = track_mission(params, state.mission, steps, truth, ops)
    state, judged = assess(params, state, truth, action, ops, steps=steps,
                           control_effort=state.control_effort
                           + (x * x + y * y + z * z + n * n) * params.dt,
                           thrust=thrust, current_polar=polar, current=current, **changes)
    return Transition(body, state, truth, observe(params, state, truth, backend), judged)


def assess(params: DockingParams, state: EpisodeState, truth: dict, action, ops, steps,
           **changes):
    """The step's reward terms and end, and the episode's record updated by them and by
    ``steps`` (the step count after this step) and ``changes`` (other fields the step set)."""
    rules = params.rules
    n_visible = truth["n_visible"]
    fov_violation = n_visible < rules.min_visible
    lost_time = rules.lights_lost_time(state.lost_time, fov_violation, ops)
    docked = rules.docked(truth)
    flags = rules.failures(truth, docked, lost_time, ops)
    code = ops.integer(rules.failure_index(flags, ops))
    failed = code > 0
    potential = rules.potential(truth)
    terms = rules.reward_terms(state.prev_potential, potential, action, fov_violation, docked,
                               failed, ops)
    state = state._replace(
        steps=steps, lost_time=lost_time, prev_potential=potential,
        success=state.success | docked, failure=code,
        docking_time=ops.where(docked, steps * params.dt, state.docking_time),
        fov_violations=state.fov_violations + fov_violation,
        min_lights_visible=ops.minimum(state.min_lights_visible, n_visible), **changes)
    return state, Assessment(terms, docked | failed, fov_violation, flags[0], flags[1])


def track_mission(params: DockingParams, record: MissionRecord, steps, truth: dict,
                  ops) -> MissionRecord:
    """The mission's ``record`` after a step (``steps`` the step count after it, ``truth``
    its truth)."""
    x, y, z = truth["position"]
    dx, dy, dz = x - record.x, y - record.y, z - record.z
    path = record.path_length + ops.sqrt(dx * dx + dy * dy + dz * dz)
    near = ((truth["n_visible"] >= params.rules.min_visible)
            & (truth["distance"] <= params.mission.handover_range))
    first = near & ops.logical_not(record.handed_over)
    lateral, vertical = truth["lateral"], truth["vertical"]
    return MissionRecord(
        x=x, y=y, z=z, path_length=path, handed_over=record.handed_over | near,
        handover_time=ops.where(first, steps * params.dt, record.handover_time),
        homing_path_length=ops.where(first, path, record.homing_path_length),
        handover_range=ops.where(first, truth["distance"], record.handover_range),
        handover_cross_track=ops.where(first, ops.sqrt(lateral * lateral + vertical * vertical),
                                       record.handover_cross_track))


# ------------------------------------------------------------------ what is seen
def truth_with_lights(truth: dict, pixels, visible, ops, visible_pixels=None,
                      n_visible=None) -> dict:
    """``truth`` with the lights' ``pixels`` (n, 2; NaN behind the camera) and ``visible``
    (n,) added, ``visible_pixels`` (zero, not NaN, where not visible) and ``n_visible``
    (each computed here unless given: a compiled truth computes them in its call)."""
    if visible_pixels is None:
        visible_pixels = ops.xp.where(visible[:, None], pixels, 0.0)
    truth.update(pixels=pixels, visible=visible, visible_pixels=visible_pixels,
                 n_visible=ops.count(visible) if n_visible is None else n_visible)
    return truth


def observe(params: DockingParams, state: EpisodeState, truth: dict, backend: Backend):
    """The observation of ``params.obs_mode`` (see the environment's docstring); in
    ``image`` mode its sensors (the CPU shell adds the camera's image)."""
    ops, draws, _ = backend
    xp = ops.xp
    if params.obs_mode == "state":
        current = state.current
        return xp.asarray(params.rules.state_observation(
            truth, (current[0], current[1], current[2]), ops), dtype=xp.float32)
    pixel_std, velocity_std, yaw_rate_std, attitude_std = params.noise
    lamps = params.lamp_detection
    if params.navigation is not None:  # read in the step (the sensors keep a state)
        sensors = params.navigation.observation(state.nav, state.steps * params.dt, ops)
    elif lamps is not None and lamps.reads:  # the readings made in the lamps' compiled call
        return lamps(truth, state.out, draws)
    else:
        # One draw of 7 standard normals, scaled: the numbers of normal(0, s_v, 3),
        # normal(0, s_r), normal(0, s_a, 3) (Generator.normal is loc + scale *
        # standard_normal).
        noise = ops.unpack(draws.standard_normal(7)) if velocity_std > 0 else None
        velocity, attitude = params.rules.sensor_readings(
            truth, noise, (velocity_std, yaw_rate_std, attitude_std))
        sensors = {"velocity": xp.asarray(velocity, dtype=xp.float32),
                   "attitude": xp.asarray(attitude, dtype=xp.float32)}
    if params.obs_mode not in LIGHT_MODES:
        return sensors
    if lamps is not None:
        return {**lamps(truth, state.out, draws), **sensors}
    visible = truth["visible"]
    pixels = truth["visible_pixels"]
    if pixel_std > 0:  # noise on the masked true pixels, masked again, clipped
        pixels = add_pixel_noise(pixels, pixel_std, draws)
        pixels = xp.clip(xp.where(visible[:, None], pixels, 0.0), *params.pixel_bounds)
    if params.optics is not None:  # the lamps the camera detects through the water
        distance = xp.linalg.norm(params.light_positions - xp.asarray(truth["camera_position"]),
                                  axis=-1)
        pixels, visible = detect_lamps(pixels, visible, distance, state, params.optics,
                                       params.focal_px, draws, xp)
        pixels = xp.clip(pixels, *params.pixel_bounds)
    return {"pixels": pixels.astype(xp.float32), "visible": visible.astype(xp.int8), **sensors}


# ------------------------------------------------------------------ the record
def step_metrics(truth: dict, state: EpisodeState) -> dict:
    """The step's metrics that are numbers (:data:`STEP_METRICS`)."""
    return {
        "distance_to_entrance": truth["distance"],
        "longitudinal_error": truth["longitudinal"],
        "lateral_error": truth["lateral"],
        "vertical_error": truth["vertical"],
        "heading_error": truth["heading"],
        "lights_visible": truth["n_visible"],
        "is_success": state.success,
    }


def summary(state: EpisodeState, truth: dict) -> dict:
    """The episode's summary as numbers: ``failure`` the code of :class:`EpisodeState`,
    ``docking_time`` NaN when it did not dock (the shells name and format them); with a
    mission, its phases too (:data:`MISSION_METRICS`, NaN without a hand-over)."""
    mission = {}
    record = state.mission
    if record is not None:
        mission = dict(zip(MISSION_METRICS, (
            record.path_length, record.handover_time, record.homing_path_length,
            record.handover_range, record.handover_cross_track), strict=True))
    return {
        "success": state.success,
        "failure": state.failure,
        "docking_time": state.docking_time,
        "steps": state.steps,
        "final_distance": truth["distance"],
        "final_lateral_error": truth["lateral"],
        "final_vertical_error": truth["vertical"],
        "final_heading_error_deg": truth["heading"] * (180.0 / math.pi),
        "fov_violation_steps": state.fov_violations,
        "min_lights_visible": state.min_lights_visible,
        "control_effort": state.control_effort,
        **mission,
    }
