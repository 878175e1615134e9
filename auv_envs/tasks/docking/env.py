"""Docking-station approach guided by lights ([OFNMPC] and [LAMP]).

Two registered layouts share this file:

* ``auv_envs/DockingStation-v2``: six lights symmetric around the entrance
  [OFNMPC].
* ``auv_envs/LampArrayDocking-v2``: asymmetric L-shaped array of four lamps
  under a recovery fork [LAMP].
"""

from __future__ import annotations

import math
from typing import ClassVar

import mujoco
import numpy as np

from auv_envs.core import difficulty as levels
from auv_envs.core.camera import project_few
from auv_envs.core.env import CPUTask, ShellEpisode, check_choice, check_image_size
from auv_envs.core.hydrodynamics import HullForceModel
from auv_envs.core.ops import FLOATS
from auv_envs.core.plant import StagedIntegrator
from auv_envs.core.rendering import CameraRenderer
from auv_envs.core.vehicle import PlantPerturbation, VehicleParams
from auv_envs.tasks.docking import transition
from auv_envs.tasks.docking.config import (  # noqa: F401  (the names' home before the config)
    CONTROL_PERIOD,
    DEFAULT_DAMPING_MISMATCH,
    EASY_NAVIGATION,
    HARD_DISTURBANCES,
    HARD_NAVIGATION,
    HARD_OPTICS,
    INTEGRATORS,
    LAMP_ARRAY_PRESETS,
    OBS_MODES,
    PAPER_DISTURBANCES,
    PAPER_LAMP_ARRAY_OPTICS,
    PAPER_NAVIGATION,
    PAPER_OPTICS,
    PLANTS,
    SCENARIO_ATTITUDE_NOISE,
    SCENARIO_PIXEL_NOISE,
    SCENARIO_VELOCITY_NOISE,
    SCENARIO_YAW_RATE_NOISE,
    SCENARIOS,
    STATION_PRESETS,
    DockingCalibration,
    DockingConfig,
    DockingDisturbances,
    DockingSetup,
    nav_space,
    params,
)
from auv_envs.tasks.docking.navigation import NavigationSensors
from auv_envs.tasks.docking.optics import WaterOptics, degrade_image
from auv_envs.tasks.docking.plant import CompiledPlant, MujocoPlant, compiled_sensors
from auv_envs.tasks.docking.rules import FAILURE_REASONS, DockingTolerances, failure_reason
from auv_envs.tasks.docking.station import (
    CHASE_CAMERA,
    CHASE_HEADLIGHT,
    OWN_HULL_GROUP,
    RENDER_CAMERAS,
    DockingPhysics,
)
from auv_envs.tasks.docking.transition import (  # noqa: F401  (their home before the transition)
    SCENARIO_CURRENT_SPEED,
    START_HEADING_SPREAD_DEG,
    START_SURGE,
)

#: Summary entries reported as None where NaN (no docking, no hand-over).
NONE_IF_NAN = frozenset({"docking_time", *transition.MISSION_METRICS}) - {"path_length"}


