"""The LARS capture task's transition: one episode as :func:`reset` then :func:`step`.

An episode is an immutable :class:`EpisodeState` (what the episode's record
holds, and its :class:`Scene`: the AUV's motion, the sea and the sun drawn at
reset); the static :class:`LARSParams` say which task it is. Both functions keep the
protocol of :mod:`auv_envs.core.task` and take a :class:`~auv_envs.core.ops.Backend`:
the arithmetic (Python floats on the CPU, ``jax.numpy`` in :mod:`auv_envs.tasks.lars.jax_task`),
the episode's random draws (NumPy ``Generator``'s interface) and the arm's plant (MuJoCo
on the CPU, MJX batched), a function of its state ``arm``: ``place(q) -> arm`` (the arm at
rest at joint angles ``q``), ``advance(arm, action, effort) -> (arm, effort)`` (one
control period under the checked action, the running control effort updated) and
``truth(arm, params, scene, steps, ops)`` (:func:`truth` of its joints; the CPU arm's is
compiled where it can be, :mod:`auv_envs.tasks.lars.compiled`). The start draw, the order
of the step (arm, truth, judgement, observation), the reward terms, the episode's end,
the ``state``/``features`` observations, the step's metrics, ``info`` and the episode
summary exist here only; :class:`auv_envs.tasks.lars.env.LARSCaptureTask` is the
task on the CPU around them, which the one Gymnasium env runs (it renders the ``stereo`` images).

The draws come in the order the environment has always made them
(``docs/environments.md``), so its episodes are the released ones, bit for
bit. The truth is scalar arithmetic on purpose: three corners in two cameras
cost less as Python floats than as many tiny NumPy operations, and the same
code evaluates JAX arrays.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import operator
from typing import Any, NamedTuple

import numpy as np

from auv_envs.core import frames
from auv_envs.core.camera import CameraIntrinsics, project_few, seen_pixels
from auv_envs.core.ops import FLOATS, Backend
from auv_envs.core.sea import FloatingAnalog, WashOver, heave, segments_cross_box
from auv_envs.core.task import Transition
from auv_envs.tasks.lars.scene import (
    AUV_DIAMETER,
    AUV_FREEBOARD,
    AUVMotion,
    auv_rotation,
    sample_motion,
    uniform_draws,
)
from auv_envs.tasks.lars.sea import EpisodeSea, GlintField, SeaSample, ShipPose, sample_waves
from auv_envs.tasks.lars.waves import WaveRealisation, sea_state_code

#: The reward's terms, in the order they sum (each reported as ``info["reward_<term>"]``).
REWARD_TERMS = ("progress", "control", "success", "failure")
#: The metrics of every step that are numbers (:func:`step_metrics`'s keys).
STEP_METRICS = ("capture_error", "relative_speed", "marker_visible", "marker_occluded",
                "distractors_in_view", "is_success", "collision", "violation_workspace")
#: Why an episode failed: ``EpisodeState.failure`` is the index + 1 (0: none).
FAILURE_REASONS = ("collision", "workspace")
#: The AUV's CG below the local water level, m (the hull floats ``AUV_FREEBOARD`` proud).
Z_CENTRE = AUV_FREEBOARD - AUV_DIAMETER / 2.0
#: The arm's end at reset: this far above the AUV's top line ([LTAT] tracks at about
#: 0.8 m), the cameras over the AUV within these offsets (m, along x and y).
START_HEIGHT = 0.8
START_OFFSET = ((-0.2, 0.2), (-0.1, 0.1))


@dataclasses.dataclass(frozen=True)
class LARSParams:
    """What makes a LARS task this one; fixed for the environment's life.

    Attributes:
        obs_mode: ``"state"``, ``"features"`` or ``"stereo"`` (the images are the
            shell's; the transition gives that mode's joint readings).
        control: ``"torque"`` or ``"position"``.
        sea_state: ``"calm"`` or ``"severe"`` (wash-over and analogs).
        dt: seconds per step. max_episode_steps: steps to the time limit.
        arm: the :class:`~auv_envs.tasks.lars.arm.ArmModel` (inverse kinematics at reset).
        sea: the :class:`~auv_envs.tasks.lars.sea.LARSSeaModel`, None for [LTAT]'s sinusoid.
        glint: the :class:`~auv_envs.tasks.lars.sea.SunGlint`, None without glint;
            ``glint_slope_variance`` its sea's, ``glint_camera`` its
            :class:`~auv_envs.tasks.lars.glint.GlintCamera`.
        intrinsics: each camera's; ``baseline`` m; ``left_in_end`` the left camera's
            centre in the arm-end frame; ``tip_z`` the capture tip's height in it.
        corners_body: the marker's corners A1, A2, A3 in the AUV's body frame;
            ``capture_point`` the lifting eye's (3 floats).
        tolerance: ``(position m, speed m/s)`` of a capture.
        workspace: ``(low, high)`` corners of the arm end's box in the ship's frame.
        pixel_noise_std: ``features`` noise, px; ``pixel_bounds`` ``(low, high)``, 12
            floats each, the bounds of the u, v of the six corners the noisy pixels are
            clipped to (``features`` only).
        hull_half: the hull's cylinder half-length between its hemispherical ends, m.
        analog_centre: ``(x, z)`` of an analog's marker centre in its body frame.
        joint_mid, joint_half: the joint limits' middle and half-range (``position``).
    """

    obs_mode: str
    control: str
    sea_state: str
    dt: float
    max_episode_steps: int
    arm: Any
    sea: Any
    glint: Any
    glint_slope_variance: float | None
    glint_camera: Any
    intrinsics: CameraIntrinsics
    baseline: float
    left_in_end: tuple
    tip_z: float
    corners_body: tuple
    capture_point: Any
    tolerance: tuple
    workspace: tuple
    pixel_noise_std: float
    pixel_bounds: tuple | None
    hull_half: float
    analog_centre: tuple
    joint_mid: Any
    joint_half: Any


class Scene(NamedTuple):
    """An episode's world, drawn at reset and fixed through it.

    ``corners``, ``capture`` and ``axis`` are the marker's corners, the
    capture point and the hull's axis in world axes about the CG (floats; a
    sea's roll and pitch recompute them every step); ``sea`` is the
    episode's sea channels (None without a sea).
    """

    motion: AUVMotion
    wash: WashOver | None
    analogs: tuple[FloatingAnalog, ...]
    waves: WaveRealisation | None
    glint: GlintField | None
    sea: EpisodeSea | None
    corners: list
    capture: tuple
    axis: tuple


class EpisodeState(NamedTuple):
    """Everything an episode changes besides the arm's plant; immutable.

    ``failure`` is the index + 1 of this step's failure in
    :data:`FAILURE_REASONS` (0: none); ``capture_time`` NaN until captured;
    ``glint_frame`` the last observation's glint (None without glint).
    """

    scene: Scene
    steps: int
    prev_error: float
    min_error: float
    success: bool
    failure: int
    capture_time: float
    visible_steps: int
    occluded_steps: int
    distractor_steps: int
    glint_steps: int
    control_effort: float
    glint_frame: dict | None = None


class Assessment(NamedTuple):
    """A step's judgement: reward terms, whether it ended, and the violations."""

    terms: dict
    terminated: bool
    collision: bool
    workspace: bool


