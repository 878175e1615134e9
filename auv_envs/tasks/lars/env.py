"""Launch-and-recovery (LARS) capture of a surfaced AUV with stereo vision [LTAT].

Registered as ``auv_envs/LARSCapture-v0``. The scene (arm, AUV, marker, sea)
is described in :mod:`auv_envs.tasks.lars.scene`, the arm's kinematics and
dynamics in :mod:`auv_envs.tasks.lars.arm`, the opt-in irregular sea and sun
glint in :mod:`auv_envs.tasks.lars.sea`.
"""

from __future__ import annotations

import dataclasses
import math
import operator

import mujoco
import numpy as np
from gymnasium import spaces

from auv_envs.core import difficulty as levels
from auv_envs.core import frames
from auv_envs.core.camera import CameraIntrinsics, pixel_space, project_few
from auv_envs.core.env import (
    ActionValidator,
    TaskEnv,
    check_choice,
    check_image_size,
)
from auv_envs.core.rendering import CameraRenderer
from auv_envs.core.sea import FloatingAnalog, WashOver, heave, segments_cross_box
from auv_envs.tasks.lars.arm import ArmModel
from auv_envs.tasks.lars.calibration import (
    CaptureTolerances,
    LARSCalibration,
    read_only,
    read_only_pose,
)
from auv_envs.tasks.lars.glint import GlintCamera
from auv_envs.tasks.lars.physics import LARSPhysics
from auv_envs.tasks.lars.scene import (
    ANALOG_MARKER_BASE_X,
    ANALOG_SCALE,
    AUV_DIAMETER,
    AUV_FREEBOARD,
    AUV_LENGTH,
    AUV_MASS,
    CAPTURE_POINT_BODY,
    MARKER_SIDES,
    AUVMotion,
    MarkerGeometry,
    build_lars_model,
    sample_motion,
    uniform_draws,
)
from auv_envs.tasks.lars.sea import (
    EpisodeSea,
    GlintField,
    LARSSeaModel,
    SeaSample,
    ShipPose,
    SunGlint,
    sample_waves,
)
from auv_envs.tasks.lars.stereo import StereoRig
from auv_envs.tasks.lars.waves import SeaSpectrum, WaveRealisation, sea_state_code

OBS_MODES = ("state", "features", "stereo")
SEA_STATES = ("calm", "severe")
CONTROLS = ("torque", "position")

PHYSICS_TIMESTEP = 0.01
FRAME_SKIP = 4
#: Seconds per env step (``calibration.control_period``).
CONTROL_PERIOD = PHYSICS_TIMESTEP * FRAME_SKIP
#: [LTAT], eq. 30: Kp = 160, Kd = 20, used by ``control="position"`` as the
#: acceleration gains of a computed-torque inner loop (eqs. 29-30).
POSITION_GAINS = (160.0, 20.0)
#: Capture head geometry in the arm-end frame (x along the ship at q1 = 0,
#: y outboard, z up): the capture device's tip hangs below the head centre,
#: the stereo pair sits outboard of it looking straight down.
CAPTURE_TIP_IN_END = (0.0, 0.0, -0.35)
CAMERA_MOUNT_IN_END = (0.0, 0.25, -0.065)
#: ``render_camera`` values: ``"side"`` (a person's view of the ship's side,
#: the arm and the AUV) or ``"stereo"`` (the capture head's pair).
RENDER_CAMERAS = ("side", "stereo")
#: ``features`` pixel noise of the released env (``difficulty="easy"``), px.
DEFAULT_PIXEL_NOISE_STD = 1.0
#: ``difficulty="paper"``: a low swell, JONSWAP (gamma 3.3, the JONSWAP mean;
#: Hasselmann et al. 1973, DNV-RP-C205 §3.5.5), Hs = 0.3 m (the middle of
#: WMO sea state code 2, "smooth", 0.1-0.5 m), Tp = 9 s (the long end of the
#: scene's 5-9 s heave periods). The AUV's largest heave excursion in a
#: 30 s episode then averages 0.17 m, near the 0.2 m amplitude the paper's
#: sine has on every cycle (§3.1, Figs. 9/14c). Calibrated so that ``ckf-pd`` and
#: ``ltat-ckf-pd`` keep [LTAT]'s capture (Fig. 15c, about 28 mm, success
#: >= 90 %) in ``sea_state="calm"``; figures in ``docs/difficulty.md``.
PAPER_SEA = SeaSpectrum(hs=0.3, tp=9.0)
#: ``difficulty="hard"``: a steeper, shorter sea, JONSWAP Hs = 0.4 m, Tp = 7 s
#: (still code 2; Tp the agents' prior swell period), whose heave is less
#: regular than eq. 8's sinusoid, and 3 px of ``features`` pixel noise (the
#: largest corner error the shipped LTAT corner extractor made on 1,251
#: fully visible views, ``docs/reproductions.md``, taken as the noise std).
#: Calibrated so that ``ckf-pd`` succeeds in at most 80 % of episodes while
#: the privileged ``ckf-pd-state`` stays at >= 90 % (``docs/difficulty.md``).
HARD_SEA = SeaSpectrum(hs=0.4, tp=7.0)
HARD_PIXEL_NOISE_STD = 3.0
#: ``difficulty="hard"``: sun glint (:class:`~auv_envs.tasks.lars.sea.SunGlint`)
#: under a sun 40-80 deg high, any azimuth: the sun around noon from the
#: equinox to the solstice between latitudes 30 and 50 deg (noon elevation
#: 90 deg - latitude + declination, declination 0-23.4 deg); the wind is the
#: one that raises ``HARD_SEA`` (4.3 m/s, Cox–Munk sigma^2 = 0.025). Not at
#: ``paper``: [LTAT] reports no glint, and that level is calibrated without.
HARD_GLINT = SunGlint(sun_elevation=(math.radians(40.0), math.radians(80.0)))

