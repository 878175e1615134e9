"""Docking-station approach guided by lights ([OFNMPC] and [LAMP]).

Two registered layouts share this file:

* ``auv_envs/DockingStation-v2``: six lights symmetric around the entrance
  [OFNMPC].
* ``auv_envs/LampArrayDocking-v2``: asymmetric L-shaped array of four lamps
  under a recovery fork [LAMP].
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
from gymnasium import spaces

from auv_envs.core import difficulty as levels
from auv_envs.core.camera import (
    CameraExtrinsics,
    CameraIntrinsics,
    pixel_space,
    project_few,
)
from auv_envs.core.env import (
    ActionValidator,
    ShellEpisode,
    TaskEnv,
    check_choice,
    check_image_size,
    check_positive_int,
)
from auv_envs.core.hydrodynamics import HullForceModel, NominalModel
from auv_envs.core.ops import FLOATS
from auv_envs.core.plant import StagedIntegrator
from auv_envs.core.rendering import CameraRenderer
from auv_envs.core.sea import GaussMarkovCurrent
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
    USBL,
    USBL_ACOUSTICS,
    DepthSensor,
    Navigation,
    NavigationSensors,
)
from auv_envs.tasks.docking.optics import WaterOptics, degrade_image
from auv_envs.tasks.docking.plant import CompiledPlant, MujocoPlant
from auv_envs.tasks.docking.rules import (
    FAILURE_REASONS,
    DockingRules,
    DockingTolerances,
    failure_reason,
)
from auv_envs.tasks.docking.station import (
    CHASE_CAMERA,
    CHASE_HEADLIGHT,
    LAMP_ARRAY,
    OWN_HULL_GROUP,
    RENDER_CAMERAS,
    SIX_LIGHTS,
    DockingPhysics,
    StationLayout,
    compose_docking_model,
)
from auv_envs.tasks.docking.transition import (  # noqa: F401  (their home before the transition)
    SCENARIO_CURRENT_SPEED,
    START_HEADING_SPREAD_DEG,
    START_SURGE,
)

OBS_MODES = ("state", "features", "image", "nav", "nav_features")
#: Summary entries reported as None where NaN (no docking, no hand-over).
NONE_IF_NAN = frozenset({"docking_time", *transition.MISSION_METRICS}) - {"path_length"}
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


class DockingEnv(TaskEnv):
    """AUV approach to a light-guided docking station ([OFNMPC] / [LAMP]).

    **Description.** A fully actuated hovering AUV (6-DOF MuJoCo rigid body
    with Fossen hydrodynamics: added mass including the acceleration term,
    Coriolis, linear + quadratic damping, restoring forces with 10 N net
    positive buoyancy and a righting moment, and an ocean current through the
    relative velocity) must reach the entrance of a docking station (DS) on
    the seabed, guided by lights seen by a forward camera. Roll and pitch are
    passively stable (CB 0.15 m above CG). The world frame is the DS frame:
    origin at the entrance centre, x into the station, z up. The episode is
    :mod:`auv_envs.tasks.docking.transition`, which the batched environment
    runs too.

    **Action space.** ``Box(-1, 1, (4,), float32)``: a normalised force and moment in the
    body frame (x forward, y to port, z up), each entry times its entry of
    ``calibration.thrust_limits`` (80 N, 80 N, 80 N, 40 N m). With
    ``disturbances.thruster_time_constant`` the thrusters reach the command with a
    first-order lag (``info["thrust"]``). Finite values outside [-1, 1] are clipped; NaN,
    inf and non-numbers raise ``ValueError``.

    =====  ====================================  ====  ====  =======================================
    index  action                                min   max   unit
    =====  ====================================  ====  ====  =======================================
    0      X, surge force (+ forward)            -1    1     fraction of 80 N
    1      Y, sway force (+ to port)             -1    1     fraction of 80 N
    2      Z, heave force (+ up)                 -1    1     fraction of 80 N
    3      N, yaw moment (+ turning to port)     -1    1     fraction of 40 N m
    =====  ====================================  ====  ====  =======================================

    **Observation space** (``obs_mode``; n lights, in the order of
    ``calibration.light_labels``). The world frame is the DS frame (x into the station,
    z up), the body frame x forward, y to port, z up; angles in rad.

    ``state``: ``Box(-inf, inf, (16,), float32)``, privileged (the ground truth, as in
    ``info``; no sensor noise):

    =====  ========================================================================  ===============
    index  observation                                                               unit
    =====  ========================================================================  ===============
    0      CG x, DS frame (``info["true_position"]``)                                m
    1      CG y, DS frame                                                            m
    2      CG z, DS frame                                                            m
    3      roll (``info["true_euler"]``; + port side up)                             rad
    4      pitch (+ nose down)                                                       rad
    5      cos(yaw), yaw the heading from the DS x axis (0: facing into the          -
           station; + towards DS +y)
    6      sin(yaw)                                                                  -
    7      u, velocity over ground along body x (``info["true_velocity"]``)          m/s
    8      v, velocity over ground along body y                                      m/s
    9      w, velocity over ground along body z                                      m/s
    10     p, angular velocity about body x                                          rad/s
    11     q, angular velocity about body y                                          rad/s
    12     r, angular velocity about body z                                          rad/s
    13     current (water velocity), DS x (``info["current"]``)                      m/s
    14     current, DS y                                                             m/s
    15     current, DS z (always 0)                                                  m/s
    =====  ========================================================================  ===============

    ``features`` and ``image``: ``Dict``. In the ``current`` scenario the sensors are noisy
    (``calibration.*_noise_std``):

    ============  =========  =======  ================================================  ============
    key           shape      dtype    observation                                       unit
    ============  =========  =======  ================================================  ============
    ``pixels``    (n, 2)     float32  each light's (u, v) in the image at               px
                                      ``image_size`` (u right, v down from the
                                      top-left corner); zero where not seen; 5 px
                                      noise in the ``current`` scenario, clipped to
                                      [-W, 2W] x [-H, 2H]. Not in ``image``
    ``visible``   (n,)       int8     ``MultiBinary(n)``: 1 where the light is seen     -
                                      (inside the image with a clear line of sight;
                                      with ``optics``, detected). Not in ``image``
    ``image``     (H, W, 3)  uint8    ``image`` only: the forward camera's RGB image,   -
                                      (W, H) = ``image_size``
    ``velocity``  (4,)       float32  DVL/INS: u, v, w (m/s) and r (rad/s), body        m/s, rad/s
                                      frame; noise 0.02 m/s and 0.005 rad/s in the
                                      ``current`` scenario
    ``attitude``  (3,)       float32  INS: roll, pitch, yaw (yaw wrapped to [-pi,       rad
                                      pi)); noise 0.2 deg in the ``current`` scenario
    ============  =========  =======  ================================================  ============

    ``nav``: ``Dict``, the navigation sensors of ``navigation``
    (:mod:`auv_envs.tasks.docking.navigation`); ``nav_features``: these and ``pixels`` and
    ``visible`` of ``features``:

    ================  =====  =======  ====================================================  ========
    key               shape  dtype    observation                                           unit
    ================  =====  =======  ====================================================  ========
    ``dvl_velocity``  (3,)   float32  DVL: u, v, w over the seabed, body frame, with the    m/s
                                      episode's scale errors and noise; zero without
                                      bottom lock
    ``dvl_valid``     (1,)   int8     ``MultiBinary(1)``: 1 with bottom lock                -
    ``attitude``      (3,)   float32  AHRS: roll, pitch, heading (wrapped to [-pi, pi),     rad
                                      with the episode's heading deviation)
    ``rates``         (3,)   float32  gyros: p, q, r with noise and a wandering bias        rad/s
    ``depth``         (1,)   float32  pressure depth of the CG below the surface            m
                                      (``navigation.station_depth`` - z), positive down
    ``usbl``          (3,)   float32  the last USBL fix delivered: the transponder as seen  m
                                      from the CG, body axes (zero before the first)
    ``usbl_age``      (1,)   float32  time since the ping of that fix (0 before the first)  s
    ``usbl_valid``    (1,)   int8     ``MultiBinary(1)``: 1 once a fix has been delivered   -
    ================  =====  =======  ====================================================  ========

    With ``optics`` the camera looks through that water: ``image`` through the
    image formation model, ``features`` detecting each lamp with a
    probability that falls with its contrast, with centroid noise, and
    missing lamps hidden by occluders; failed lamps stay dark. The reward and
    the episode's end count the lamps geometrically in view.

    **Rewards** (each in ``info["reward_<term>"]``, summing to the reward):

    ==============  =======================================================
    term            value
    ==============  =======================================================
    ``progress``    decrease of (distance to the entrance + 0.5 |heading|)
    ``control``     -0.001 |a|^2
    ``visibility``  -0.01 per step with fewer than ``min_visible_lights`` seen
    ``success``     +10 on docking
    ``failure``     -10 on failing
    ==============  =======================================================

    **Starting state.** CG at x in [-12, -8] m, y in [-1.5, 1.5] m, z in the
    layout's range, heading towards the entrance +-10 deg, surge 0-0.3 m/s;
    in the ``current`` scenario a 0.3 m/s current towards
    ``current_direction`` (deg; drawn when None).

    **Episode end.** Terminated on success (the nose within
    ``DockingTolerances`` of the entrance: 0.2 m lateral and vertical, 10 deg,
    0.15 m along the axis) or failure (``behind_entrance``, ``seabed``,
    ``lights_lost`` for more than ``lights_lost_timeout`` s, ``out_of_bounds``
    beyond 30 m); truncated after ``time_limit`` s.

    **Info.** Every step: ``distance_to_entrance``, ``lateral_error``,
    ``vertical_error``, ``longitudinal_error``, ``heading_error``, ``docked``,
    ``lights_visible``, ``violation_fov``, ``violation_behind_entrance``,
    ``violation_seabed``, ``is_success``, the reward terms, ground truth for
    metrics (``true_position``, ``true_euler``, ``true_velocity``,
    ``true_pixels``, ``true_visible``, ``current``), ``thrust`` with a thruster
    lag. At reset: ``plant`` (a plant perturbation's draws), ``optics``
    (``failed_lamps``). At the end: ``episode_metrics`` (``docking_time`` None
    without success).

    **Arguments.**

    =======================  =====================  ==============  ================================
    argument                 Type                   Default         meaning
    =======================  =====================  ==============  ================================
    ``obs_mode``             str                    ``"state"``     ``"state"``, ``"features"``,
                                                                    ``"image"``, ``"nav"``,
                                                                    ``"nav_features"``
    ``scenario``             str                    ``"mismatch"``  ``"mismatch"`` ([OFNMPC]
                                                                    Scenario 1) or ``"current"``
                                                                    (Scenario 2: current and noise)
    ``current_direction``    float | None           ``None``        the scenario current's
                                                                    direction, deg (None: drawn)
    ``image_size``           tuple[int, int]        ``(640, 480)``  (W, H) of the camera, also the
                                                                    pixel frame of ``features``
    ``model_mismatch``       bool                   ``True``        False: nominal model = plant
    ``damping_mismatch``     tuple[float, ...]      (0.7, 1.4,      scale of the nominal D diagonals
                                                    1.3, 1.0,       (surge, sway, heave, roll,
                                                    1.0, 0.6)       pitch, yaw):
                                                                    ``DEFAULT_DAMPING_MISMATCH``
    ``tolerances``           DockingTolerances |    ``None``        success tolerances (None:
                             None                                   ``DockingTolerances()``)
    ``time_limit``           float                  ``100.0``       s
    ``lights_lost_timeout``  float                  ``5.0``         s
    ``min_visible_lights``   int                    ``3``           lights in view below which the
                                                                    ``visibility`` penalty and the
                                                                    lights-lost clock run (1 to n)
    ``integrator``           str                    ``"rk4"``       ``"rk4"``; ``"euler"``: the v0
                                                                    plant
    ``physics_substeps``     int                    ``1``           plant steps per 0.1 s
    ``plant``                str                    ``"compiled"``  ``"compiled"`` (the hull
                                                                    compiled away from the scenery)
                                                                    or ``"mujoco"`` (the v1 plant)
    ``render_mode``          str | None             ``None``        ``"rgb_array"`` or None
    ``render_camera``        str                    ``"chase"``     ``"chase"`` or ``"onboard"``
    ``render_size``          tuple[int, int]        ``(640, 480)``  (W, H) of ``render()``
    ``disturbances``         DockingDisturbances |  ``None``        :class:`DockingDisturbances`
                             None                                   (None: the level's; none at
                                                                    ``easy``)
    ``optics``               WaterOptics | None     ``None``        :class:`WaterOptics` (None: the
                                                                    level's; clear water at
                                                                    ``easy``)
    ``navigation``           NavigationSensors |    ``None``        :class:`NavigationSensors` of
                             None                                   the ``nav`` modes (None: the
                                                                    level's; ``docs/navigation.md``)
    ``difficulty``           str                    ``"easy"``      ``DEFAULT_LEVEL``: ``"easy"``
                                                                    (the release), ``"paper"``,
                                                                    ``"hard"``: ``disturbances``,
                                                                    ``optics`` and ``navigation``
                                                                    (:data:`PAPER_DISTURBANCES`,
                                                                    ..., ``docs/difficulty.md``)
    =======================  =====================  ==============  ================================

    **Version history.** v2: the same plant, compiled (CasADi) wherever no
    contact can act, MuJoCo's near the scenery: equal to v1 to round-off. v1:
    the plant integrates with classical RK4 (0.1 s, the hull wrench at every
    stage). v0: semi-implicit Euler at 0.05 s. v0 and v1 are still registered.
    Changes within a version (rendering, opt-in arguments) with their
    measurements: ``CHANGELOG.md``.
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": round(1 / CONTROL_PERIOD),
    }
    _closeables = ("camera_renderer", "_view")

    layout: StationLayout = SIX_LIGHTS
    #: The whole approach's start and phases (:class:`transition.MissionSpec`); None: the
    #: terminal approach of the docking ids.
    mission: transition.MissionSpec | None = None
    #: The water when ``optics`` is None and the level sets none (None: clear water, every
    #: lamp seen at any range).
    default_optics: WaterOptics | None = None

    #: The contract the registry-driven tests read (see tests/conftest.py).
    obs_modes = OBS_MODES
    #: ``difficulty`` levels (:mod:`auv_envs.core.difficulty`): the plant's
    #: disturbances and the water's optics (see :data:`PAPER_DISTURBANCES` and
    #: the constants after it for each value's unit, source and calibration).
    difficulty_presets = {
        "easy": {},
        "paper": {"disturbances": PAPER_DISTURBANCES, "optics": PAPER_OPTICS,
                  "navigation": PAPER_NAVIGATION},
        "hard": {"disturbances": HARD_DISTURBANCES, "optics": HARD_OPTICS,
                 "navigation": HARD_NAVIGATION},
    }
    transition = transition
    reward_terms = transition.REWARD_TERMS
    metric_keys = (
        "distance_to_entrance", "longitudinal_error", "lateral_error", "vertical_error",
        "heading_error", "docked", "lights_visible", "violation_fov",
        "violation_behind_entrance", "violation_seabed", "is_success",
    )

    def __init__(
        self,
        obs_mode: str = "state",
        scenario: str = "mismatch",
        current_direction: float | None = None,
        image_size: tuple[int, int] = (640, 480),
        model_mismatch: bool = True,
        damping_mismatch: tuple[float, ...] = DEFAULT_DAMPING_MISMATCH,
        tolerances: DockingTolerances | None = None,
        time_limit: float = 100.0,
        lights_lost_timeout: float = 5.0,
        min_visible_lights: int = 3,
        integrator: str = "rk4",
        physics_substeps: int = 1,
        plant: str = "compiled",
        render_mode: str | None = None,
        render_camera: str = "chase",
        render_size: tuple[int, int] = (640, 480),
        disturbances: DockingDisturbances | None = None,
        optics: WaterOptics | None = None,
        navigation: NavigationSensors | None = None,
        difficulty: str = levels.DEFAULT_LEVEL,
        **unknown,
    ):
        self._accept_arguments(
            unknown,
            obs_mode=obs_mode, scenario=scenario, current_direction=current_direction,
            image_size=tuple(image_size), model_mismatch=model_mismatch,
            damping_mismatch=tuple(damping_mismatch), tolerances=tolerances,
            time_limit=time_limit, lights_lost_timeout=lights_lost_timeout,
            min_visible_lights=min_visible_lights, integrator=integrator,
            physics_substeps=physics_substeps, plant=plant, render_mode=render_mode,
            render_camera=render_camera, render_size=render_size, disturbances=disturbances,
            optics=optics, navigation=navigation, difficulty=difficulty,
        )
        level = self._apply_difficulty(difficulty, disturbances=disturbances, optics=optics,
                                       navigation=navigation)
        disturbances, optics, navigation = (level["disturbances"], level["optics"],
                                            level["navigation"])
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
            optics = self.default_optics
        if optics is not None and not isinstance(optics, WaterOptics):
            raise TypeError(f"optics must be a WaterOptics or None, got {type(optics).__name__}")
        check_choice("scenario", scenario, SCENARIOS)
        check_choice("render_camera", render_camera, RENDER_CAMERAS)
        render_width, render_height = check_image_size(render_size, "render_size")
        self._init_kwargs["render_size"] = (render_width, render_height)
        check_choice("integrator", integrator, INTEGRATORS)
        check_choice("plant", plant, PLANTS)
        if plant == "compiled" and integrator != "rk4":
            raise ValueError(f"the compiled plant integrates with RK4, not {integrator!r}: "
                             "pass plant='mujoco' with integrator='euler'")
        width, height = check_image_size(image_size)
        for name, value in (("time_limit", time_limit),
                            ("lights_lost_timeout", lights_lost_timeout)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        check_positive_int("physics_substeps", physics_substeps)
        if current_direction is not None and not math.isfinite(current_direction):
            raise ValueError(f"current_direction must be finite, got {current_direction}")

        self.obs_mode = obs_mode
        self.scenario = scenario
        self.render_mode = render_mode
        self._current_direction = current_direction
        self._time_limit = float(time_limit)
        self._lost_timeout = float(lights_lost_timeout)
        self._min_visible = int(min_visible_lights)
        self._params = hovering_auv()
        n_lights = len(self.layout.light_labels)
        if not 1 <= self._min_visible <= n_lights:
            raise ValueError(f"min_visible_lights must be in [1, {n_lights}]")

        # The station's drawn meshes are tessellated for the image observation's size.
        #: The composed model's text (:class:`~auv_envs.core.assets.MJCF`).
        self.model_source = compose_docking_model(
            self.layout, self._params, image_height=height if obs_mode == "image" else None)
        model = self.model_source.compile()
        model.opt.timestep = CONTROL_PERIOD / physics_substeps
        model.opt.integrator = INTEGRATORS[integrator]
        self._physics_substeps = physics_substeps
        self.physics = DockingPhysics(model, n_lights)
        self.hull = HullForceModel(self._params, self.physics.hull_body, self.physics.qvel_adr)
        #: The plant's integrator: MuJoCo's, with the hull wrench at every stage.
        self.integrator = StagedIntegrator(model, self.physics.data, self.hull.passive_force)
        self._dt = CONTROL_PERIOD
        #: The simulated vehicle's parameters (what the plant integrates), read-only.
        self.vehicle = self._params
        #: Control period, s (one env step).
        self.dt = self._dt
        #: Steps of an episode that runs to its ``time_limit``.
        self.max_episode_steps = math.ceil(self._time_limit / self._dt - 1e-6)

        noisy = scenario == "current"
        nominal = (
            with_damping_mismatch(self._params, tuple(damping_mismatch))
            if model_mismatch
            else self._params
        )
        light_positions = self.physics.light_positions.copy()
        light_positions.setflags(write=False)
        nose = self._params.length / 2.0
        target = np.array([-nose, 0.0, 0.0])
        target.setflags(write=False)
        self.calibration = DockingCalibration(
            intrinsics=CameraIntrinsics.from_fovy(
                width, height, float(model.cam_fovy[self.physics.camera_id])
            ),
            extrinsics=CameraExtrinsics.from_mujoco(
                self.physics.camera_pos_body, self.physics.camera_mat_body
            ),
            light_positions=light_positions,
            light_labels=self.layout.light_labels,
            nominal_params=nominal,
            nominal_model=NominalModel(nominal),
            control_period=self._dt,
            thrust_limits=self._params.thrust_limits,
            nose_offset=nose,
            target_position=target,
            tolerances=tolerances or DockingTolerances(),
            seabed_z=self.physics.seabed_z,
            pixel_noise_std=SCENARIO_PIXEL_NOISE if noisy else 0.0,
            velocity_noise_std=SCENARIO_VELOCITY_NOISE if noisy else 0.0,
            yaw_rate_noise_std=SCENARIO_YAW_RATE_NOISE if noisy else 0.0,
            attitude_noise_std=SCENARIO_ATTITUDE_NOISE if noisy else 0.0,
            disturbances=disturbances,
            optics=optics,
        )
        self._optics = optics
        #: The task's geometry and rules (:mod:`auv_envs.tasks.docking.rules`), which the
        #: batched environment evaluates too.
        self.rules = DockingRules(
            intrinsics=self.calibration.intrinsics,
            camera_position=self.calibration.extrinsics.position,
            camera_rotation=self.calibration.extrinsics.rotation,
            lights=tuple(tuple(p) for p in light_positions.tolist()), nose_offset=nose,
            hull_axes=(nose, self._params.diameter / 2, self._params.diameter / 2),
            seabed_z=self.physics.seabed_z, tolerances=self.calibration.tolerances,
            min_visible=self._min_visible,
            lights_lost_timeout=self._lost_timeout if self.mission is None else math.inf,
            control_period=self._dt,
            **({} if self.mission is None else {"out_of_bounds": self.mission.out_of_bounds,
                                                "behind_radius": self.mission.behind_radius,
                                                "surface_z": navigation.station_depth}),
        )
        mission = self.mission
        if mission is not None:  # the lights take over where the water shows them
            mission = dataclasses.replace(
                mission, handover_range=math.inf if optics is None else optics.detection_range())

        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._validate_action = ActionValidator(self.action_space)
        self.observation_space = self._make_observation_space(n_lights, width, height)
        pixel_bounds = None
        if obs_mode in transition.LIGHT_MODES:
            space = self.observation_space["pixels"]
            pixel_bounds = (space.low.astype(np.float64), space.high.astype(np.float64))
        cal = self.calibration
        #: The task as the transition sees it (:mod:`auv_envs.tasks.docking.transition`),
        #: which the batched environment runs too.
        self.params = transition.DockingParams(
            rules=self.rules, start_box=(self.layout.start_x, self.layout.start_y,
                                         self.layout.start_z),
            light_positions=light_positions, obs_mode=obs_mode, scenario=scenario,
            current_direction=current_direction, disturbances=disturbances, optics=optics,
            # Per-step constants as Python floats (the step path works in floats).
            thrust_limits=tuple(float(t) for t in self._params.thrust_limits),
            thruster_gain=thruster_lag_gain(disturbances.thruster_time_constant, self._dt),
            noise=(cal.pixel_noise_std, cal.velocity_noise_std, cal.yaw_rate_noise_std,
                   cal.attitude_noise_std),
            pixel_bounds=pixel_bounds, focal_px=cal.intrinsics.fy,
            max_episode_steps=self.max_episode_steps,
            navigation=(Navigation(navigation, self.physics.seabed_z, self._dt)
                        if obs_mode in transition.NAV_MODES else None),
            mission=mission)
        #: The navigation sensors (:mod:`auv_envs.tasks.docking.navigation`) of the ``nav`` modes.
        self.navigation = navigation
        self._plant = CompiledPlant(self) if plant == "compiled" else MujocoPlant(self)
        # One renderer for the image observation, one for render(): they differ
        # in camera, size or lighting.
        self.camera_renderer: CameraRenderer | None = None
        if obs_mode == "image":
            hidden = () if self.physics.camera_sees_hull(width, height) else (OWN_HULL_GROUP,)
            self.camera_renderer = CameraRenderer(model, (self.physics.camera_name,), width, height,
                                                  hidden_groups=hidden, fit_outlines=True,
                                                  detail=self.physics.detail_levels())
        self._view: CameraRenderer | None = None
        if render_mode == "rgb_array":
            chase = render_camera == "chase"
            self._view = CameraRenderer(
                model, (CHASE_CAMERA if chase else self.physics.camera_name,),
                render_width, render_height, headlight=CHASE_HEADLIGHT if chase else None,
                fog=chase, skybox=chase, fit_outlines=not chase,  # onboard: as the observation
                detail=() if chase else self.physics.detail_levels(),
            )
        self._episode = ShellEpisode()

    # ------------------------------------------------------------------ spaces
    def _make_observation_space(self, n: int, width: int, height: int) -> spaces.Space:
        if self.obs_mode == "state":
            return spaces.Box(-np.inf, np.inf, shape=(16,), dtype=np.float32)
        sensors = {
            "velocity": spaces.Box(-np.inf, np.inf, shape=(4,), dtype=np.float32),
            "attitude": spaces.Box(-np.pi - 1.0, np.pi + 1.0, shape=(3,), dtype=np.float32),
        }
        if self.obs_mode in transition.NAV_MODES:
            sensors = nav_space()
        if self.obs_mode == "nav":
            return sensors
        if self.obs_mode in transition.LIGHT_MODES:
            return spaces.Dict(
                {
                    "pixels": pixel_space(width, height, (n,)),
                    "visible": spaces.MultiBinary(n),
                    **sensors,
                }
            )
        return spaces.Dict(
            {"image": spaces.Box(0, 255, shape=(height, width, 3), dtype=np.uint8), **sensors}
        )

    # ------------------------------------------------------------------ episode hooks
    def _begin_episode(self, rng: np.random.Generator, options: dict | None):
        _, state, truth, obs, _ = transition.reset(self.params, self._backend(rng))
        self._episode = ShellEpisode(state, obs)
        extras = {}
        if state.plant is not None:
            extras["plant"] = self.plant_draws(state.plant)
        if state.failed is not None:
            extras["optics"] = {"failed_lamps": tuple(
                label for label, out in zip(self.layout.light_labels, state.failed, strict=True)
                if out)}
        return truth, extras

    def vehicle_of(self, draws) -> VehicleParams:
        """The simulated vehicle of an episode's plant draws (the nominal one for None)."""
        if draws is None:
            return self._params
        mass, damping, buoyancy = draws
        return PlantPerturbation.apply(self._params, float(mass), damping.tolist(),
                                       float(buoyancy))

    @staticmethod
    def plant_draws(draws) -> dict:
        """``info["plant"]`` at reset: the episode's plant perturbation, named."""
        mass, damping, buoyancy = draws
        damping = damping.tolist()
        return {"mass_scale": float(mass), "linear_damping_scale": damping[:6],
                "quadratic_damping_scale": damping[6:], "net_buoyancy_offset": float(buoyancy)}

    def _set_runtime_state(self, state: dict) -> None:
        # The episode's (perturbed) vehicle and failed lamps live in the model too.
        episode = state["episode"].state
        if episode is not None:
            self._use_vehicle(self.vehicle_of(episode.plant))
        super()._set_runtime_state(state)
        if episode is not None and episode.failed is not None:
            self.physics.show_lamps(episode.failed)

    def _use_vehicle(self, vehicle: VehicleParams) -> None:
        """Make ``vehicle`` the simulated one: MuJoCo's mass and inertia, the hull wrench."""
        if vehicle is self.vehicle:
            return
        model, data, body = self.physics.model, self.physics.data, self.physics.hull_body
        model.body_mass[body] = vehicle.mass
        model.body_inertia[body] = vehicle.inertia
        mujoco.mj_setConst(model, data)  # the constants derived from masses
        self.hull = HullForceModel(vehicle, body, self.physics.qvel_adr)
        self.integrator.force = self.hull.passive_force
        self.vehicle = vehicle

    def _command(self, action: np.ndarray) -> list:
        """The transition takes the four commands as Python floats."""
        return action.tolist()

    def _render_frame(self) -> np.ndarray:
        return self._render_camera(self._view)

    # ------------------------------------------------------------------ internals
    def _truth(self) -> dict:
        """Ground truth now (the plant's: compiled or in Python floats)."""
        return self._plant.truth(self.physics.data)

    def _float_truth(self) -> dict:
        """Ground truth now, computed once a step and shared by obs, reward and info
        (:func:`~auv_envs.tasks.docking.transition.truth_with_lights`); ``plant="mujoco"``'s.

        Python floats throughout: with a handful of lights, NumPy's per-call
        overhead would cost several times the arithmetic.
        """
        phys = self.physics
        truth = self.rules.kinematics(*phys.kinematics(), FLOATS)
        cam_pos = truth["camera_position"]
        pixels, in_image = project_few(
            self.calibration.intrinsics, self.rules.lights, cam_pos, truth.pop("camera_rows")
        )
        visible = phys.unoccluded(cam_pos, self.rules.lights, in_image)
        return transition.truth_with_lights(truth, np.array(pixels), np.array(visible), FLOATS)

    def _observation(self, truth: dict):
        obs = self._episode.obs  # the transition's: state, features, or image mode's sensors
        if self.obs_mode != "image":
            return obs
        if self._optics is not None:
            return {"image": self._render_through_water(), **obs}
        return {"image": self._render_camera(self.camera_renderer), **obs}

    def lights_in_view(self) -> tuple[np.ndarray, np.ndarray]:
        """Where the camera sees each light now, geometrically: ``(pixels (n, 2),
        visible (n,) bool)``, the projection of each light's centre (NaN outside the
        image) and a clear line of sight to it inside the image; what
        ``info["true_pixels"]`` and ``info["true_visible"]`` report after a step (there
        zero where not visible). Draws nothing from the generator."""
        truth = self._truth()
        return truth["pixels"], truth["visible"]

    def lamps_in_image(self) -> tuple[np.ndarray, np.ndarray]:
        """Each lamp as a person labelling the camera's frame marks it: ``(pixels (n, 2),
        shown (n,) bool)``, the centroid of the lamp's pixels in the clear-water render
        (NaN where none) and whether any shows (``image`` mode only).

        ``info["true_pixels"]`` is the projection of a lamp's centre and
        ``info["true_visible"]`` a clear line of sight to it. A lamp sphere
        partly behind the station's structure still shows, off its centre,
        and is labelled where it shows; [LAMP]'s tracking figures are
        scored against these labels (``scripts/reproduce_lamp_array.py``). A
        lamp that failed (``optics``) is drawn unlit and not labelled. One
        segmentation draw (:meth:`CameraRenderer.render_geom_ids`); draws
        nothing from the generator.
        """
        if self.obs_mode != "image":
            raise RuntimeError("lamps_in_image() needs obs_mode='image' (the camera renderer)")
        mujoco.mj_forward(self.physics.model, self.physics.data)
        ids = self.camera_renderer.render_geom_ids(self.physics.data)
        pixels = np.full((len(self.physics.lamp_geoms), 2), np.nan)
        state = self._episode.state
        failed = (state.failed if state is not None and state.failed is not None
                  else np.zeros(len(pixels), bool))
        for i, geom in enumerate(self.physics.lamp_geoms):
            rows, cols = np.nonzero(ids == geom)
            if len(rows) and not failed[i]:
                pixels[i] = cols.mean() + 0.5, rows.mean() + 0.5  # pixel centres
        return pixels, ~np.isnan(pixels[:, 0])

    def _render_through_water(self) -> np.ndarray:
        """The forward camera's image through the water of ``optics``."""
        mujoco.mj_forward(self.physics.model, self.physics.data)
        image, distance = self.camera_renderer.render_with_range(self.physics.data)
        return degrade_image(image, distance, self._optics, self.calibration.intrinsics.fy,
                             self.np_random)

    def _render_camera(self, renderer: CameraRenderer) -> np.ndarray:
        mujoco.mj_forward(self.physics.model, self.physics.data)
        return renderer.render(self.physics.data)

    def _info(self, truth: dict) -> dict:
        ep = self._episode
        state, judged = ep.state, ep.judged
        info = {
            "distance_to_entrance": truth["distance"],
            "longitudinal_error": truth["longitudinal"],
            "lateral_error": truth["lateral"],
            "vertical_error": truth["vertical"],
            "heading_error": truth["heading"],
            "docked": state.success,
            "is_success": state.success,
            "lights_visible": truth["n_visible"],
            "violation_fov": judged is not None and judged.fov_violation,
            "violation_behind_entrance": judged is not None and judged.behind_entrance,
            "violation_seabed": judged is not None and judged.seabed,
            "failure_reason": FAILURE_REASONS[state.failure - 1] if state.failure else "",
            "time": state.steps * self._dt,
            "true_position": np.array(truth["position"]),
            "true_euler": np.array(truth["euler"]),
            "true_velocity": np.array(truth["velocity"]),
            "true_pixels": truth["visible_pixels"],  # observations build their own arrays
            "true_visible": truth["visible"],
            "current": np.array(state.current, dtype=float),
        }
        if state.thrust is not None and state.steps:
            info["thrust"] = state.thrust
        return info

    def _episode_metrics(self, truth: dict) -> dict:
        state = self._episode.state
        metrics = {}
        for key, value in transition.summary(state, truth).items():
            if key == "failure":
                key, value = "failure_reason", failure_reason(value, state.success)
            elif key in NONE_IF_NAN and math.isnan(value):
                value = None
            metrics[key] = value
        return metrics


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


class DockingStationEnv(DockingEnv):
    __doc__ = DockingEnv.__doc__.replace(
        "AUV approach to a light-guided docking station ([OFNMPC] / [LAMP]).",
        "AUV approach to a seabed docking station guided by six lights around its "
        "entrance ([OFNMPC]).",
        1,
    ).replace(
        "**Version history.**",
        "Layout: six lights around the entrance [OFNMPC].\n\n    **Version history.**",
    )
    layout = SIX_LIGHTS


class LampArrayDockingEnv(DockingEnv):
    __doc__ = DockingEnv.__doc__.replace(
        "AUV approach to a light-guided docking station ([OFNMPC] / [LAMP]).",
        "AUV approach to a recovery fork guided by an L-shaped four-lamp array ([LAMP]).",
        1,
    ).replace(
        "**Version history.**",
        "Layout: L-shaped four-lamp array A, B, C, D [LAMP]; camera tilted 20 deg down."
        "\n\n    **Version history.**",
    )
    layout = LAMP_ARRAY
    #: ``difficulty`` levels: as :class:`DockingEnv`'s, with the laboratory water of [LAMP]
    #: at ``paper`` (:data:`PAPER_LAMP_ARRAY_OPTICS`).
    difficulty_presets = {
        "easy": {},
        "paper": {"disturbances": PAPER_DISTURBANCES, "optics": PAPER_LAMP_ARRAY_OPTICS,
                  "navigation": PAPER_NAVIGATION},
        "hard": {"disturbances": HARD_DISTURBANCES, "optics": HARD_OPTICS,
                 "navigation": HARD_NAVIGATION},
    }