# ------------------------------------------------------------------ the scene
def scene_of(params: LARSParams, motion: AUVMotion, waves=None, wash=None, analogs=(),
             glint=None, *, ops) -> Scene:
    """The :class:`Scene` of an episode's draws (the per-episode geometry precomputed)."""
    rot = auv_rotation(motion.pitch, motion.yaw, ops.xp)
    sea = None
    if waves is not None:
        tracks = [(motion.x0 + a.dx0, motion.y0 + a.dy, motion.surge + a.drift)
                  for a in analogs]
        sea = EpisodeSea(params.sea, waves, motion.x0, motion.y0, motion.surge, motion.yaw,
                         tracks, ops)
    corners = ops.xp.asarray(params.corners_body) @ rot.T
    return Scene(motion=motion, wash=wash, analogs=analogs, waves=waves, glint=glint, sea=sea,
                 corners=[ops.unpack(row) for row in corners],
                 capture=ops.unpack(rot @ ops.xp.asarray(params.capture_point)),
                 axis=ops.unpack(rot[:, 0]))


def sea_sample(scene: Scene, t: float) -> SeaSample | None:
    """The sea at time ``t`` (None without a sea)."""
    return None if scene.sea is None else scene.sea(t)


def ship_pose(params: LARSParams, sample: SeaSample, ops) -> ShipPose:
    """The ship's displacement in the sea state ``sample``."""
    return ShipPose(params.sea.ship_origin, sample, ops)