#: Rotation from the OpenCV camera frame to the arm-end frame (looking down,
#: image x along end x, image y down = end -y).
R_END_CV = np.diag([1.0, -1.0, -1.0])
#: Where the analogs wait while not in play (far below the opaque surface).
PARKED = (0.0, 0.0, -50.0)
DEFAULT_FOVY_DEG = 60.0
#: Half-width of the hull's waterline, m: where the water meets the hull
#: floating ``AUV_FREEBOARD`` proud (the hull's footprint seen from above).
WATERLINE_HALF_WIDTH = math.sqrt(
    (AUV_DIAMETER / 2.0) ** 2 - (AUV_DIAMETER / 2.0 - AUV_FREEBOARD) ** 2)


@dataclasses.dataclass
class _EpisodeState:
    """Everything that changes during an episode besides MuJoCo's state."""

    motion: AUVMotion | None = None
    wash: WashOver | None = None
    analogs: tuple[FloatingAnalog, ...] = ()
    waves: WaveRealisation | None = None
    glint: GlintField | None = None
    #: The last observation's glint (:meth:`LARSCaptureEnv._info` reports it).
    glint_frame: dict | None = None
    steps: int = 0
    prev_error: float = 0.0
    done: bool = False
    success: bool = False
    failure_reason: str = ""
    capture_time: float | None = None
    min_error: float = math.inf
    visible_steps: int = 0
    occluded_steps: int = 0
    distractor_steps: int = 0
    glint_steps: int = 0
    control_effort: float = 0.0


