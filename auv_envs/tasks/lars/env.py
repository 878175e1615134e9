"""Launch-and-recovery (LARS) capture of a surfaced AUV with stereo vision [LTAT].

Registered as ``auv_envs/LARSCapture-v0``. The episode is
:mod:`auv_envs.tasks.lars.transition`; this module is its task on the CPU (and
renders the ``stereo`` images). The scene (arm, AUV, marker, sea) is
described in :mod:`auv_envs.tasks.lars.scene`, the arm's kinematics and
dynamics in :mod:`auv_envs.tasks.lars.arm`, the opt-in irregular sea and sun
glint in :mod:`auv_envs.tasks.lars.sea`.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from auv_envs.core import difficulty as levels
from auv_envs.core import frames
from auv_envs.core.env import (
    CPUTask,
    ShellEpisode,
    check_choice,
    check_image_size,
)
from auv_envs.core.ops import FLOATS
from auv_envs.core.rendering import CameraRenderer
from auv_envs.tasks.lars import transition
from auv_envs.tasks.lars.calibration import (
    CaptureTolerances,
)
from auv_envs.tasks.lars.compiled import CompiledTruth
from auv_envs.tasks.lars.config import (  # noqa: F401  (the names' home before the config)
    CAMERA_MOUNT_IN_END,
    CAPTURE_TIP_IN_END,
    CONTROL_PERIOD,
    CONTROLS,
    DEFAULT_FOVY_DEG,
    DEFAULT_PIXEL_NOISE_STD,
    FRAME_SKIP,
    HARD_GLINT,
    HARD_PIXEL_NOISE_STD,
    HARD_SEA,
    OBS_MODES,
    PAPER_SEA,
    PARKED,
    PHYSICS_TIMESTEP,
    POSITION_GAINS,
    PRESETS,
    R_END_CV,
    RENDER_CAMERAS,
    SEA_STATES,
    WATERLINE_HALF_WIDTH,
    LARSConfig,
    LARSSetup,
    params,
)
from auv_envs.tasks.lars.physics import LARSPhysics
from auv_envs.tasks.lars.scene import (
    AUVMotion,
)
from auv_envs.tasks.lars.sea import (
    GlintField,
    SunGlint,
)
from auv_envs.tasks.lars.waves import SeaSpectrum


class LARSCaptureTask(CPUTask):
    """Capture of a surfaced AUV by a ship's launch-and-recovery arm [LTAT].

    **Description.** The side of a mother ship carries a 3-DOF articulated
    LARS arm (slew, shoulder, elbow; boom 2.2 m / 80 kg, jib 1.8 m / 45 kg,
    a 20 kg capture head at the tip), simulated in MuJoCo with joint and
    torque limits, so that M(q), C(q, qd) and G(q) of eq. 29 all matter. The
    capture head is held level by a gimbal; it carries the capture device
    (its tip 0.35 m below the head) and a binocular camera looking straight
    down. A surfaced Explore-100-like AUV (1.8 m x 0.2 m, 47 kg; upper
    surface 5 cm above the local water) floats beside the ship with the
    isosceles-triangle marker (0.15, 0.4, 0.4 m) on its top, moving as in the
    paper's test case (§2.3): uniform surge, sinusoidal heave of 0.2 m
    amplitude, constant yaw and pitch offsets. The opaque sea surface hides
    what is below it. In ``severe`` sea, crests wash over the AUV and hide
    the marker for stretches of time, and two floating look-alikes
    ("analogs": 0.9 m hulls with a 0.8x red triangle) drift in view. World
    frame: x along the ship, y outboard, z up, calm water at z = 0.

    With a ``sea`` (:mod:`auv_envs.tasks.lars.sea`) the sinusoid gives way to
    an irregular long-crested sea (a seeded sum of harmonics of a JONSWAP/PM
    spectrum): the AUV heaves, rolls and pitches with the surface under its
    hull, the analogs with the water at their places, and the ship (linear
    RAOs of a ~32 m vessel) carries the arm; wash-over timing and the number
    of analogs follow ``Hs``. With a ``glint``
    (:class:`~auv_envs.tasks.lars.sea.SunGlint`) the sun glitters on a
    Cox–Munk sea: saturated spots in ``stereo`` images; in ``features`` a
    glint near a corner takes the corner detector.

    **Action space.** ``Box(-1, 1, (3,), float32)``, one entry per joint.
    ``control="torque"``: joint torques as fractions of ``calibration.torque_limits``,
    gravity not compensated. ``control="position"``: joint-angle targets, -1..1 mapped
    linearly onto the joint limits (``calibration.joint_limits``;
    ``env.position_action(q, np)`` inverts the map), tracked by a computed-torque loop at the
    physics rate (eq. 30 gains Kp = 160, Kd = 20 through eq. 29's model). Finite values
    outside [-1, 1] are clipped; NaN, inf and non-numbers raise ``ValueError``.

    =====  ========  ===  ===  ========================  ===========================================
    index  joint     min  max  torque (``"torque"``)     angle target (``"position"``)
    =====  ========  ===  ===  ========================  ===========================================
    0      slew      -1   1    fraction of 1000 N m      -1..1 onto [-1.3, 1.3] rad
    1      shoulder  -1   1    fraction of 4000 N m      -1..1 onto [-1.0, 1.2] rad
    2      elbow     -1   1    fraction of 1500 N m      -1..1 onto [-2.6, 0.0] rad
    =====  ========  ===  ===  ========================  ===========================================

    **Observation space** (``obs_mode``). World frame as above; with a ``sea`` the arm's
    end moves with the ship. Angles in rad.

    ``state``: ``Box(-inf, inf, (24,), float32)``, privileged (the ground truth, as in
    ``info``):

    =====  ============================================================================  ===========
    index  observation                                                                   unit
    =====  ============================================================================  ===========
    0      slew angle                                                                    rad
    1      shoulder angle                                                                rad
    2      elbow angle                                                                   rad
    3      slew rate                                                                     rad/s
    4      shoulder rate                                                                 rad/s
    5      elbow rate                                                                    rad/s
    6      arm end (the capture head's centre) x (``info["end_position"]``)              m
    7      arm end y                                                                     m
    8      arm end z                                                                     m
    9      arm-end velocity x                                                            m/s
    10     arm-end velocity y                                                            m/s
    11     arm-end velocity z                                                            m/s
    12     AUV CG minus arm end, x (``info["relative_position"]``)                       m
    13     AUV CG minus arm end, y                                                       m
    14     AUV CG minus arm end, z                                                       m
    15     AUV velocity x: the surge (``info["true_velocity"]``)                         m/s
    16     AUV velocity y (always 0)                                                     m/s
    17     AUV velocity z: the heave rate                                                m/s
    18     capture point minus capture tip, x (``info["capture_offset"]``)               m
    19     capture point minus capture tip, y                                            m
    20     capture point minus capture tip, z                                            m
    21     AUV pitch, + nose up (``info["true_pitch"]``): the episode's offset, plus     rad
           the waves' with a ``sea``
    22     AUV yaw, the episode's constant offset (``info["true_yaw"]``)                 rad
    23     water level at the AUV, z of the surface (``info["water_level"]``)            m
    =====  ============================================================================  ===========

    ``features`` and ``stereo``: ``Dict``:

    ==================  =========  =======  ============================================  ==========
    key                 shape      dtype    observation                                   unit
    ==================  =========  =======  ============================================  ==========
    ``pixels``          (2, 3, 2)  float32  ``features``: the marker corners' (u, v) at   px
                                            ``image_size``, indexed (camera, corner,
                                            u/v): camera 0 left, 1 right; corner 0 A1
                                            (port base), 1 A2 (starboard base), 2 A3
                                            (apex). Gaussian noise
                                            (``pixel_noise_std``), zero where not seen,
                                            clipped to [-W, 2W] x [-H, 2H]; with a
                                            ``glint``, a corner a glint takes is
                                            reported at the glint
    ``visible``         (2, 3)     int8     ``features``: ``MultiBinary((2, 3))``, 1      -
                                            where that camera sees the corner (inside
                                            its image, not under a crest, not lost under
                                            a glint's bloom)
    ``left``            (H, W, 3)  uint8    ``stereo``: the left camera's image           -
    ``right``           (H, W, 3)  uint8    ``stereo``: the right camera's image,         -
                                            rendered in the same pass
    ``joint_position``  (3,)       float32  both modes: slew, shoulder, elbow angles      rad
                                            (exact; bounds: the joint limits +-0.5 rad)
    ``joint_velocity``  (3,)       float32  both modes: the joint rates (exact)           rad/s
    ==================  =========  =======  ============================================  ==========

    **Rewards** (each in ``info["reward_<term>"]``, summing to the reward):

    ============  =======================================================
    term          value
    ============  =======================================================
    ``progress``  decrease of the capture error (m)
    ``control``   -0.001 |a|^2
    ``success``   +10 once, on capture
    ``failure``   -10 once, on failing
    ============  =======================================================

    **Starting state.** The AUV's motion from ``scene.MOTION_RANGES``: CG x0
    in [-0.4, 0.4] m, y0 in [1.9, 2.2] m, surge 0.03-0.12 m/s, heave period
    5-9 s and phase, yaw -30..30 deg, pitch -4..4 deg
    (``reset(options={"motion": {...}})`` pins any of them). The arm starts at
    rest with its end 0.8 m above the AUV's top line and the cameras over the
    AUV (offset up to 0.2 m along x, 0.1 m along y). Severe sea also draws the
    wash-over schedule and the analogs' offsets and drifts; a ``sea`` its
    direction (``options={"wave_heading": rad}`` pins it) and realisation; a
    ``glint`` the sun's elevation and azimuth. The order of the draws:
    ``docs/environments.md``.

    **Episode end.** Success (terminated): the capture tip within 0.05 m of
    the capture point (lifting eye, 0.45 m aft of the CG on the top line)
    with a relative speed below 0.25 m/s (``CaptureTolerances``). Failure
    (terminated): ``collision`` (the tip enters the hull without capturing)
    or ``workspace`` (the arm end leaves ``calibration.workspace``).
    Truncated after ``time_limit`` s.

    **Info.** Every step: ``capture_error`` (m), ``capture_offset`` (3),
    ``relative_position`` (3), ``relative_speed`` (m/s), ``is_success``,
    ``collision``, ``violation_workspace``, ``marker_visible`` (corners seen
    in both images, 0-3), ``marker_occluded``, ``distractors_in_view``,
    ``failure_reason``, ``time``, the reward terms, and ground truth for
    metrics (``true_position``, ``true_velocity``, ``true_pitch``,
    ``true_yaw``, ``true_corners``, ``true_pixels``, ``true_visible``,
    ``end_position``, ``water_level``). With a ``sea`` also ``true_roll`` and
    ``ship_motion`` (heave, roll, pitch), and at reset ``sea``
    (``hs_realised``, ``sea_state_code``, ``components``, ``wave_heading``,
    ``wash_period``, ``wash_duration``, ``analogs``). With a ``glint``: at
    reset ``glint`` (``sun_elevation``, ``sun_azimuth``, ``slope_variance``),
    every step ``glint_corners`` (2, 3) int8 (0 clean, 1 taken by a glint, 2
    lost under its bloom), in ``features`` ``glint_probability``, in
    ``stereo`` ``glints_in_view`` and ``glint_expected``. At the end
    ``episode_metrics``.

    **Arguments.**

    ===================  ===================  ==============  ======================================
    argument             Type                 Default         meaning
    ===================  ===================  ==============  ======================================
    ``obs_mode``         str                  ``"state"``     ``"state"``, ``"features"``,
                                                              ``"stereo"``
    ``sea_state``        str                  ``"calm"``      ``"calm"`` (no interference) or
                                                              ``"severe"``
    ``control``          str                  ``"torque"``    ``"torque"`` or ``"position"``
    ``image_size``       tuple[int, int]      ``(640, 480)``  (W, H) of the cameras, also the pixel
                                                              frame of ``features`` (the paper used
                                                              1280x960)
    ``baseline``         float                ``0.12``        stereo baseline, m (in (0, 1])
    ``focal_length``     float | None         ``None``        px at ``image_size`` (None: 60 deg
                                                              vertical field of view,
                                                              ``DEFAULT_FOVY_DEG``)
    ``pixel_noise_std``  float | None         ``None``        px (None: the level's; 1.0,
                                                              ``DEFAULT_PIXEL_NOISE_STD``, at
                                                              ``easy``/``paper``)
    ``tolerances``       CaptureTolerances |  ``None``        capture tolerances (None:
                         None                                 ``CaptureTolerances()``, 0.05 m and
                                                              0.25 m/s)
    ``time_limit``       float                ``30.0``        s
    ``render_mode``      str | None           ``None``        ``"rgb_array"`` or None
    ``render_camera``    str                  ``"side"``      ``"side"`` (from outboard and astern)
                                                              or ``"stereo"`` (the pair side by
                                                              side)
    ``render_size``      tuple[int, int]      ``(640, 480)``  (W, H) of ``render()``
    ``sea``              SeaSpectrum | None   ``None``        :class:`SeaSpectrum` or None (the
                                                              level's; the [LTAT] sinusoid at
                                                              ``easy``)
    ``glint``            SunGlint | bool |    ``None``        :class:`SunGlint`, ``False`` (off) or
                         None                                 None (the level's)
    ``difficulty``       str                  ``"easy"``      ``DEFAULT_LEVEL``: ``"easy"`` (the
                                                              release), ``"paper"``
                                                              (``sea=PAPER_SEA``, JONSWAP Hs 0.3 m,
                                                              Tp 9 s), ``"hard"`` (``HARD_SEA`` Hs
                                                              0.4 m, Tp 7 s, 3 px noise,
                                                              ``HARD_GLINT``); explicit ``sea``,
                                                              ``pixel_noise_std`` and ``glint``
                                                              override the level's
                                                              (``docs/difficulty.md``)
    ===================  ===================  ==============  ======================================

    **Version history.** v0: initial release. Changes within v0 (rendering,
    opt-in seas, levels and glint, each leaving the default episodes
    unchanged bit for bit): ``CHANGELOG.md``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}
    _closeables = ("camera_renderer", "_view")

    obs_modes = OBS_MODES
    #: ``difficulty`` levels (:mod:`auv_envs.core.difficulty`): the sea and the pixel noise.
    difficulty_presets = PRESETS
    transition = transition
    reward_terms = transition.REWARD_TERMS
    metric_keys = (
        "capture_error", "relative_position", "relative_speed", "is_success", "collision",
        "violation_workspace", "marker_visible", "marker_occluded", "distractors_in_view",
    )

    def __init__(
        self,
        obs_mode: str = "state",
        sea_state: str = "calm",
        control: str = "torque",
        image_size: tuple[int, int] = (640, 480),
        baseline: float = 0.12,
        focal_length: float | None = None,
        pixel_noise_std: float | None = None,
        tolerances: CaptureTolerances | None = None,
        time_limit: float = 30.0,
        render_mode: str | None = None,
        render_camera: str = "side",
        render_size: tuple[int, int] = (640, 480),
        sea: SeaSpectrum | None = None,
        glint: SunGlint | bool | None = None,
        difficulty: str = levels.DEFAULT_LEVEL,
        **unknown,
    ):
        self._accept_arguments(
            unknown,
            obs_mode=obs_mode, sea_state=sea_state, control=control,
            image_size=tuple(image_size), baseline=baseline, focal_length=focal_length,
            pixel_noise_std=pixel_noise_std, tolerances=tolerances, time_limit=time_limit,
            render_mode=render_mode, render_camera=render_camera,
            render_size=render_size, sea=sea, glint=glint, difficulty=difficulty,
        )
        config = self._configuration(LARSConfig)
        check_choice("render_camera", render_camera, RENDER_CAMERAS)
        render_width, render_height = check_image_size(render_size, "render_size")
        self._init_kwargs["render_size"] = (render_width, render_height)
        setup = params(config)
        #: What the configuration fixes (:class:`~auv_envs.tasks.lars.config.LARSSetup`).
        self.setup = setup
        #: The difficulty level (:mod:`auv_envs.core.difficulty`).
        self.difficulty = difficulty
        #: The sun-glint model (``SunGlint``), None when off.
        self.glint = setup.levels["glint"]
        self.obs_mode, self.sea_state, self.control = obs_mode, sea_state, control
        self.render_mode = render_mode
        #: The arm model's text (:class:`~auv_envs.core.assets.MJCF`: what the physics
        #: simulates; the scene around it is drawn only).
        self.model_source = setup.model_source
        scene_model = setup.scene_model
        self.physics = LARSPhysics(scene_model, setup.model)
        self._arm = setup.arm
        self._dt = setup.dt
        #: Step period, s (one env step).
        self.dt = self._dt
        #: Steps of an episode that runs to its ``time_limit``.
        self.max_episode_steps = setup.max_episode_steps
        self.calibration = setup.calibration
        self.action_space = setup.action_space
        self.observation_space = setup.observation_space
        width, height = self._width, self._height = setup.image_size
        self._glint_camera = setup.glint_camera
        #: The transition's :class:`~auv_envs.tasks.lars.transition.LARSParams`.
        self.params = setup.params
        self._plant = _MujocoArm(self)
        # One renderer for the stereo observation, one for render().
        self.camera_renderer: CameraRenderer | None = None
        if obs_mode == "stereo":
            self.camera_renderer = CameraRenderer(scene_model, ("left", "right"), width,
                                                  height)
        self._view: CameraRenderer | None = None
        if render_mode == "rgb_array":
            side = render_camera == "side"
            self._view = CameraRenderer(
                scene_model, ("side",) if side else ("left", "right"), render_width,
                render_height, skybox=side,
            )
        self._episode = ShellEpisode()

    # ------------------------------------------------------------------ episode hooks
    def _begin_episode(self, rng: np.random.Generator, options: dict | None):
        _, state, truth, obs, _ = transition.reset(self.params, self._backend(rng), options)
        self._episode = ShellEpisode(state, obs)
        return truth, transition.reset_info(self.params, state)

    def truth_now(self) -> dict:
        return transition.truth_now(self.params, self.physics.data, self._episode.state,
                                    self._plant, FLOATS)

    def observe(self, truth: dict):
        ep = self._episode
        if self.obs_mode != "stereo":
            return ep.obs  # the transition's
        field = ep.state.scene.glint
        if field is None:
            pair = self._render_pair()
        else:
            self._pose_scene()
            pair, ranges = self.camera_renderer.render_with_range(self.physics.scene_data)
            pair, frame = self._glint_camera.on_pair(field, truth, pair, ranges, self.rng)
            ep.state = transition.with_glint_frame(ep.state, frame, FLOATS)
        w = self._width
        return {"left": np.ascontiguousarray(pair[:, :w]),
                "right": np.ascontiguousarray(pair[:, w:]), **ep.obs}

    def step_info(self, truth: dict) -> dict:
        ep = self._episode
        return transition.info(self.params, ep.state, truth, ep.judged)

    def summarise(self, truth: dict) -> dict:
        return transition.episode_metrics(self.params, self._episode.state, truth)

    def render_frame(self) -> np.ndarray:
        self._pose_scene()
        return self._view.render(self.physics.scene_data)

    # ------------------------------------------------------------------ internals
    @property
    def auv_motion(self) -> AUVMotion | None:
        """The episode's AUV motion (surge, sway, heave sinusoid, attitude; drawn at
        reset, None before the first)."""
        state = self._episode.state
        return None if state is None else state.scene.motion

    @property
    def glint_field(self) -> GlintField | None:
        """The episode's sun-glint field (``glint``; None without glint or before the
        first reset)."""
        state = self._episode.state
        return None if state is None else state.scene.glint

    def position_action(self, q, xp) -> np.ndarray:
        """The ``control="position"`` action whose joint targets are ``q`` (rad, (..., 3)):
        the inverse of the action's linear map onto the joint limits (not clipped);
        ``xp``: NumPy, or ``jax.numpy`` for traced angles (the setup's)."""
        return self.setup.position_action(q, xp)

    def _pose_scene(self) -> None:
        """Pose the kinematic bodies (AUV, sea, head, analogs) for rendering.

        The physics never reads them; they are posed only before a render.
        """
        phys = self.physics
        state = self._episode.state
        scene = state.scene
        t = state.steps * self._dt
        sample = transition.sea_sample(scene, t)
        pos = transition.auv_position(scene, t, sample, FLOATS)
        q = phys.data.qpos
        end = self._arm.forward_kinematics(q)
        ship = None
        if sample is None:
            level = pos[2] - transition.Z_CENTRE
            quat = scene.motion.quaternion()
        else:
            level = sample.level
            roll, pitch = transition.auv_attitude(scene, sample)
            quat = frames.quat_from_euler(roll, -pitch, scene.motion.yaw, np)
            pose = transition.ship_pose(self.params, sample, FLOATS)
            end = pose.carry(*end.tolist(), 0.0, 0.0, 0.0)[:3]
            ship = pose.transform()
        phys.pose("water", (0.0, 0.0, level), (1.0, 0.0, 0.0, 0.0))
        phys.pose("auv", pos, quat)
        half = 0.5 * float(q[0])
        phys.pose("head", end, (math.cos(half), 0.0, 0.0, math.sin(half)))
        crest = PARKED
        if scene.wash is not None:
            active, centre = transition.crest_centre(scene, t, pos, level)
            crest = centre if active else PARKED
        phys.pose("crest", crest, (1.0, 0.0, 0.0, 0.0))
        for k in range(2):
            if k < len(scene.analogs):
                centre, yaw = transition.analog_pose(scene, k, t, pos, sample, FLOATS)
                quat = (math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0))
            else:
                centre, quat = PARKED, (1.0, 0.0, 0.0, 0.0)
            phys.pose(f"analog_{k}", centre, quat)
        phys.refresh_kinematics(ship)

    def _render_pair(self) -> np.ndarray:
        """Left and right images side by side, (H, 2 W, 3), one rendering pass."""
        self._pose_scene()
        return self.camera_renderer.render(self.physics.scene_data)


class _MujocoArm:
    """The LARS transition's plant on the CPU: the env's MuJoCo arm, driven by joint
    torques (``control="torque"``) or by the computed-torque loop of [LTAT] eqs. 29-30
    at the physics rate (``control="position"``). Its state is the env's ``MjData``,
    which MuJoCo integrates in place (:mod:`auv_envs.core.task`)."""

    def __init__(self, env: LARSCaptureTask):
        self.model, self.data = env.physics.model, env.physics.data
        self.physics = env.physics
        self.torque_mode = env.control == "torque"
        self.dt = env.dt
        self.q_mid, self.q_half = env.params.joint_mid, env.params.joint_half
        self.kp, self.kd = env.calibration.position_gains
        self.limits = env.calibration.torque_limits
        self.tau = np.zeros(3)
        self._compiled = None

    def place(self, q):
        self.physics.reset(q)
        return self.data

    def joints(self) -> tuple[list, list]:
        return self.data.qpos.tolist(), self.data.qvel.tolist()

    def truth(self, arm, params, scene, steps, ops) -> dict:
        """The truth after a move: compiled without a sea model, in floats with one."""
        if scene.sea is None:
            if self._compiled is None:  # built on first use: the sea ids never need it
                self._compiled = CompiledTruth(params, self.data.qpos, self.data.qvel)
            return self._compiled(scene, steps)
        return transition.truth(params, scene, steps, *self.joints(), ops)

    def advance(self, arm, action: np.ndarray, effort: float) -> tuple:
        """One control period under ``action``: ``(arm, effort)``, the control effort with
        the period's added."""
        model, data = self.model, self.data
        if self.torque_mode:
            a0, a1, a2 = action.tolist()
            data.ctrl[:] = action
            mujoco.mj_step(model, data, FRAME_SKIP)
            # |a|^2 in floats: a @ a costs more than the sum
            return arm, effort + (a0 * a0 + a1 * a1 + a2 * a2) * self.dt
        q_target = self.q_mid + action * self.q_half
        tau = self.tau
        for _ in range(FRAME_SKIP):
            mujoco.mj_step1(model, data)
            accel = self.kp * (q_target - data.qpos) - self.kd * data.qvel
            mujoco.mj_mulM(model, data, tau, accel)
            tau += data.qfrc_bias
            np.clip(tau / self.limits, -1.0, 1.0, out=data.ctrl)
            effort += float(data.ctrl @ data.ctrl) * PHYSICS_TIMESTEP
            mujoco.mj_step2(model, data)
        return arm, effort