def auv_position(scene: Scene, t: float, sample: SeaSample | None, ops) -> tuple:
    """AUV CG position at time ``t`` ([LTAT] motion model, or the sea's heave)."""
    m = scene.motion
    if sample is None:
        level = heave(t, m.heave_amplitude, m.omega, m.heave_phase, ops)[0]
    else:
        level = sample.auv_heave
    return (m.x0 + m.surge * t, m.y0, level + Z_CENTRE)


def auv_attitude(scene: Scene, sample: SeaSample | None) -> tuple[float, float]:
    """AUV roll and nose-up pitch (constant without a sea)."""
    m = scene.motion
    if sample is None:
        return 0.0, m.pitch
    return sample.auv_roll, m.pitch + sample.auv_pitch


def crest_centre(scene: Scene, t: float, position, level: float) -> tuple:
    """``(active, centre)`` of the wash-over crest at time ``t`` over the AUV at
    ``position``: whether an event is on, and where the crest is were it on."""
    wash = scene.wash
    active, shift = wash.shift(t)
    top = level + AUV_FREEBOARD + wash.overtop
    return active, (position[0] + shift, position[1], top - wash.half_size[2])


def analog_pose(scene: Scene, k: int, t: float, position, sample: SeaSample | None,
                ops):
    """Centre and yaw of analog ``k``: heaving with its own phase lag, or, with a sea,
    with the elevation at its own place."""
    m = scene.motion
    analog = scene.analogs[k]
    if sample is None:
        level = heave(t, m.heave_amplitude, m.omega, m.heave_phase + analog.heave_lag,
                      ops)[0]
    else:
        level = sample.analog_levels[k]
    centre = (position[0] + analog.dx0 + analog.drift * t, position[1] + analog.dy,
              level + Z_CENTRE)
    return centre, analog.yaw


def camera_rows(c: float, s: float) -> tuple:
    """Left camera -> world rotation rows of the downward head at slew ``(cos, sin)``
    (OpenCV axes: x = (c, s, 0), y = (s, -c, 0), z down)."""
    return ((c, s, 0.0), (s, -c, 0.0), (0.0, 0.0, -1.0))


def _body_to_world(params: LARSParams, roll, pitch, yaw, ops) -> tuple:
    """Marker corners (3 points), capture point and hull axis of the AUV at an
    attitude, in world axes (scalars): the per-step twin of :func:`scene_of`'s
    geometry for a rolling, pitching AUV."""
    rows = frames.rotation_rows(roll, -pitch, yaw, ops)  # frames' ZYX pitch is nose-down
    corners = [frames.rotate_rows(rows, p) for p in params.corners_body]
    capture = frames.rotate_rows(rows, params.capture_point)
    return corners, capture, (rows[0][0], rows[1][0], rows[2][0])


def _count_distractors(params: LARSParams, scene: Scene, t, position, sample, camera,
                       rows, ops) -> int:
    """Analogs whose marker centre projects into the left image (camera centre
    ``camera``, camera -> world ``rows``)."""
    mx, mz = params.analog_centre
    centres = []
    for k in range(len(scene.analogs)):
        (ax, ay, az), yaw = analog_pose(scene, k, t, position, sample, ops)
        centres.append((ax + mx * ops.cos(yaw), ay + mx * ops.sin(yaw), az + mz))
    return sum(project_few(params.intrinsics, centres, camera, rows, ops)[1])