class LARSCaptureEnv(TaskEnv):
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

    **Action space.** ``Box(-1, 1, (3,))``. ``control="torque"``: joint
    torques (slew, shoulder, elbow) as fractions of
    ``calibration.torque_limits`` (1000, 4000, 1500 N m), gravity not
    compensated. ``control="position"``: joint-angle targets, -1..1 mapped
    onto the joint limits, tracked by a computed-torque loop at the physics
    rate (eq. 30 gains Kp = 160, Kd = 20 through eq. 29's model). Finite
    values outside [-1, 1] are clipped; NaN, inf and non-numbers raise
    ``ValueError``.

    **Observation space** (``obs_mode``):

    ============  ===========================================================
    mode          space
    ============  ===========================================================
    ``state``     ``Box((24,), float32)``, privileged: joint angles (3) and
                  rates (3), arm-end position (3) and velocity (3), AUV CG
                  minus arm end (3), AUV velocity (3), capture point minus
                  capture tip (3), AUV pitch and yaw (2), water level (1)
    ``features``  ``Dict``: ``pixels`` (2, 3, 2) float32, the marker corners
                  A1 (port base), A2 (starboard base), A3 (apex) in the left
                  (0) and right (1) images at ``image_size``, with Gaussian
                  noise (``pixel_noise_std``), zero where not seen;
                  ``visible`` ``MultiBinary((2, 3))``; ``joint_position``
                  (3), ``joint_velocity`` (3)
    ``stereo``    ``Dict``: ``left`` and ``right`` (H, W, 3) uint8 images
                  rendered in one pass, ``joint_position``,
                  ``joint_velocity``
    ============  ===========================================================

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

    ====================  ===================================================
    argument              meaning (default)
    ====================  ===================================================
    ``obs_mode``          ``"state"``, ``"features"``, ``"stereo"``
    ``sea_state``         ``"calm"`` (no interference) or ``"severe"``
    ``control``           ``"torque"`` or ``"position"`` (``"torque"``)
    ``image_size``        (W, H) of the cameras, also the pixel frame of
                          ``features`` (640x480; the paper used 1280x960)
    ``baseline``          m (0.12)
    ``focal_length``      px at ``image_size`` (60 deg vertical field of view)
    ``pixel_noise_std``   px (None: the level's, 1.0 at ``easy``/``paper``)
    ``tolerances``        ``CaptureTolerances``
    ``time_limit``        s (30)
    ``render_mode``       ``"rgb_array"`` or None
    ``render_camera``     ``"side"`` (from outboard and astern) or
                          ``"stereo"`` (the pair side by side)
    ``render_size``       (W, H) of ``render()`` (640x480)
    ``sea``               :class:`~auv_envs.tasks.lars.sea.SeaSpectrum` or
                          None (the [LTAT] sinusoid)
    ``glint``             :class:`~auv_envs.tasks.lars.sea.SunGlint`,
                          ``False`` (off) or None (the level's)
    ``difficulty``        ``"easy"`` (the release), ``"paper"``
                          (``sea=PAPER_SEA``, JONSWAP Hs 0.3 m, Tp 9 s),
                          ``"hard"`` (``HARD_SEA`` Hs 0.4 m, Tp 7 s, 3 px
                          noise, ``HARD_GLINT``); explicit ``sea``,
                          ``pixel_noise_std`` and ``glint`` override the
                          level's (``docs/difficulty.md``)
    ====================  ===================================================

    **Version history.** v0: initial release. Changes within v0 (rendering,
    opt-in seas, levels and glint, each leaving the default episodes
    unchanged bit for bit): ``CHANGELOG.md``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}
    _closeables = ("camera_renderer", "_view")

    obs_modes = OBS_MODES
    #: ``difficulty`` levels (:mod:`auv_envs.core.difficulty`): the sea and the pixel noise.
    difficulty_presets = {
        "easy": {},
        "paper": {"sea": PAPER_SEA},
        "hard": {"sea": HARD_SEA, "pixel_noise_std": HARD_PIXEL_NOISE_STD,
                 "glint": HARD_GLINT},
    }
    reward_terms = ("progress", "control", "success", "failure")
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
        level = self._apply_difficulty(difficulty, sea=sea, pixel_noise_std=pixel_noise_std,
                                       glint=glint)
        sea, pixel_noise_std, glint = level["sea"], level["pixel_noise_std"], level["glint"]
        if glint is False:
            glint = None
        if glint is not None and not isinstance(glint, SunGlint):
            raise TypeError(f"glint must be a SunGlint, False or None, got {glint!r}")
        if pixel_noise_std is None:
            pixel_noise_std = DEFAULT_PIXEL_NOISE_STD
        check_choice("sea_state", sea_state, SEA_STATES)
        sea_model = None if sea is None else LARSSeaModel.from_spectrum(sea)
        #: The sun-glint model (``SunGlint``), None when off.
        self.glint = glint
        self._glint_slope_variance = (
            None if glint is None else glint.slope_variance(None if sea is None else sea.hs))
        check_choice("render_camera", render_camera, RENDER_CAMERAS)
        render_width, render_height = check_image_size(render_size, "render_size")
        self._init_kwargs["render_size"] = (render_width, render_height)
        check_choice("control", control, CONTROLS)
        width, height = check_image_size(image_size)
        if not (math.isfinite(baseline) and 0.0 < baseline <= 1.0):
            raise ValueError(f"baseline must be in (0, 1] m, got {baseline}")
        if focal_length is None:
            fovy = DEFAULT_FOVY_DEG
        elif math.isfinite(focal_length) and focal_length > 0:
            fovy = math.degrees(2.0 * math.atan(0.5 * height / focal_length))
        else:
            raise ValueError(f"focal_length must be positive (pixels), got {focal_length}")
        if not (math.isfinite(pixel_noise_std) and pixel_noise_std >= 0):
            raise ValueError(f"pixel_noise_std must be >= 0, got {pixel_noise_std}")
        if not (math.isfinite(time_limit) and time_limit > 0):
            raise ValueError(f"time_limit must be positive, got {time_limit}")

        self.obs_mode = obs_mode
        self.sea_state = sea_state
        self.control = control
        self.render_mode = render_mode
        self._time_limit = float(time_limit)

        marker = MarkerGeometry.on_cylinder()
        analog_marker = MarkerGeometry.on_cylinder(
            tuple(s * ANALOG_SCALE for s in MARKER_SIDES), base_x=ANALOG_MARKER_BASE_X
        )
        model = build_lars_model(float(baseline), fovy, marker, analog_marker)
        self.physics = LARSPhysics(model)
        arm = ArmModel(model)
        self._arm = arm
        self._dt = CONTROL_PERIOD
        #: Step period, s (one env step).
        self.dt = self._dt
        #: Steps of an episode that runs to its ``time_limit``.
        self.max_episode_steps = math.ceil(self._time_limit / self._dt - 1e-6)
        if abs(model.opt.timestep - PHYSICS_TIMESTEP) > 1e-12:
            raise ValueError("assets/lars/scene.xml timestep differs from PHYSICS_TIMESTEP")

        intr = CameraIntrinsics.from_fovy(width, height, fovy)
        mount = np.array(CAMERA_MOUNT_IN_END)
        left_t = mount + (-baseline / 2.0, 0.0, 0.0)
        right_t = mount + (baseline / 2.0, 0.0, 0.0)
        self.calibration = LARSCalibration(
            stereo=StereoRig(intr, intr, float(baseline)),
            left_in_end=read_only_pose(R_END_CV, left_t),
            right_in_end=read_only_pose(R_END_CV, right_t),
            capture_tip_in_end=read_only(CAPTURE_TIP_IN_END),
            arm=arm,
            control_period=self._dt,
            torque_limits=arm.torque_limits,
            joint_limits=arm.joint_limits,
            position_gains=POSITION_GAINS,
            marker=marker,
            marker_sides=MARKER_SIDES,
            capture_point_body=read_only(CAPTURE_POINT_BODY),
            auv_length=AUV_LENGTH,
            auv_diameter=AUV_DIAMETER,
            auv_mass=AUV_MASS,
            auv_freeboard=AUV_FREEBOARD,
            tolerances=tolerances or CaptureTolerances(),
            workspace=read_only([[-3.0, 3.0], [0.6, 3.9], [-0.1, 4.0]]),
            pixel_noise_std=float(pixel_noise_std),
            sea=sea_model,
        )
        # Constants of the per-step geometry, precomputed once.
        self._left_in_end = tuple(left_t.tolist())
        self._tip_z = CAPTURE_TIP_IN_END[2]
        self._intrinsics = intr
        self._baseline = float(baseline)
        self._q_mid = arm.joint_limits.mean(axis=1)
        self._q_half = 0.5 * (arm.joint_limits[:, 1] - arm.joint_limits[:, 0])
        self._ws_lo = tuple(self.calibration.workspace[:, 0].tolist())
        self._ws_hi = tuple(self.calibration.workspace[:, 1].tolist())
        tol = self.calibration.tolerances
        self._tolerance = (tol.position, tol.speed)
        self._marker_corners = self.calibration.marker.corners
        self._corners_body = [tuple(v) for v in self._marker_corners.tolist()]
        self._capture_point = self.calibration.capture_point_body
        self._kp, self._kd = POSITION_GAINS
        self._tau = np.zeros(3)
        self._hull_half = AUV_LENGTH / 2.0 - AUV_DIAMETER / 2.0
        self._analog_centre = float(
            analog_marker.corners[:, 0].mean()
        ), float(analog_marker.corners[:, 2].mean())

        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self._validate_action = ActionValidator(self.action_space)
        self.observation_space = self._make_observation_space(width, height)
        if obs_mode == "features":  # noisy pixels are clipped to the space's bounds
            pixels = self.observation_space["pixels"]
            self._pixel_bounds = (*pixels.low[0, 0].tolist(), *pixels.high[0, 0].tolist())
        self._width, self._height = width, height
        self._glint_camera = None if glint is None else GlintCamera(
            glint, intr, self._hull_half, WATERLINE_HALF_WIDTH, images=obs_mode == "stereo")
        # One renderer for the stereo observation, one for render().
        self.camera_renderer: CameraRenderer | None = None
        if obs_mode == "stereo":
            self.camera_renderer = CameraRenderer(model, ("left", "right"), width, height)
        self._view: CameraRenderer | None = None
        if render_mode == "rgb_array":
            side = render_camera == "side"
            self._view = CameraRenderer(
                model, ("side",) if side else ("left", "right"), render_width, render_height,
                skybox=side,
            )
        self._episode = _EpisodeState()
        self._geom: dict = {}
        self._sea: EpisodeSea | None = None
        self._sea_sample: tuple[float, SeaSample] | None = None

    # ------------------------------------------------------------------ spaces
    def _make_observation_space(self, width: int, height: int) -> spaces.Space:
        if self.obs_mode == "state":
            return spaces.Box(-np.inf, np.inf, shape=(24,), dtype=np.float32)
        lim = self._arm.joint_limits
        joints = {
            "joint_position": spaces.Box(
                lim[:, 0].astype(np.float32) - 0.5, lim[:, 1].astype(np.float32) + 0.5,
                dtype=np.float32,
            ),
            "joint_velocity": spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32),
        }
        if self.obs_mode == "features":
            return spaces.Dict(
                {
                    "pixels": pixel_space(width, height, (2, 3)),
                    "visible": spaces.MultiBinary((2, 3)),
                    **joints,
                }
            )
        image = spaces.Box(0, 255, shape=(height, width, 3), dtype=np.uint8)
        return spaces.Dict({"left": image, "right": image, **joints})

    # ------------------------------------------------------------------ API
    # ------------------------------------------------------------------ episode hooks
    def _begin_episode(self, rng: np.random.Generator, options: dict | None):
        options = dict(options or {})
        sea = self.calibration.sea
        valid = {"motion"} if sea is None else {"motion", "wave_heading"}
        unknown = set(options) - valid
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}; valid: {sorted(valid)}")
        motion = sample_motion(rng, options.get("motion"))
        waves = None if sea is None else sample_waves(rng, sea, options.get("wave_heading"))
        wash, analogs = None, ()
        if self.sea_state == "severe":
            if sea is None:
                wash = WashOver.sample(rng)
            elif sea.wash_ranges() is not None:
                wash = WashOver.sample(rng, *sea.wash_ranges())
            side = 1.0 if rng.uniform() < 0.5 else -1.0
            analogs = (FloatingAnalog.sample(rng, side), FloatingAnalog.sample(rng, -side))
            if sea is not None:
                analogs = analogs[:sea.analogs]
        self._episode = _EpisodeState(motion=motion, wash=wash, analogs=analogs, waves=waves)
        self._prepare_episode_constants(motion)

        # The arm end 0.8 m above the AUV's top ([LTAT] tracks at about
        # 0.8 m), the cameras over the AUV: within 1 m of the AUV's CG.
        top = self._auv_position(0.0)[2] + AUV_DIAMETER / 2.0
        offset = uniform_draws(rng, ((-0.2, 0.2), (-0.1, 0.1)))
        if self.glint is not None:  # drawn last: everything else is drawn as without glint
            self._episode.glint = self.glint.sample(rng, self._glint_slope_variance)
        end = np.array(
            [motion.x0 + offset[0], motion.y0 - CAMERA_MOUNT_IN_END[1] + offset[1], top + 0.8]
        )
        if self._sea is not None:  # the joint angles that put the end there on the moved ship
            end = self._ship_pose(0.0).to_ship(end)
        self.physics.reset(self._arm.inverse_kinematics(end))
        truth = self._truth()
        self._episode.prev_error = truth["capture_error"]
        self._episode.min_error = truth["capture_error"]
        extras = {}
        if waves is not None:
            wash = self._episode.wash
            extras["sea"] = {
                "hs_realised": waves.significant_height,
                "sea_state_code": sea_state_code(sea.spectrum.hs),
                "components": int(waves.omega.size),
                "wave_heading": waves.heading,
                "wash_period": None if wash is None else wash.period,
                "wash_duration": None if wash is None else wash.duration,
                "analogs": len(self._episode.analogs),
            }
        field = self._episode.glint
        if field is not None:
            extras["glint"] = {
                "sun_elevation": field.elevation,
                "sun_azimuth": field.azimuth,
                "slope_variance": field.slope_variance,
            }
        return truth, extras

    def _simulate(self, action: np.ndarray) -> dict:
        ep = self._episode
        if self.control == "torque":
            a0, a1, a2 = action.tolist()
            data = self.physics.data
            data.ctrl[:] = action
            mujoco.mj_step(self.physics.model, data, FRAME_SKIP)
            # |a|^2 in floats: a @ a costs more than the sum
            ep.control_effort += (a0 * a0 + a1 * a1 + a2 * a2) * self._dt
        else:
            self._track_position(self._q_mid + action * self._q_half)
        ep.steps += 1
        return self._truth()

    def _assess(self, truth: dict, action: np.ndarray) -> tuple[dict, bool]:
        ep = self._episode
        a0, a1, a2 = action.tolist()
        error = truth["capture_error"]
        captured = error <= self._tolerance[0] and truth["relative_speed"] <= self._tolerance[1]
        collision = (not captured) and truth["tip_in_hull"]
        (x, y, z), (x_lo, y_lo, z_lo), (x_hi, y_hi, z_hi) = (
            truth["end_on_ship"], self._ws_lo, self._ws_hi)
        workspace = not (x_lo <= x <= x_hi and y_lo <= y <= y_hi and z_lo <= z <= z_hi)
        failure = "collision" if collision else ("workspace" if workspace else "")
        terms = {
            "progress": ep.prev_error - error,
            "control": -0.001 * (a0 * a0 + a1 * a1 + a2 * a2),
            "success": 10.0 if captured else 0.0,
            "failure": -10.0 if failure else 0.0,
        }
        ep.prev_error = error
        ep.min_error = min(ep.min_error, error)
        if captured:
            ep.success = True
            ep.capture_time = ep.steps * self._dt
        ep.failure_reason = failure
        ep.visible_steps += truth["n_visible"] == 3
        ep.occluded_steps += truth["occluded"]
        ep.distractor_steps += truth["distractors"] > 0
        truth["collision"], truth["workspace"] = collision, workspace
        return terms, captured or bool(failure)

    def _render_frame(self) -> np.ndarray:
        self._pose_scene()
        return self._view.render(self.physics.data)

    # ------------------------------------------------------------------ internals
    @property
    def auv_motion(self) -> AUVMotion | None:
        """The episode's AUV motion (surge, sway, heave sinusoid, attitude; drawn at
        reset, None before the first)."""
        return self._episode.motion

    @property
    def glint_field(self) -> GlintField | None:
        """The episode's sun-glint field (``glint``; None without glint or before the
        first reset)."""
        return self._episode.glint

    def _prepare_episode_constants(self, motion: AUVMotion) -> None:
        """The AUV's per-episode geometry in world axes, as floats for the per-step code,
        and the episode's sea channels when there is a sea.

        The body quaternion is left to :meth:`_pose_scene`: only rendering needs it.
        """
        rot = motion.rotation()
        self._geom = {
            "corners": [tuple(v) for v in (self._marker_corners @ rot.T).tolist()],
            "capture": tuple((rot @ self._capture_point).tolist()),
            "axis": tuple(rot[:, 0].tolist()),
            "z_centre": AUV_FREEBOARD - AUV_DIAMETER / 2.0,
            "omega": motion.omega,
        }
        self._sea_sample = None
        waves = self._episode.waves
        if waves is None:
            self._sea = None
            return
        tracks = [(motion.x0 + a.dx0, motion.y0 + a.dy, motion.surge + a.drift)
                  for a in self._episode.analogs]
        self._sea = EpisodeSea(self.calibration.sea, waves, motion.x0, motion.y0,
                               motion.surge, motion.yaw, tracks)

    def _sea_at(self, t: float) -> SeaSample:
        """The sea at time ``t``; the last one is kept (truth, analogs and the scene share it)."""
        if self._sea_sample is None or self._sea_sample[0] != t:
            self._sea_sample = (t, self._sea(t))
        return self._sea_sample[1]

    def _ship_pose(self, t: float) -> ShipPose:
        """The ship's displacement at time ``t`` (only with a sea)."""
        return ShipPose(self.calibration.sea.ship_origin, self._sea_at(t))

    def _auv_attitude(self, t: float) -> tuple[float, float]:
        """AUV roll and nose-up pitch at time ``t`` (constant without a sea)."""
        m = self._episode.motion
        if self._sea is None:
            return 0.0, m.pitch
        sample = self._sea_at(t)
        return sample.auv_roll, m.pitch + sample.auv_pitch

    def _auv_position(self, t: float) -> tuple[float, float, float]:
        """AUV CG position at time ``t`` ([LTAT] motion model, or the sea's heave)."""
        m = self._episode.motion
        if self._sea is None:
            level = heave(t, m.heave_amplitude, m.omega, m.heave_phase)[0]
        else:
            level = self._sea_at(t).auv_heave
        return (m.x0 + m.surge * t, m.y0, level + self._geom["z_centre"])

    def _body_to_world(self, roll: float, pitch: float, yaw: float) -> tuple:
        """Marker corners (3 points), capture point and hull axis of the AUV at an
        attitude, in world axes (floats): the per-step twin of
        :meth:`_prepare_episode_constants` for a rolling, pitching AUV."""
        rows = frames.rotation_rows(roll, -pitch, yaw)  # frames' ZYX pitch is nose-down
        corners = [frames.rotate_rows(rows, p) for p in self._corners_body]
        capture = frames.rotate_rows(rows, self._capture_point.tolist())
        return corners, capture, (rows[0][0], rows[1][0], rows[2][0])

    def position_action(self, q) -> np.ndarray:
        """The ``control="position"`` action whose joint targets are ``q`` (rad, (..., 3)):
        the inverse of the action's linear map onto the joint limits (not clipped)."""
        return (np.asarray(q, dtype=float) - self._q_mid) / self._q_half

    def _track_position(self, q_target: np.ndarray) -> None:
        """Computed-torque PD (eqs. 29-30) at the physics rate, torque-limited."""
        model, data = self.physics.model, self.physics.data
        limits = self.calibration.torque_limits
        tau = self._tau
        for _ in range(FRAME_SKIP):
            mujoco.mj_step1(model, data)
            accel = self._kp * (q_target - data.qpos) - self._kd * data.qvel
            mujoco.mj_mulM(model, data, tau, accel)
            tau += data.qfrc_bias
            np.clip(tau / limits, -1.0, 1.0, out=data.ctrl)
            self._episode.control_effort += float(data.ctrl @ data.ctrl) * PHYSICS_TIMESTEP
            mujoco.mj_step2(model, data)

    def _truth(self) -> dict:
        """Ground truth after a step, computed once and shared by obs, reward and info.

        Plain-float arithmetic on purpose: three corners in two cameras cost
        less as scalars than as many tiny numpy operations. ``corners`` (9)
        and ``pixels`` (12: left u, v of A1, A2, A3, then right) are flat
        lists, shaped once when they become arrays.
        """
        data = self.physics.data
        ep = self._episode
        g = self._geom
        t = ep.steps * self._dt
        q = data.qpos.tolist()
        qd = data.qvel.tolist()
        ex, ey, ez, evx, evy, evz = self._arm.end_state(q, qd)
        end_on_ship = (ex, ey, ez)
        c, s = math.cos(q[0]), math.sin(q[0])
        m = ep.motion
        if self._sea is None:
            level, rate = heave(t, m.heave_amplitude, g["omega"], m.heave_phase)
            px, py, pz = m.x0 + m.surge * t, m.y0, level + g["z_centre"]
            roll, pitch = 0.0, m.pitch
            body_corners, (kx, ky, kz), (ax, ay, az) = g["corners"], g["capture"], g["axis"]
        else:
            sea = self._sea_at(t)
            level, rate = sea.level, sea.auv_heave_rate
            px, py, pz = m.x0 + m.surge * t, m.y0, sea.auv_heave + g["z_centre"]
            roll, pitch = sea.auv_roll, m.pitch + sea.auv_pitch
            body_corners, (kx, ky, kz), (ax, ay, az) = self._body_to_world(roll, pitch, m.yaw)
            # The arm's end is a point of the moving ship; the levelled head hangs from it.
            ex, ey, ez, evx, evy, evz = self._ship_pose(t).carry(ex, ey, ez, evx, evy, evz)
        lx, ly, lz = self._left_in_end
        camx, camy, camz = ex + c * lx - s * ly, ey + s * lx + c * ly, ez + lz

        # Camera -> world rows (OpenCV axes): x = (c, s, 0), y = (s, -c, 0), z = down; the
        # right camera sits one baseline along the left camera's x axis.
        rows = self._camera_rows(c, s)
        points = [(px + ox, py + oy, pz + oz) for ox, oy, oz in body_corners]
        corners = [x for point in points for x in point]
        b = self._baseline
        left_cam, right_cam = (camx, camy, camz), (camx + b * c, camy + b * s, camz)
        left_px, vis_left = project_few(self._intrinsics, points, left_cam, rows)
        right_px, vis_right = project_few(self._intrinsics, points, right_cam, rows)
        left = [x for uv in left_px for x in uv]
        right = [x for uv in right_px for x in uv]

        occluded = False
        distractors = 0
        if ep.wash is not None:
            crest = self._crest_centre(t, (px, py, pz), level)
            if crest is not None and (any(vis_left) or any(vis_right)):
                cams = np.array([left_cam, right_cam])
                hidden_left, hidden_right = segments_cross_box(
                    cams[:, None, :], np.array(corners).reshape(1, 3, 3), crest,
                    ep.wash.half_size,
                ).tolist()
                occluded = any(hidden_left) or any(hidden_right)
                vis_left = [v and not h for v, h in zip(vis_left, hidden_left, strict=True)]
                vis_right = [v and not h for v, h in zip(vis_right, hidden_right, strict=True)]
            distractors = self._count_distractors(t, (px, py, pz), left_cam, rows)

        # Capture tip vs the AUV: capture point offset and hull penetration.
        tx, ty, tz = ex, ey, ez + self._tip_z
        offset = (px + kx - tx, py + ky - ty, pz + kz - tz)
        dx, dy, dz = tx - px, ty - py, tz - pz
        half = self._hull_half
        along = dx * ax + dy * ay + dz * az
        along = -half if along < -half else (half if along > half else along)
        radial2 = (dx - along * ax) ** 2 + (dy - along * ay) ** 2 + (dz - along * az) ** 2
        dvx, dvy, dvz = m.surge - evx, -evy, rate - evz
        return {
            "q": q,
            "qd": qd,
            "end": (ex, ey, ez),
            "end_on_ship": end_on_ship,
            "end_vel": (evx, evy, evz),
            "position": (px, py, pz),
            "velocity": (m.surge, 0.0, rate),
            "level": level,
            "roll": roll,
            "pitch": pitch,
            "corners": corners,
            "cameras": (left_cam, right_cam),
            "hull_axis": (ax, ay, az),
            "pixels": left + right,
            "visible": [vis_left, vis_right],
            "n_visible": sum(map(operator.and_, vis_left, vis_right)),
            "occluded": occluded,
            "distractors": distractors,
            "offset": offset,
            "capture_error": math.sqrt(offset[0] ** 2 + offset[1] ** 2 + offset[2] ** 2),
            "relative_speed": math.sqrt(dvx * dvx + dvy * dvy + dvz * dvz),
            "tip_in_hull": radial2 < (AUV_DIAMETER / 2.0) ** 2,
        }

    def _crest_centre(self, t: float, pos: np.ndarray, level: float):
        shift = self._episode.wash.offset(t)
        if shift is None:
            return None
        wash = self._episode.wash
        top = level + AUV_FREEBOARD + wash.overtop
        return (pos[0] + shift, pos[1], top - wash.half_size[2])

    def _analog_pose(self, k: int, t: float, pos: np.ndarray):
        """Centre and yaw of analog ``k``: heaving with its own phase lag, or, with a
        sea, with the elevation at its own place."""
        m = self._episode.motion
        analog = self._episode.analogs[k]
        if self._sea is None:
            level = heave(t, m.heave_amplitude, m.omega, m.heave_phase + analog.heave_lag)[0]
        else:
            level = self._sea_at(t).analog_levels[k]
        centre = (pos[0] + analog.dx0 + analog.drift * t, pos[1] + analog.dy,
                  level + self._geom["z_centre"])
        return centre, analog.yaw

    def _count_distractors(self, t, pos, cam, rows) -> int:
        """Analogs whose marker centre projects into the left image (camera centre ``cam``,
        camera -> world ``rows`` of :meth:`_camera_rows`)."""
        mx, mz = self._analog_centre
        centres = []
        for k in range(len(self._episode.analogs)):
            (ax, ay, az), yaw = self._analog_pose(k, t, pos)
            centres.append((ax + mx * math.cos(yaw), ay + mx * math.sin(yaw), az + mz))
        return sum(project_few(self._intrinsics, centres, cam, rows)[1])

    @staticmethod
    def _camera_rows(c: float, s: float) -> tuple:
        """Left camera -> world rotation rows of the downward head at slew ``(cos, sin)``."""
        return ((c, s, 0.0), (s, -c, 0.0), (0.0, 0.0, -1.0))

    def _joints(self, truth: dict) -> dict:
        return {
            "joint_position": np.array(truth["q"], dtype=np.float32),
            "joint_velocity": np.array(truth["qd"], dtype=np.float32),
        }

    def _observation(self, truth: dict):
        obs = self._observe(truth)
        ep = self._episode
        if ep.steps and ep.glint_frame is not None:  # the glint the step's observation met
            ep.glint_steps += bool(ep.glint_frame["glint_corners"].any())
        return obs

    def _observe(self, truth: dict):
        if self.obs_mode == "state":
            m = self._episode.motion
            (px, py, pz), (ex, ey, ez) = truth["position"], truth["end"]
            return np.array(
                [*truth["q"], *truth["qd"], ex, ey, ez, *truth["end_vel"],
                 px - ex, py - ey, pz - ez, *truth["velocity"], *truth["offset"],
                 truth["pitch"], m.yaw, truth["level"]],
                dtype=np.float32,
            )
        if self.obs_mode == "features":
            vis_left, vis_right = visible = truth["visible"]
            true_pixels = truth["pixels"]
            std = self.calibration.pixel_noise_std
            # Drawn always, whatever is visible: the same noise stream every step.
            noise = self.np_random.normal(0.0, std, 12).tolist() if std > 0 else [0.0] * 12
            seen = vis_left + vis_right
            if self._episode.glint is not None:
                true_pixels, seen, self._episode.glint_frame = self._glint_camera.on_corners(
                    self._episode.glint, truth, seen, self.np_random)
                visible = [seen[:3], seen[3:]]
            lo_u, lo_v, hi_u, hi_v = self._pixel_bounds
            pixels = [0.0] * 12
            i = 0  # u of the corner; v at i + 1
            for corner_seen in seen:
                if corner_seen:  # finite; clipped by comparisons (cheaper than min/max)
                    u, v = true_pixels[i] + noise[i], true_pixels[i + 1] + noise[i + 1]
                    pixels[i] = lo_u if u < lo_u else (hi_u if u > hi_u else u)
                    pixels[i + 1] = lo_v if v < lo_v else (hi_v if v > hi_v else v)
                i += 2
            return {
                "pixels": np.array(pixels, dtype=np.float32).reshape(2, 3, 2),
                "visible": np.array(visible, dtype=np.int8),
                **self._joints(truth),
            }
        if self._episode.glint is None:
            pair = self._render_pair()
        else:
            self._pose_scene()
            pair, ranges = self.camera_renderer.render_with_range(self.physics.data)
            pair, self._episode.glint_frame = self._glint_camera.on_pair(
                self._episode.glint, truth, pair, ranges, self.np_random)
        w = self._width
        return {
            "left": np.ascontiguousarray(pair[:, :w]),
            "right": np.ascontiguousarray(pair[:, w:]),
            **self._joints(truth),
        }

    def _pose_scene(self) -> None:
        """Pose the kinematic bodies (AUV, sea, head, analogs) for rendering.

        The physics never reads them; they are posed only before a render.
        """
        phys = self.physics
        ep = self._episode
        t = ep.steps * self._dt
        pos = self._auv_position(t)
        q = phys.data.qpos
        end = self._arm.forward_kinematics(q)
        ship = None
        if self._sea is None:
            level = pos[2] - self._geom["z_centre"]
            quat = ep.motion.quaternion()
        else:
            level = self._sea_at(t).level
            roll, pitch = self._auv_attitude(t)
            quat = frames.quat_from_euler(roll, -pitch, ep.motion.yaw)
            pose = self._ship_pose(t)
            end = pose.carry(*end.tolist(), 0.0, 0.0, 0.0)[:3]
            ship = pose.transform()
        phys.pose("water", (0.0, 0.0, level), (1.0, 0.0, 0.0, 0.0))
        phys.pose("auv", pos, quat)
        half = 0.5 * float(q[0])
        phys.pose("head", end, (math.cos(half), 0.0, 0.0, math.sin(half)))
        crest = self._crest_centre(t, pos, level) if ep.wash is not None else None
        phys.pose("crest", PARKED if crest is None else crest, (1.0, 0.0, 0.0, 0.0))
        for k in range(2):
            if k < len(ep.analogs):
                centre, yaw = self._analog_pose(k, t, pos)
                quat = (math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0))
            else:
                centre, quat = PARKED, (1.0, 0.0, 0.0, 0.0)
            phys.pose(f"analog_{k}", centre, quat)
        phys.refresh_kinematics(ship)

    def _render_pair(self) -> np.ndarray:
        """Left and right images side by side, (H, 2 W, 3), one rendering pass."""
        self._pose_scene()
        return self.camera_renderer.render(self.physics.data)

    def _info(self, truth: dict) -> dict:
        ep = self._episode
        m = ep.motion
        (px, py, pz), (ex, ey, ez) = truth["position"], truth["end"]
        info = {
            "capture_error": truth["capture_error"],
            "capture_offset": np.array(truth["offset"]),
            "relative_position": np.array((px - ex, py - ey, pz - ez)),
            "relative_speed": truth["relative_speed"],
            "is_success": ep.success,
            "collision": truth.get("collision", False),
            "violation_workspace": truth.get("workspace", False),
            "marker_visible": truth["n_visible"],
            "marker_occluded": truth["occluded"],
            "distractors_in_view": truth["distractors"],
            "failure_reason": ep.failure_reason,
            "time": ep.steps * self._dt,
            "true_position": np.array(truth["position"]),
            "true_velocity": np.array(truth["velocity"]),
            "true_pitch": truth["pitch"],
            "true_yaw": m.yaw,
            "true_corners": np.array(truth["corners"]).reshape(3, 3),
            "true_pixels": np.array(truth["pixels"]).reshape(2, 3, 2),
            "true_visible": np.array(truth["visible"]),
            "end_position": np.array(truth["end"]),
            "water_level": truth["level"],
        }
        if ep.glint_frame is not None:
            info.update(ep.glint_frame)
        if self._sea is not None:
            sea = self._sea_at(info["time"])
            info["true_roll"] = truth["roll"]
            info["ship_motion"] = np.array((sea.ship_heave, sea.ship_roll, sea.ship_pitch))
        return info

    def _episode_metrics(self, truth: dict) -> dict:
        ep = self._episode
        steps = max(ep.steps, 1)
        glint = {} if self.glint is None else {"glint_fraction": ep.glint_steps / steps}
        return {
            "success": ep.success,
            "failure_reason": ep.failure_reason or ("" if ep.success else "time_limit"),
            "capture_time": ep.capture_time,
            "steps": ep.steps,
            "final_capture_error": truth["capture_error"],
            "min_capture_error": ep.min_error,
            "final_relative_speed": truth["relative_speed"],
            "marker_visible_fraction": ep.visible_steps / steps,
            "occluded_fraction": ep.occluded_steps / steps,
            "distractor_fraction": ep.distractor_steps / steps,
            "control_effort": ep.control_effort,
            **glint,
        }

    # ------------------------------------------------------------------ pickling
    def _set_runtime_state(self, state: dict) -> None:
        super()._set_runtime_state(state)
        if self._episode.motion is not None:
            self._prepare_episode_constants(self._episode.motion)