class DockingTask(CPUTask):
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
    ``sensors``              str                    ``"numpy"``     the sensors' models on the
                                                                    CPU: ``"numpy"`` or
                                                                    ``"compiled"`` (the navigation
                                                                    sensors and the lamps'
                                                                    detection through the water,
                                                                    compiled calls; the same
                                                                    draws, the numbers equal at
                                                                    round-off). The batched envs
                                                                    run theirs on JAX either way
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

    #: The :class:`~auv_envs.tasks.docking.config.DockingConfig` fields this id fixes.
    _variant: ClassVar[dict] = {"layout": "six_lights"}
    #: The contract the registry-driven tests read (see tests/conftest.py).
    obs_modes = OBS_MODES
    #: ``difficulty`` levels (:mod:`auv_envs.core.difficulty`): the plant's
    #: disturbances, the water's optics and the navigation sensors
    #: (:data:`~auv_envs.tasks.docking.config.STATION_PRESETS`).
    difficulty_presets = STATION_PRESETS
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
        sensors: str = "numpy",
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
            physics_substeps=physics_substeps, plant=plant, sensors=sensors,
            render_mode=render_mode,
            render_camera=render_camera, render_size=render_size, disturbances=disturbances,
            optics=optics, navigation=navigation, difficulty=difficulty,
        )
        config = self._configuration(DockingConfig, **self._variant)
        check_choice("render_camera", render_camera, RENDER_CAMERAS)
        render_width, render_height = check_image_size(render_size, "render_size")
        self._init_kwargs["render_size"] = (render_width, render_height)
        self._use_setup(params(config))
        self.render_mode = render_mode
        model = self.physics.model
        width, height = self.setup.image_size
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

    def _use_setup(self, setup: DockingSetup) -> None:
        """Become the task of ``setup`` (:func:`~auv_envs.tasks.docking.config.params`): its
        model simulated here (the plant's integrator on it), its spaces, calibration,
        rules and transition parameters."""
        config = setup.config
        #: What the configuration fixes (:class:`~auv_envs.tasks.docking.config.DockingSetup`).
        self.setup = setup
        #: The difficulty level (:mod:`auv_envs.core.difficulty`).
        self.difficulty = config.difficulty
        self.obs_mode, self.scenario = config.obs_mode, config.scenario
        self.layout = setup.layout
        self._params = setup.vehicle
        #: The composed model's text (:class:`~auv_envs.core.assets.MJCF`).
        self.model_source = setup.model_source
        self._physics_substeps = config.physics_substeps
        self.physics = DockingPhysics(setup.model, len(setup.layout.light_labels))
        self.hull = HullForceModel(self._params, self.physics.hull_body, self.physics.qvel_adr)
        #: The plant's integrator: MuJoCo's, with the hull wrench at every stage.
        self.integrator = StagedIntegrator(setup.model, self.physics.data,
                                           self.hull.passive_force)
        self._dt = setup.dt
        #: The simulated vehicle's parameters (what the plant integrates), read-only.
        self.vehicle = self._params
        #: Control period, s (one env step).
        self.dt = setup.dt
        #: Steps of an episode that runs to its ``time_limit``.
        self.max_episode_steps = setup.max_episode_steps
        self.calibration = setup.calibration
        self._optics = setup.levels["optics"]
        #: The task's geometry and rules (:mod:`auv_envs.tasks.docking.rules`), which the
        #: batched environment evaluates too.
        self.rules = setup.rules
        self.action_space = setup.action_space
        self.observation_space = setup.observation_space
        #: The task as the transition sees it (:mod:`auv_envs.tasks.docking.transition`),
        #: which the batched environment runs too (with :class:`Navigation` on JAX where
        #: the CPU's sensors are compiled).
        self.params = setup.params
        if config.sensors == "compiled":
            self.params = compiled_sensors(setup.params)
        #: The navigation sensors (:mod:`auv_envs.tasks.docking.navigation`) of the ``nav`` modes.
        self.navigation = setup.levels["navigation"]

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

    def command(self, action: np.ndarray) -> list:
        """The transition takes the four commands as Python floats."""
        return action.tolist()

    def render_frame(self) -> np.ndarray:
        return self._render_camera(self._view)

    # ------------------------------------------------------------------ internals
    def truth_now(self) -> dict:
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
            self.calibration.intrinsics, self.rules.lights, cam_pos, truth.pop("camera_rows"),
            FLOATS)
        visible = phys.unoccluded(cam_pos, self.rules.lights, in_image)
        return transition.truth_with_lights(truth, np.array(pixels), np.array(visible), FLOATS)

    def observe(self, truth: dict):
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
        truth = self.truth_now()
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
                             self.rng)

    def _render_camera(self, renderer: CameraRenderer) -> np.ndarray:
        mujoco.mj_forward(self.physics.model, self.physics.data)
        return renderer.render(self.physics.data)

    def step_info(self, truth: dict) -> dict:
        ep = self._episode
        state, judged = ep.state, ep.judged
        # One new array, handed out in slices (a few NumPy calls cost more than the copy)
        motion = np.array((*truth["position"], *truth["euler"], *truth["velocity"],
                           *state.current), dtype=float)
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
            "true_position": motion[0:3],
            "true_euler": motion[3:6],
            "true_velocity": motion[6:12],
            "true_pixels": truth["visible_pixels"],  # observations build their own arrays
            "true_visible": truth["visible"],
            "current": motion[12:15],
        }
        if state.thrust is not None and state.steps:
            info["thrust"] = state.thrust
        return info

    def summarise(self, truth: dict) -> dict:
        state = self._episode.state
        metrics = {}
        for key, value in transition.summary(state, truth).items():
            if key == "failure":
                key, value = "failure_reason", failure_reason(value, state.success)
            elif key in NONE_IF_NAN and math.isnan(value):
                value = None
            metrics[key] = value
        return metrics



class DockingStationTask(DockingTask):
    __doc__ = DockingTask.__doc__.replace(
        "AUV approach to a light-guided docking station ([OFNMPC] / [LAMP]).",
        "AUV approach to a seabed docking station guided by six lights around its "
        "entrance ([OFNMPC]).",
        1,
    ).replace(
        "**Version history.**",
        "Layout: six lights around the entrance [OFNMPC].\n\n    **Version history.**",
    )
    _variant = {"layout": "six_lights"}


class LampArrayDockingTask(DockingTask):
    __doc__ = DockingTask.__doc__.replace(
        "AUV approach to a light-guided docking station ([OFNMPC] / [LAMP]).",
        "AUV approach to a recovery fork guided by an L-shaped four-lamp array ([LAMP]).",
        1,
    ).replace(
        "**Version history.**",
        "Layout: L-shaped four-lamp array A, B, C, D [LAMP]; camera tilted 20 deg down."
        "\n\n    **Version history.**",
    )
    _variant = {"layout": "lamp_array"}
    #: ``difficulty`` levels: as :class:`DockingTask`'s, with the laboratory water of [LAMP]
    #: at ``paper`` (:data:`~auv_envs.tasks.docking.config.LAMP_ARRAY_PRESETS`).
    difficulty_presets = LAMP_ARRAY_PRESETS