# ------------------------------------------------------------------ the truth
def truth(params: LARSParams, scene: Scene, steps, q, qd, ops) -> dict:
    """Ground truth at step ``steps`` with the arm at joint angles ``q`` and rates ``qd``
    (three scalars each), computed once a step and shared by observation, reward and
    info, in the scalars of ``ops``: :func:`geometry`, then :func:`sighting`.

    ``corners`` (9) and ``pixels`` (12: left u, v of A1, A2, A3, then right) are
    flat lists, shaped once when they become arrays; ``sea`` is the sea's
    sample (None without a sea).
    """
    t = steps * params.dt
    sample = sea_sample(scene, t)
    return sighting(params, scene, t, sample, geometry(params, scene, t, sample, q, qd, ops),
                    ops)


def geometry(params: LARSParams, scene: Scene, t, sample: SeaSample | None, q, qd,
             ops, inside: bool = True) -> dict:
    """The truth's arithmetic at time ``t`` (the sea's ``sample`` at it): the arm's end,
    the AUV, the cameras, the marker's pixels (NaN behind a camera; ``visible`` per
    camera, inside its image, when ``inside``: CasADi's symbols, whose comparisons do not
    combine, leave it out, as :func:`~auv_envs.core.camera.project_few` does), the
    capture offset and ``radial2``, the capture tip's squared distance from the hull's
    axis. Arithmetic only: evaluated on any backend of :mod:`auv_envs.core.ops`, and
    compiled by the CPU arm (:class:`auv_envs.tasks.lars.compiled.CompiledTruth`)."""
    ex, ey, ez, evx, evy, evz = params.arm.end_state(q, qd, ops)
    end_on_ship = (ex, ey, ez)
    c, s = ops.cos(q[0]), ops.sin(q[0])
    m = scene.motion
    if sample is None:
        level, rate = heave(t, m.heave_amplitude, m.omega, m.heave_phase, ops)
        px, py, pz = m.x0 + m.surge * t, m.y0, level + Z_CENTRE
        roll, pitch = 0.0, m.pitch
        body_corners, (kx, ky, kz), (ax, ay, az) = scene.corners, scene.capture, scene.axis
    else:
        level, rate = sample.level, sample.auv_heave_rate
        px, py, pz = m.x0 + m.surge * t, m.y0, sample.auv_heave + Z_CENTRE
        roll, pitch = sample.auv_roll, m.pitch + sample.auv_pitch
        body_corners, (kx, ky, kz), (ax, ay, az) = _body_to_world(params, roll, pitch, m.yaw,
                                                                  ops)
        # The arm's end is a point of the moving ship; the levelled head hangs from it.
        ex, ey, ez, evx, evy, evz = ship_pose(params, sample, ops).carry(ex, ey, ez, evx, evy,
                                                                         evz)
    lx, ly, lz = params.left_in_end
    camx, camy, camz = ex + c * lx - s * ly, ey + s * lx + c * ly, ez + lz

    # The right camera sits one baseline along the left camera's x axis.
    rows = camera_rows(c, s)
    points = [(px + ox, py + oy, pz + oz) for ox, oy, oz in body_corners]
    b = params.baseline
    left_cam, right_cam = (camx, camy, camz), (camx + b * c, camy + b * s, camz)
    left_px, vis_left = project_few(params.intrinsics, points, left_cam, rows, ops, inside)
    right_px, vis_right = project_few(params.intrinsics, points, right_cam, rows, ops, inside)

    # Capture tip vs the AUV: capture point offset and hull penetration.
    tx, ty, tz = ex, ey, ez + params.tip_z
    offset = (px + kx - tx, py + ky - ty, pz + kz - tz)
    dx, dy, dz = tx - px, ty - py, tz - pz
    half = params.hull_half
    along = ops.clip(dx * ax + dy * ay + dz * az, -half, half)
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
        "sea": sample,
        "corners": list(itertools.chain.from_iterable(points)),
        "cameras": (left_cam, right_cam),
        "hull_axis": (ax, ay, az),
        "pixels": list(itertools.chain(*left_px, *right_px)),
        "visible": [vis_left, vis_right],
        "offset": offset,
        "capture_error": ops.sqrt(offset[0] ** 2 + offset[1] ** 2 + offset[2] ** 2),
        "relative_speed": ops.sqrt(dvx * dvx + dvy * dvy + dvz * dvz),
        "radial2": (dx - along * ax) ** 2 + (dy - along * ay) ** 2 + (dz - along * az) ** 2,
    }


