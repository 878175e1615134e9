"""The docking family's configuration and parameters, built without an environment.

The docking family's task, in the manner of Gymnasium's ``FuncEnv`` and MuJoCo
Playground's ``MjxEnv``: :func:`default_config` gives an id's configuration (a frozen
:class:`DockingConfig`, changed with :meth:`DockingConfig.replace`), and :func:`params`
builds from it everything the configuration fixes (a frozen :class:`DockingSetup`: the
composed MuJoCo model, what an agent may know, the rules, the transition's parameters and
the spaces), checking every value. The task on the CPU
(:class:`auv_envs.tasks.docking.env.DockingTask`, which the one Gymnasium env runs) and
the task on JAX (:class:`auv_envs.tasks.docking.jax_task.DockingJax`) are both built from
a setup.

The difficulty levels' presets (``PAPER_DISTURBANCES`` and after) are here too, each
with its units, sources and calibration.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces

from auv_envs.core import difficulty as levels
from auv_envs.core.camera import CameraExtrinsics, CameraIntrinsics, pixel_space
from auv_envs.core.env import check_choice, check_image_size, check_positive_int
from auv_envs.core.hydrodynamics import NominalModel
from auv_envs.core.sea import GaussMarkovCurrent
from auv_envs.core.task import Config, Setup
from auv_envs.core.vehicle import (
    PlantPerturbation,
    VehicleParams,
    hovering_auv,
    thruster_lag_gain,
    with_damping_mismatch,
)
from auv_envs.tasks.docking import transition
from auv_envs.tasks.docking.navigation import (
    AHRS,
    DVL,
    SENSOR_CODES,
    USBL,
    USBL_ACOUSTICS,
    DepthSensor,
    Navigation,
    NavigationSensors,
)
from auv_envs.tasks.docking.optics import WaterOptics
from auv_envs.tasks.docking.rules import DockingRules, DockingTolerances
from auv_envs.tasks.docking.station import (
    LAMP_ARRAY,
    SIX_LIGHTS,
    DockingPhysics,
    StationLayout,
    compose_docking_model,
)
from auv_envs.tasks.docking.transition import SCENARIO_CURRENT_SPEED

OBS_MODES = ("state", "features", "image", "nav", "nav_features")
SCENARIOS = ("mismatch", "current")

#: Default nominal-model damping scale (surge, sway, heave, roll, pitch, yaw):
#: the controller's D diagonals differ from the plant's as in [OFNMPC]'s
#: comparison of D between plant and prediction model.
DEFAULT_DAMPING_MISMATCH = (0.7, 1.4, 1.3, 1.0, 1.0, 0.6)

#: [OFNMPC] Scenario 2 noise: 5 px on the light pixels, 0.02 m/s on velocities.
SCENARIO_PIXEL_NOISE = 5.0
SCENARIO_VELOCITY_NOISE = 0.02
#: Yaw-rate and attitude noise in the noisy scenario (INS grade; our choice).
SCENARIO_YAW_RATE_NOISE = 0.005
SCENARIO_ATTITUDE_NOISE = math.radians(0.2)

#: Seconds per env step. The plant takes ``physics_substeps`` (default 1)
#: classical RK4 steps per control period, the hull wrench re-evaluated at every
#: stage; ``docs/physics.md`` gives its error against an independent reference.
CONTROL_PERIOD = 0.1
#: Plant integrators: ``"rk4"`` (v1) and ``"euler"`` (MuJoCo's semi-implicit
#: Euler, the v0 plant: first order, centimetres and degrees from the converged
#: solution after 10 s at its 0.05 s step; ``docs/physics.md``).
INTEGRATORS = {"rk4": mujoco.mjtIntegrator.mjINT_RK4, "euler": mujoco.mjtIntegrator.mjINT_EULER}
#: ``plant``: the hull compiled away from the scenery (``-v2``), or MuJoCo's staged
#: integrator throughout (``-v1``, ``-v0``).
PLANTS = ("compiled", "mujoco")

@dataclasses.dataclass(frozen=True)
class DockingDisturbances:
    """Physical disturbances of the docking plant beyond the scenario's (default: none).

    Every random draw comes from the episode's generator, and none is made for
    a part that is switched off, so the default keeps the environment
    bit-identical to its release.

    Attributes:
        current: the current's speed and direction vary as first-order
            Gauss–Markov processes about the scenario's current (0.3 m/s in
            ``current``; none in ``mismatch``, where the mean direction is
            drawn uniformly when ``current_direction`` is None):
            :class:`auv_envs.core.sea.GaussMarkovCurrent`, advanced once per
            control period.
        plant: per-episode deviation of the simulated vehicle's mass,
            inertia, damping and net buoyancy from the nominal values:
            :class:`auv_envs.core.vehicle.PlantPerturbation`.
        thruster_time_constant: first-order lag of the thrusters, s (0: the
            commanded force acts at once):
            :func:`auv_envs.core.vehicle.thruster_lag_gain`.
    """

    current: GaussMarkovCurrent = GaussMarkovCurrent()
    plant: PlantPerturbation = PlantPerturbation()
    thruster_time_constant: float = 0.0

    def __post_init__(self):
        if not isinstance(self.current, GaussMarkovCurrent):
            raise TypeError("current must be a GaussMarkovCurrent")
        if not isinstance(self.plant, PlantPerturbation):
            raise TypeError("plant must be a PlantPerturbation")
        thruster_lag_gain(self.thruster_time_constant, CONTROL_PERIOD)  # validates


# ------------------------------------------------------------------ difficulty levels
#: ``paper`` level, plant (both layouts; ``docs/difficulty.md``).
#: Calibrated on [OFNMPC] Scenario 2 (Table 4, Figs. 15-16: OFNMPC-EKF docks in 5 of 5 current
#: directions, OFNMPC-MHE in 3 of 5) with the band EKF >= 80 %, MHE >= 60 % of episodes.
#:
#: * ``current``: Gauss–Markov current about the scenario's 0.3 m/s (Fossen 2011, ch. 8):
#:   ``speed_std`` 0.1 m/s, ``direction_std_deg`` 30 deg, ``time_constant`` 30 s (our choice,
#:   calibrated on Table 4), ``max_speed`` 0.3 m/s ([OFNMPC] §4: "the maximum current was
#:   maintained at 0.3 m/s").
#: * ``plant``: ``damping`` 0.3 (relative half-range of each damping coefficient: [OFNMPC]'s
#:   comparison of the D diagonals of plant and prediction model differs by tens of per cent),
#:   ``mass`` 0.1 (relative; our choice), ``net_buoyancy`` 5 N (half the 10 N positive
#:   buoyancy whose estimate [OFNMPC] shows in Fig. 10; trim drift, our choice).
#: * ``thruster_time_constant`` 0.5 s (first-order thruster lag of Yoerger, Cooke and
#:   Slotine 1990; our choice of value for a small electric thruster).
PAPER_DISTURBANCES = DockingDisturbances(
    current=GaussMarkovCurrent(speed_std=0.1, direction_std_deg=30.0, time_constant=30.0,
                               max_speed=SCENARIO_CURRENT_SPEED),
    plant=PlantPerturbation(mass=0.1, damping=0.3, net_buoyancy=5.0),
    thruster_time_constant=0.5,
)
#: ``paper`` level, water of ``DockingStation`` ([OFNMPC], a simulated sea docking): Jerlov
#: coastal type 1C (Jerlov 1976; ``K_d`` per channel), every other optics value the
#: :class:`WaterOptics` default (its docstring gives their sources). Calibrated with the
#: plant on [OFNMPC] Table 4 as above.
PAPER_OPTICS = WaterOptics.jerlov("1C")
#: ``paper`` level, water of ``LampArrayDocking`` ([LAMP]: a laboratory tank, §2.2.4, with
#: suspended matter, §2.2): Jerlov 5C (turbid coastal) with lamps 200 times the sensor's full
#: scale (``lamp_radiance``, the exposure set for the dim water; our choice) and a narrow glow
#: (``glow_angle`` 0.02 rad per unit scattering depth: a mean forward-scattering angle of
#: 0.04 rad, Wells 1973): the saturated halos that make [LAMP]'s lamp blobs large.
#: Calibrated on [LAMP] Table 4 (PRCN 99.76 %, MOTA 84.65 %, MOTP 13.24 px) and Fig. 11,
#: to the band MOTA 75-95 %, PRCN >= 95 %, MOTP >= 3 px (what the lamp tracker measures:
#: ``docs/difficulty.md``).
PAPER_LAMP_ARRAY_OPTICS = WaterOptics.jerlov("5C", lamp_radiance=200.0, glow_angle=0.02)

#: ``hard`` level, plant (both layouts): beyond [OFNMPC] Scenario 2. ``current``: 0.1 m/s
#: speed and 30 deg direction standard deviation, 30 s correlation time (Fossen 2011, ch. 8),
#: up to 0.45 m/s (1.5 times [OFNMPC]'s maximum); ``plant``: damping +-40 %, mass +-10 %,
#: net buoyancy +-5 N; thrusters lag 0.7 s. Our choices, checked against the headroom rule
#: (``docs/difficulty.md``): the privileged ``ofnmpc-state`` docks in >= 90 % of episodes.
HARD_DISTURBANCES = DockingDisturbances(
    current=GaussMarkovCurrent(speed_std=0.1, direction_std_deg=30.0, time_constant=30.0,
                               max_speed=0.45),
    plant=PlantPerturbation(mass=0.1, damping=0.4, net_buoyancy=5.0),
    thruster_time_constant=0.7,
)
#: ``hard`` level, water (both layouts): Jerlov 7C (turbid coastal; Jerlov 1976), a lamp dark
#: for the episode with probability 0.1 (five times the default 0.02), occluders passing a
#: lamp at 0.05 /s for 3 s on average (hidden about 13 % of the time). Our choices, checked
#: against the headroom rule (``docs/difficulty.md``, which has the measurements).
HARD_OPTICS = WaterOptics.jerlov("7C", lamp_failure_probability=0.1, occlusion_rate=0.05,
                                 occlusion_duration=3.0)

#: ``paper`` level, navigation sensors (the ``nav`` modes; ``docs/navigation.md`` gives each
#: figure's source): the defaults of :mod:`auv_envs.tasks.docking.navigation`, from data sheets
#: (a DVL's 1 % long-term accuracy and 0.05-50 m bottom lock, [OFNMPC]'s 0.02 m/s velocity
#: noise; an MTi-30-class AHRS, 0.5 deg roll/pitch and 1 deg heading, an MTi-1-class gyro,
#: 0.007 deg/s/sqrt(Hz) and 10 deg/h bias instability; a quartz depth sensor, 0.01 % of a
#: 140 m full scale, 1 mm resolution; a USBL fix every second, 0.5 us element timing, a
#: 3 m/s sound-speed error) with faults at rates of our choice: 2 % of DVL pings lost, 5 %
#: of USBL fixes from a mirror path, 2 % spurious.
PAPER_NAVIGATION = NavigationSensors(
    dvl=DVL(dropout=0.02), usbl=USBL(shadowing=0.05, outlier_rate=0.02))
#: ``easy`` level (``navigation=None``), navigation sensors: the data-sheet noise of
#: ``paper`` with no faults (no lost ping, mirror-path or spurious fix, no sound-speed
#: error).
EASY_NAVIGATION = NavigationSensors(usbl=USBL(acoustics=dataclasses.replace(
    USBL_ACOUSTICS, sound_speed_error_std=0.0)))
#: ``hard`` level, navigation sensors: a lower grade of each (our choices): DVL 0.05 m/s
#: noise, 2 % scale error, 10 % of pings lost; AHRS 1 deg roll/pitch, 2 deg heading, three
#: times the gyro noise and bias, and the heading off the station's frame by an episode's
#: deviation of 8 deg RMS (the compass near the station's steel, the station's surveyed
#: heading; calibrated with the docking mission's headroom rule, ``docs/mission.md``);
#: depth 0.05 m; a USBL fix every 2 s with 1.5 us element timing, 15 % mirror-path and 5 %
#: spurious fixes and a 5 m/s sound-speed error.
HARD_NAVIGATION = NavigationSensors(
    dvl=DVL(noise_std=0.05, scale_std=0.02, dropout=0.1),
    ahrs=AHRS(roll_pitch_std=math.radians(1.0), heading_std=math.radians(2.0),
              rate_noise_density=math.radians(0.021), bias_instability=math.radians(30.0) / 3600,
              heading_bias_std=math.radians(8.0)),
    depth=DepthSensor(noise_std=0.05),
    usbl=USBL(period=2.0, shadowing=0.15, outlier_rate=0.05, acoustics=dataclasses.replace(
        USBL_ACOUSTICS, timing_floor=1.5e-6, sound_speed_error_std=5.0)))


@dataclasses.dataclass(frozen=True)
class DockingCalibration:
    """What a classical agent may know (read-only; arrays are not writeable).

    Attributes:
        intrinsics: camera intrinsics at the observation image size.
        extrinsics: camera pose in the body frame (OpenCV camera axes).
        light_positions: (n, 3) light positions in the DS (= world) frame.
        light_labels: names of the lights in observation order.
        nominal_params: parameters of the nominal (controller) model.
        nominal_model: 4-DOF prediction model built from ``nominal_params``.
        control_period: seconds per env step.
        thrust_limits: (X, Y, Z, N) limits that scale the normalised action.
        nose_offset: CG-to-nose distance along body x, m.
        target_position: CG position at the docking point (nose at the
            entrance centre, heading 0), DS frame.
        tolerances: success tolerances.
        seabed_z: seabed height in the DS frame, m.
        pixel_noise_std, velocity_noise_std, yaw_rate_noise_std,
        attitude_noise_std: sensor noise of the scenario.
        disturbances: the plant's disturbance models and their parameters
            (:class:`DockingDisturbances`; each episode's draws are in the
            reset ``info``).
        optics: the water between camera and lamps and the camera's sensor
            (:class:`auv_envs.tasks.docking.optics.WaterOptics`), None for clear water.
    """

    intrinsics: CameraIntrinsics
    extrinsics: CameraExtrinsics
    light_positions: np.ndarray
    light_labels: tuple[str, ...]
    nominal_params: VehicleParams
    nominal_model: NominalModel
    control_period: float
    thrust_limits: tuple[float, float, float, float]
    nose_offset: float
    target_position: np.ndarray
    tolerances: DockingTolerances
    seabed_z: float
    pixel_noise_std: float
    velocity_noise_std: float
    yaw_rate_noise_std: float
    attitude_noise_std: float
    disturbances: DockingDisturbances = DockingDisturbances()
    optics: WaterOptics | None = None




#: ``difficulty`` levels of ``DockingStation`` and of the mission
#: (:mod:`auv_envs.core.difficulty`): the plant's disturbances, the water's optics and the
#: navigation sensors (see :data:`PAPER_DISTURBANCES` and the constants after it for each
#: value's unit, source and calibration).
STATION_PRESETS = {
    "easy": {},
    "paper": {"disturbances": PAPER_DISTURBANCES, "optics": PAPER_OPTICS,
              "navigation": PAPER_NAVIGATION},
    "hard": {"disturbances": HARD_DISTURBANCES, "optics": HARD_OPTICS,
             "navigation": HARD_NAVIGATION},
}
#: ``difficulty`` levels of ``LampArrayDocking``: as :data:`STATION_PRESETS`, with the
#: laboratory water of [LAMP] at ``paper`` (:data:`PAPER_LAMP_ARRAY_OPTICS`).
LAMP_ARRAY_PRESETS = {
    **STATION_PRESETS,
    "paper": {**STATION_PRESETS["paper"], "optics": PAPER_LAMP_ARRAY_OPTICS},
}
#: The station layouts: ``"six_lights"`` ([OFNMPC]) and ``"lamp_array"`` ([LAMP]).
LAYOUTS = {"six_lights": SIX_LIGHTS, "lamp_array": LAMP_ARRAY}
#: The mission's water at ``easy`` (``optics=None``): Jerlov's clearest oceanic type IA
#: (Jerlov 1976), where a lamp in view is detected half the time at about 30 m.
CLEAR_OCEAN = WaterOptics.jerlov("IA")


@dataclasses.dataclass(frozen=True)
class DockingConfig(Config):
    """Everything that fixes a docking task: the arguments of ``gym.make`` for the
    docking ids (the environment's docstring gives each one's meaning, type and
    default) without the rendering ones, and the variant; changed by ``replace``
    (``TypeError`` for an unknown field).

    Attributes:
        layout: the station: ``"six_lights"`` (``DockingStation``, [OFNMPC]) or
            ``"lamp_array"`` (``LampArrayDocking``, [LAMP]).
        mission: the whole approach from 100-300 m (``DockingMission``): the mission's
            start and rules, the station's levels with clear ocean water at ``easy``;
            ``lights_lost_timeout`` does not apply.
        (the others): as the environment's arguments.
    """

    obs_mode: str = "state"
    scenario: str = "mismatch"
    current_direction: float | None = None
    image_size: tuple = (640, 480)
    model_mismatch: bool = True
    damping_mismatch: tuple = DEFAULT_DAMPING_MISMATCH
    tolerances: DockingTolerances | None = None
    time_limit: float = 100.0
    lights_lost_timeout: float = 5.0
    min_visible_lights: int = 3
    integrator: str = "rk4"
    physics_substeps: int = 1
    plant: str = "compiled"
    sensors: str = "numpy"
    disturbances: DockingDisturbances | None = None
    optics: WaterOptics | None = None
    navigation: NavigationSensors | None = None
    difficulty: str = levels.DEFAULT_LEVEL
    layout: str = "six_lights"
    mission: bool = False

    @property
    def presets(self) -> dict:
        """The ``difficulty`` levels that apply (the mission's are the station's)."""
        return LAMP_ARRAY_PRESETS if self.layout == "lamp_array" and not self.mission \
            else STATION_PRESETS

    @property
    def default_optics(self) -> WaterOptics | None:
        """The water when ``optics`` is None and the level sets none (None: clear water,
        every lamp seen at any range; the mission: :data:`CLEAR_OCEAN`)."""
        return CLEAR_OCEAN if self.mission else None


#: Each current docking id's configuration (:func:`default_config`).
_DEFAULTS = {
    "auv_envs/DockingStation-v2": DockingConfig(),
    "auv_envs/LampArrayDocking-v2": DockingConfig(layout="lamp_array"),
    "auv_envs/DockingMission-v0": DockingConfig(time_limit=600.0, mission=True),
}


def default_config(env_id: str = "auv_envs/DockingStation-v2") -> DockingConfig:
    """The configuration ``gym.make(env_id)`` builds (a superseded id's: its keywords
    applied; :data:`auv_envs.families.FAMILIES`).

    Raises:
        ValueError: ``env_id`` is not a docking id.
    """
    from auv_envs.families import family

    entry = family(env_id)
    if entry.env_id not in _DEFAULTS:
        raise ValueError(f"{env_id!r} is not a docking id: {tuple(_DEFAULTS)}")
    return _DEFAULTS[entry.env_id].replace(**entry.previous.get(env_id, {}))


def config_of(env_id: str, **arguments) -> DockingConfig:
    """The configuration of ``gym.make(env_id, **arguments)`` (without the rendering
    arguments): :func:`default_config` with ``arguments`` (the id's own: ``layout`` for the
    mission alone, ``lights_lost_timeout`` for the docking ids alone).

    Raises:
        TypeError: an argument the id does not take.
    """
    config = default_config(env_id)
    fixed = {"mission"} | ({"lights_lost_timeout"} if config.mission else {"layout"})
    refused = sorted(fixed & set(arguments))
    if refused:
        raise TypeError(f"{env_id} does not take {', '.join(refused)}")
    return config.replace(**arguments)


@dataclasses.dataclass(frozen=True)
class DockingSetup(Setup):
    """What a :class:`DockingConfig` fixes (:func:`params`), for the Gymnasium environment
    and the task on JAX alike.

    Attributes:
        config: the configuration it was built from.
        levels: the configuration's ``disturbances``, ``optics`` and ``navigation`` with
            its ``difficulty`` level's presets filled in (``optics`` None: clear water;
            ``navigation`` always set, used in the ``nav`` modes).
        layout: the station (:class:`~auv_envs.tasks.docking.station.StationLayout`).
        mission: the whole approach's start and phases, None for the docking ids.
        vehicle: the simulated vehicle's nominal parameters.
        model_source: the composed MJCF (:class:`~auv_envs.core.assets.MJCF`).
        model: its compiled MuJoCo model, the integrator and timestep set: a Gymnasium
            environment built from this setup simulates (and changes) this very model.
        calibration: what an agent may know (:class:`DockingCalibration`).
        rules: the task's geometry and rules
            (:class:`~auv_envs.tasks.docking.rules.DockingRules`).
        params: the transition's parameters
            (:class:`~auv_envs.tasks.docking.transition.DockingParams`).
        observation_space, action_space: the spaces.
        dt: the control period, s.
        max_episode_steps: steps of an episode that runs to ``time_limit``.
    """

    levels: dict
    layout: StationLayout
    mission: Any
    vehicle: VehicleParams
    rules: DockingRules

    @property
    def navigation(self) -> NavigationSensors:
        """The navigation sensors (the level's; used in the ``nav`` modes)."""
        return self.levels["navigation"]

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` of the camera's image."""
        return self.calibration.intrinsics.width, self.calibration.intrinsics.height


def params(config: DockingConfig) -> DockingSetup:
    """Everything ``config`` fixes, each value checked (module docstring).

    Raises:
        TypeError: a value of the wrong type (``disturbances``, ``optics``,
            ``navigation``).
        ValueError: a value out of its range or not one of its choices.
    """
    if not isinstance(config, DockingConfig):
        raise TypeError(f"params takes a DockingConfig, got {type(config).__name__}")
    check_choice("obs_mode", config.obs_mode, OBS_MODES)
    check_choice("layout", config.layout, LAYOUTS)
    resolved = levels.resolve(config.presets, config.difficulty, {
        "disturbances": config.disturbances, "optics": config.optics,
        "navigation": config.navigation})
    disturbances, optics, navigation = (resolved["disturbances"], resolved["optics"],
                                        resolved["navigation"])
    if navigation is None:  # easy: the release's presets set nothing
        navigation = EASY_NAVIGATION
    if not isinstance(navigation, NavigationSensors):
        raise TypeError(f"navigation must be a NavigationSensors, got "
                        f"{type(navigation).__name__}")
    disturbances = disturbances if disturbances is not None else DockingDisturbances()
    if not isinstance(disturbances, DockingDisturbances):
        raise TypeError(
            f"disturbances must be a DockingDisturbances, got {type(disturbances).__name__}")
    if optics is None:
        optics = config.default_optics
    if optics is not None and not isinstance(optics, WaterOptics):
        raise TypeError(f"optics must be a WaterOptics or None, got {type(optics).__name__}")
    check_choice("scenario", config.scenario, SCENARIOS)
    check_choice("integrator", config.integrator, INTEGRATORS)
    check_choice("plant", config.plant, PLANTS)
    check_choice("sensors", config.sensors, SENSOR_CODES)
    if config.plant == "compiled" and config.integrator != "rk4":
        raise ValueError(f"the compiled plant integrates with RK4, not {config.integrator!r}: "
                         "pass plant='mujoco' with integrator='euler'")
    width, height = check_image_size(config.image_size)
    for name in ("time_limit", "lights_lost_timeout"):
        value = getattr(config, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    check_positive_int("physics_substeps", config.physics_substeps)
    direction = config.current_direction
    if direction is not None and not math.isfinite(direction):
        raise ValueError(f"current_direction must be finite, got {direction}")
    layout = LAYOUTS[config.layout]
    n_lights = len(layout.light_labels)
    min_visible = int(config.min_visible_lights)
    if not 1 <= min_visible <= n_lights:
        raise ValueError(f"min_visible_lights must be in [1, {n_lights}]")

    vehicle = hovering_auv()
    obs_mode = config.obs_mode
    # The station's drawn meshes are tessellated for the image observation's size.
    model_source = compose_docking_model(
        layout, vehicle, image_height=height if obs_mode == "image" else None)
    model = model_source.compile()
    model.opt.timestep = CONTROL_PERIOD / config.physics_substeps
    model.opt.integrator = INTEGRATORS[config.integrator]
    physics = DockingPhysics(model, n_lights)  # the geometry's named accessors
    dt = CONTROL_PERIOD
    max_episode_steps = math.ceil(float(config.time_limit) / dt - 1e-6)

    noisy = config.scenario == "current"
    nominal = (with_damping_mismatch(vehicle, tuple(config.damping_mismatch))
               if config.model_mismatch else vehicle)
    light_positions = physics.light_positions.copy()
    light_positions.setflags(write=False)
    nose = vehicle.length / 2.0
    target = np.array([-nose, 0.0, 0.0])
    target.setflags(write=False)
    calibration = DockingCalibration(
        intrinsics=CameraIntrinsics.from_fovy(width, height,
                                              float(model.cam_fovy[physics.camera_id])),
        extrinsics=CameraExtrinsics.from_mujoco(physics.camera_pos_body,
                                                physics.camera_mat_body),
        light_positions=light_positions,
        light_labels=layout.light_labels,
        nominal_params=nominal,
        nominal_model=NominalModel(nominal),
        control_period=dt,
        thrust_limits=vehicle.thrust_limits,
        nose_offset=nose,
        target_position=target,
        tolerances=config.tolerances or DockingTolerances(),
        seabed_z=physics.seabed_z,
        pixel_noise_std=SCENARIO_PIXEL_NOISE if noisy else 0.0,
        velocity_noise_std=SCENARIO_VELOCITY_NOISE if noisy else 0.0,
        yaw_rate_noise_std=SCENARIO_YAW_RATE_NOISE if noisy else 0.0,
        attitude_noise_std=SCENARIO_ATTITUDE_NOISE if noisy else 0.0,
        disturbances=disturbances,
        optics=optics,
    )
    mission = transition.MissionSpec() if config.mission else None
    rules = DockingRules(
        intrinsics=calibration.intrinsics,
        camera_position=calibration.extrinsics.position,
        camera_rotation=calibration.extrinsics.rotation,
        lights=tuple(tuple(p) for p in light_positions.tolist()), nose_offset=nose,
        hull_axes=(nose, vehicle.diameter / 2, vehicle.diameter / 2),
        seabed_z=physics.seabed_z, tolerances=calibration.tolerances,
        min_visible=min_visible,
        lights_lost_timeout=(float(config.lights_lost_timeout) if mission is None
                             else math.inf),
        control_period=dt,
        **({} if mission is None else {"out_of_bounds": mission.out_of_bounds,
                                       "behind_radius": mission.behind_radius,
                                       "surface_z": navigation.station_depth}),
    )
    if mission is not None:  # the lights take over where the water shows them
        mission = dataclasses.replace(
            mission, handover_range=math.inf if optics is None else optics.detection_range())

    action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
    observation_space = _observation_space(obs_mode, n_lights, width, height)
    pixel_bounds = None
    if obs_mode in transition.LIGHT_MODES:
        space = observation_space["pixels"]
        pixel_bounds = (space.low.astype(np.float64), space.high.astype(np.float64))
    cal = calibration
    task_params = transition.DockingParams(
        rules=rules, start_box=(layout.start_x, layout.start_y, layout.start_z),
        light_positions=light_positions, obs_mode=obs_mode, scenario=config.scenario,
        current_direction=direction, disturbances=disturbances, optics=optics,
        # Per-step constants as Python floats (the step path works in floats).
        thrust_limits=tuple(float(t) for t in vehicle.thrust_limits),
        thruster_gain=thruster_lag_gain(disturbances.thruster_time_constant, dt),
        noise=(cal.pixel_noise_std, cal.velocity_noise_std, cal.yaw_rate_noise_std,
               cal.attitude_noise_std),
        pixel_bounds=pixel_bounds, focal_px=cal.intrinsics.fy,
        max_episode_steps=max_episode_steps,
        navigation=(Navigation(navigation, physics.seabed_z, dt)
                    if obs_mode in transition.NAV_MODES else None),
        mission=mission)
    return DockingSetup(
        config=config,
        levels={"disturbances": disturbances, "optics": optics, "navigation": navigation},
        layout=layout, mission=mission, vehicle=vehicle, model_source=model_source,
        model=model, calibration=calibration, rules=rules, params=task_params,
        observation_space=observation_space, action_space=action_space, dt=dt,
        max_episode_steps=max_episode_steps)


def _observation_space(obs_mode: str, n: int, width: int, height: int) -> spaces.Space:
    """The observation space of ``obs_mode`` with ``n`` lights and a ``width`` x
    ``height`` camera."""
    if obs_mode == "state":
        return spaces.Box(-np.inf, np.inf, shape=(16,), dtype=np.float32)
    sensors = {
        "velocity": spaces.Box(-np.inf, np.inf, shape=(4,), dtype=np.float32),
        "attitude": spaces.Box(-np.pi - 1.0, np.pi + 1.0, shape=(3,), dtype=np.float32),
    }
    if obs_mode in transition.NAV_MODES:
        sensors = nav_space()
    if obs_mode == "nav":
        return sensors
    if obs_mode in transition.LIGHT_MODES:
        return spaces.Dict({"pixels": pixel_space(width, height, (n,)),
                            "visible": spaces.MultiBinary(n), **sensors})
    return spaces.Dict(
        {"image": spaces.Box(0, 255, shape=(height, width, 3), dtype=np.uint8), **sensors})


def nav_space() -> spaces.Dict:
    """The navigation sensors' observation (:meth:`Navigation.observation`)."""
    unbounded = {"shape": (3,), "dtype": np.float32}
    return spaces.Dict({
        "dvl_velocity": spaces.Box(-np.inf, np.inf, **unbounded),
        "dvl_valid": spaces.MultiBinary(1),
        "attitude": spaces.Box(-np.pi - 1.0, np.pi + 1.0, **unbounded),
        "rates": spaces.Box(-np.inf, np.inf, **unbounded),
        "depth": spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32),
        "usbl": spaces.Box(-np.inf, np.inf, **unbounded),
        "usbl_age": spaces.Box(0.0, np.inf, shape=(1,), dtype=np.float32),
        "usbl_valid": spaces.MultiBinary(1),
    })