def sighting(params: LARSParams, scene: Scene, t, sample: SeaSample | None, now: dict,
             ops) -> dict:
    """:func:`geometry`'s ``now`` at time ``t`` made the truth, in place: the wash-over
    crest hiding corners (``occluded``), the analogs in view (``distractors``), the
    corners both cameras see (``n_visible``) and whether the tip is in the hull
    (``tip_in_hull``, from ``radial2``)."""
    vis_left, vis_right = now["visible"]
    occluded = False
    distractors = 0
    if scene.wash is not None:
        position = now["position"]
        active, crest = crest_centre(scene, t, position, now["level"])
        # Python bools can skip the test when nothing can be hidden; arrays always run it.
        skip = isinstance(active, bool) and not (active and (any(vis_left) or any(vis_right)))
        if not skip:
            xp = ops.xp
            hidden = segments_cross_box(
                xp.asarray(now["cameras"])[:, None, :],
                xp.asarray(now["corners"]).reshape(1, 3, 3), crest, scene.wash.half_size, xp,
            ) & active
            hidden_left, hidden_right = ops.unpack(hidden[0]), ops.unpack(hidden[1])
            occluded = functools.reduce(operator.or_, hidden_left + hidden_right)
            vis_left = [v & ops.logical_not(h) for v, h in zip(vis_left, hidden_left,
                                                                strict=True)]
            vis_right = [v & ops.logical_not(h) for v, h in zip(vis_right, hidden_right,
                                                                  strict=True)]
            now["visible"] = [vis_left, vis_right]
        q0 = now["q"][0]
        distractors = _count_distractors(params, scene, t, position, sample,
                                         now["cameras"][0],
                                         camera_rows(ops.cos(q0), ops.sin(q0)), ops)
    now["n_visible"] = sum(map(operator.and_, vis_left, vis_right))
    now["occluded"] = occluded
    now["distractors"] = distractors
    now["tip_in_hull"] = now.pop("radial2") < (AUV_DIAMETER / 2.0) ** 2
    return now


def truth_now(params: LARSParams, arm, state: EpisodeState, plant, ops) -> dict:
    """:func:`truth` at the state's step with the ``plant``'s joints at ``arm``."""
    return plant.truth(arm, params, state.scene, state.steps, ops)


# ------------------------------------------------------------------ reset
def draw_scene(params: LARSParams, draws, options: dict | None, ops):
    """The episode's world and where the arm's end starts: ``(scene, end)``, ``end``
    the arm end's position (three scalars) in the ship's frame.

    Draws, in order: the AUV's motion; with a sea, its realisation; in
    ``severe`` sea the wash-over schedule, the analogs' side and the two
    analogs; the arm end's offset over the AUV; with glint, the sun.
    ``options``: ``motion`` (pins fields of the motion) and, with a sea,
    ``wave_heading`` (rad); ``ValueError`` for any other.
    """
    options = dict(options or {})
    sea = params.sea
    valid = {"motion"} if sea is None else {"motion", "wave_heading"}
    unknown = set(options) - valid
    if unknown:
        raise ValueError(f"unknown reset option(s) {sorted(unknown)}; valid: {sorted(valid)}")
    motion = sample_motion(draws, options.get("motion"), ops)
    waves = (None if sea is None
             else sample_waves(draws, sea, options.get("wave_heading"), ops.xp))
    wash, analogs = None, ()
    if params.sea_state == "severe":
        if sea is None:
            wash = WashOver.sample(draws)
        elif sea.wash_ranges() is not None:
            wash = WashOver.sample(draws, *sea.wash_ranges())
        side = ops.where(draws.uniform() < 0.5, 1.0, -1.0)
        analogs = (FloatingAnalog.sample(draws, side), FloatingAnalog.sample(draws, -side))
        if sea is not None:
            analogs = analogs[:sea.analogs]
    scene = scene_of(params, motion, waves, wash, analogs, ops=ops)
    sample = sea_sample(scene, 0.0)
    top = auv_position(scene, 0.0, sample, ops)[2] + AUV_DIAMETER / 2.0
    offset = uniform_draws(draws, START_OFFSET, ops)
    if params.glint is not None:  # drawn last: everything else is drawn as without glint
        scene = scene._replace(glint=params.glint.sample(draws, params.glint_slope_variance,
                                                         ops))
    # The cameras (at y = left_in_end[1] in the end frame) over the AUV's CG line.
    end = (motion.x0 + offset[0], motion.y0 - params.left_in_end[1] + offset[1],
           top + START_HEIGHT)
    if sample is not None:  # the joint angles that put the end there on the moved ship
        end = ops.unpack(ship_pose(params, sample, ops).to_ship(end, ops.xp))
    return scene, end


def reset(params: LARSParams, backend: Backend, options: dict | None = None) -> Transition:
    """A new episode (:class:`~auv_envs.core.task.Transition`, no judgement)."""
    ops, draws, plant = backend
    scene, end = draw_scene(params, draws, options, ops)
    arm = plant.place(params.arm.joint_angles(end, ops))
    now = plant.truth(arm, params, scene, ops.integer(0), ops)
    state, obs = observe(params, first_state(scene, now, ops), now, backend)
    return Transition(arm, state, now, obs)


def first_state(scene: Scene, now: dict, ops) -> EpisodeState:
    """The record of an episode in ``scene`` before its first step (``now`` its truth)."""
    error = now["capture_error"]
    zero = ops.integer(0)
    return EpisodeState(
        scene=scene, steps=zero, prev_error=error, min_error=error,
        success=ops.boolean(False), failure=zero, capture_time=ops.real(math.nan),
        visible_steps=zero, occluded_steps=zero, distractor_steps=zero, glint_steps=zero,
        control_effort=ops.real(0.0))


def reset_info(params: LARSParams, state: EpisodeState) -> dict:
    """What the reset ``info`` adds: the sea's realisation and the sun (with each)."""
    scene = state.scene
    extras = {}
    if scene.waves is not None:
        waves, wash = scene.waves, scene.wash
        extras["sea"] = {
            "hs_realised": waves.significant_height,
            "sea_state_code": sea_state_code(params.sea.spectrum.hs),
            "components": int(waves.omega.size),
            "wave_heading": waves.heading,
            "wash_period": None if wash is None else wash.period,
            "wash_duration": None if wash is None else wash.duration,
            "analogs": len(scene.analogs),
        }
    field = scene.glint
    if field is not None:
        extras["glint"] = {
            "sun_elevation": field.elevation,
            "sun_azimuth": field.azimuth,
            "slope_variance": field.slope_variance,
        }
    return extras


# ------------------------------------------------------------------ step
def step(params: LARSParams, arm, state: EpisodeState, action,
         backend: Backend) -> Transition:
    """One control period of the arm at ``arm`` under ``action`` (the (3,) command already
    checked, :func:`auv_envs.core.env.clip_actions`); the judgement is an
    :class:`Assessment`."""
    ops, _, plant = backend
    arm, effort = plant.advance(arm, action, state.control_effort)
    steps = state.steps + 1
    now = plant.truth(arm, params, state.scene, steps, ops)
    state, judged = assess(params, state, now, action, ops, steps=steps,
                           control_effort=effort)
    state, obs = observe(params, state, now, backend)
    return Transition(arm, state, now, obs, judged)


def assess(params: LARSParams, state: EpisodeState, now: dict, action, ops, steps,
           control_effort):
    """The step's reward terms and end, and the episode's record updated by them, by
    ``steps`` (the step count after this step) and the ``control_effort`` so far."""
    a0, a1, a2 = ops.unpack(action)
    error = now["capture_error"]
    position_tolerance, speed_tolerance = params.tolerance
    captured = (error <= position_tolerance) & (now["relative_speed"] <= speed_tolerance)
    collision = ops.logical_not(captured) & now["tip_in_hull"]
    (x, y, z), (x_lo, y_lo, z_lo), (x_hi, y_hi, z_hi) = (now["end_on_ship"],
                                                         *params.workspace)
    workspace = ops.logical_not((x_lo <= x) & (x <= x_hi) & (y_lo <= y) & (y <= y_hi)
                                & (z_lo <= z) & (z <= z_hi))
    failure = ops.integer(ops.where(collision, 1, ops.where(workspace, 2, 0)))
    failed = collision | workspace
    terms = {
        "progress": state.prev_error - error,
        "control": -0.001 * (a0 * a0 + a1 * a1 + a2 * a2),
        "success": ops.where(captured, 10.0, 0.0),
        "failure": ops.where(failed, -10.0, 0.0),
    }
    state = EpisodeState(
        state.scene, steps, error, ops.minimum(state.min_error, error),
        state.success | captured, failure,
        ops.where(captured, steps * params.dt, state.capture_time),
        state.visible_steps + (now["n_visible"] == 3), state.occluded_steps + now["occluded"],
        state.distractor_steps + (now["distractors"] > 0), state.glint_steps, control_effort,
        state.glint_frame)
    return state, Assessment(terms, captured | failed, collision, workspace)


# ------------------------------------------------------------------ what is seen
def joint_readings(now: dict, xp) -> dict:
    """The joint angles and rates every image-based mode carries."""
    joints = xp.asarray((*now["q"], *now["qd"]), dtype=xp.float32)
    return {"joint_position": joints[:3], "joint_velocity": joints[3:]}


def with_glint_frame(state: EpisodeState, frame: dict, ops) -> EpisodeState:
    """``state`` with the observation's glint ``frame``, counted when a glint took a corner
    after a step."""
    took = (state.steps > 0) & frame["glint_corners"].any()
    return state._replace(glint_frame=frame, glint_steps=state.glint_steps + ops.integer(took))


def observe(params: LARSParams, state: EpisodeState, now: dict, backend: Backend):
    """``(state, observation)``: the ``state`` or ``features`` observation (see the
    environment's docstring); in ``stereo`` mode the joint readings (the shell adds
    the images and their glint, :func:`with_glint_frame`)."""
    ops, draws, _ = backend
    xp = ops.xp
    if params.obs_mode == "state":
        m = state.scene.motion
        (px, py, pz), (ex, ey, ez) = now["position"], now["end"]
        return state, xp.asarray(
            [*now["q"], *now["qd"], ex, ey, ez, *now["end_vel"],
             px - ex, py - ey, pz - ez, *now["velocity"], *now["offset"],
             now["pitch"], m.yaw, now["level"]],
            dtype=xp.float32,
        )
    if params.obs_mode != "features":
        return state, joint_readings(now, xp)
    vis_left, vis_right = visible = now["visible"]
    true_pixels = now["pixels"]
    std = params.pixel_noise_std
    # Drawn always, whatever is visible: the same noise stream every step.
    noise = draws.normal(0.0, std, 12) if std > 0 else None
    seen = vis_left + vis_right
    field = state.scene.glint
    if field is not None:
        true_pixels, seen, frame = params.glint_camera.on_corners(field, now, seen, draws, ops)
        visible = [seen[:3], seen[3:]]
        state = with_glint_frame(state, frame, ops)
    pixels = seen_pixels(true_pixels, noise, seen, *params.pixel_bounds, ops)
    readings = xp.asarray((*pixels, *now["q"], *now["qd"]), dtype=xp.float32)
    return state, {
        "pixels": readings[:12].reshape(2, 3, 2),
        "visible": xp.asarray(visible, dtype=xp.int8),
        "joint_position": readings[12:15],
        "joint_velocity": readings[15:],
    }


# ------------------------------------------------------------------ the record
def failure_reason(state: EpisodeState) -> str:
    """This step's failure by name ("" when none)."""
    return FAILURE_REASONS[state.failure - 1] if state.failure else ""


def end_reason(failure, success) -> str:
    """How an episode ended, by name: its failure's (``failure`` the code of
    :class:`EpisodeState`), ``""`` when it captured, ``"time_limit"`` otherwise."""
    failure = int(failure)
    if failure:
        return FAILURE_REASONS[failure - 1]
    return "" if success else "time_limit"


def info(params: LARSParams, state: EpisodeState, now: dict,
         judged: Assessment | None) -> dict:
    """The step's ``info`` without the reward terms (see the environment's docstring)."""
    (px, py, pz), (ex, ey, ez) = now["position"], now["end"]
    # Every vector in one array (one NumPy call, not seven); each key is its own rows.
    flat = np.array((*now["offset"], px - ex, py - ey, pz - ez, *now["position"],
                     *now["velocity"], *now["end"], *now["corners"], *now["pixels"]))
    out = {
        "capture_error": now["capture_error"],
        "capture_offset": flat[0:3],
        "relative_position": flat[3:6],
        "relative_speed": now["relative_speed"],
        "is_success": state.success,
        "collision": judged is not None and judged.collision,
        "violation_workspace": judged is not None and judged.workspace,
        "marker_visible": now["n_visible"],
        "marker_occluded": now["occluded"],
        "distractors_in_view": now["distractors"],
        "failure_reason": failure_reason(state),
        "time": state.steps * params.dt,
        "true_position": flat[6:9],
        "true_velocity": flat[9:12],
        "true_pitch": now["pitch"],
        "true_yaw": state.scene.motion.yaw,
        "true_corners": flat[15:24].reshape(3, 3),
        "true_pixels": flat[24:36].reshape(2, 3, 2),
        "true_visible": np.array(now["visible"]),
        "end_position": flat[12:15],
        "water_level": now["level"],
    }
    if state.glint_frame is not None:
        out.update(state.glint_frame)
    sample = now["sea"]
    if sample is not None:
        out["true_roll"] = now["roll"]
        out["ship_motion"] = np.array((sample.ship_heave, sample.ship_roll, sample.ship_pitch))
    return out


def step_metrics(state: EpisodeState, now: dict, judged: Assessment | None, ops) -> dict:
    """The step's metrics that are numbers (:data:`STEP_METRICS`; no violation at reset,
    ``judged`` None)."""
    false = ops.boolean(False)
    return {
        "capture_error": now["capture_error"],
        "relative_speed": now["relative_speed"],
        "marker_visible": now["n_visible"],
        "marker_occluded": ops.boolean(now["occluded"]),
        "distractors_in_view": ops.integer(now["distractors"]),
        "is_success": state.success,
        "collision": false if judged is None else judged.collision,
        "violation_workspace": false if judged is None else judged.workspace,
    }


def summary(params: LARSParams, state: EpisodeState, now: dict, ops) -> dict:
    """The episode's summary as numbers: ``failure`` the code of :class:`EpisodeState`,
    ``capture_time`` NaN when it did not capture, ``glint_fraction`` with glint only
    (:func:`episode_metrics` names and formats them)."""
    steps = ops.maximum(state.steps, 1)
    glint = {} if params.glint is None else {"glint_fraction": state.glint_steps / steps}
    return {
        "success": state.success,
        "failure": state.failure,
        "capture_time": state.capture_time,
        "steps": state.steps,
        "final_capture_error": now["capture_error"],
        "min_capture_error": state.min_error,
        "final_relative_speed": now["relative_speed"],
        "marker_visible_fraction": state.visible_steps / steps,
        "occluded_fraction": state.occluded_steps / steps,
        "distractor_fraction": state.distractor_steps / steps,
        "control_effort": state.control_effort,
        **glint,
    }


def episode_metrics(params: LARSParams, state: EpisodeState, now: dict) -> dict:
    """``info["episode_metrics"]``: :func:`summary` with the failure named
    (``failure_reason``: ``"time_limit"`` when it neither captured nor failed) and
    ``capture_time`` None when it did not capture."""
    out = {}
    for key, value in summary(params, state, now, FLOATS).items():
        if key == "failure":
            key, value = "failure_reason", end_reason(state.failure, state.success)
        elif key == "capture_time" and math.isnan(value):
            value = None
        out[key] = value
    return out
