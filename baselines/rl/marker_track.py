"""LARS capture on ``features`` for a batched learner: a fixed-gain tracker of the marker fixes.

:class:`~baselines.rl.marker_estimate.MarkerEstimate` runs ``ckf-pd``'s estimator
(cubature Kalman filter, heave refit, gating) in Python, about 0.6 ms an observation:
it cannot run inside a compiled, batched rollout. This module is the same kind of
front end written as pure functions of arrays, evaluated with NumPy on the CPU
(:class:`MarkerTrack`, the Gymnasium wrapper the shipped agent applies) and with
``jax.numpy`` under ``jit`` and ``vmap`` (:class:`MarkerTrackMJX`, around the batched
env the compiled PPO trains on): one definition for both.

Each observation:

1. **Marker fix** ([LTAT] §2.2, as :class:`~baselines.lars.perception.marker.MarkerLocaliser`):
   the corners seen in both images with a disparity above
   :data:`~baselines.lars.perception.marker.MIN_DISPARITY` triangulated (eq. 2), carried
   to the arm's frame by the hand-eye transform and the arm's kinematics (eq. 3); with
   all three, the AUV's pitch and yaw (eqs. 4-6,
   :func:`~baselines.lars.perception.marker.marker_attitude`).
2. **Attitude**: the running mean of the fixes' pitch and yaw
   (:class:`~baselines.lars.estimation.auv_state.PitchYawMean`'s rule).
3. **Position**: the AUV's CG from the triangulated corners and the mean attitude,
   tracked by an alpha-beta filter (a constant-velocity Kalman filter at its steady
   gains; Kalata 1984, "The tracking index", IEEE TAES 20(2)): predicted one control
   period on, corrected by ``alpha`` and ``beta / dt`` times the fix's residual; the
   first fix starts it at rest.

The learner's observation is :data:`LAYOUT`, the layout of ``MarkerEstimate``'s, so
:class:`~baselines.rl.marker_estimate.JointResidualPolicy` reads either. The tracker's
gains were chosen on the untrained servo (``docs/training.md``).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from auv_envs.core.ops import FLOATS
from auv_envs.tasks.lars.stereo import points_from_disparity
from baselines.lars.estimation.auv_state import ATTITUDE_MEMORY
from baselines.lars.perception.marker import MIN_DISPARITY, attitude_rotation, marker_attitude
from baselines.rl.batched_front_end import BatchedFrontEnd, FrontEnd
from baselines.rl.config import ConfigError

#: The layout of the front ends' observation vector (``MarkerEstimate``'s and
#: :class:`MarkerTrack`'s): name and length.
LAYOUT = (
    ("hold_target", 3),       # q as the position action that holds it, (q - mid) / half
    ("joint_velocity", 3),    # rad/s
    ("offset", 3),            # capture point minus capture tip, m (arm frame)
    ("relative_velocity", 3),  # AUV CG velocity minus tip velocity, m/s
    ("offset_ahead", 3),      # the offset HORIZON s ahead (tip held still), m
    ("estimate", 3),          # settled, attitude/heave known, ln(1 + steps since the last fix)
    # the three vectors above in joint-target units: J(q)^-1 v / half (the joint-target
    # change that would move the tip by v, the arm's first-order inverse kinematics)
    ("joint_offset", 3),
    ("joint_relative_velocity", 3),
    ("joint_offset_ahead", 3),
)
#: s ahead of ``offset_ahead``.
HORIZON = 0.5
SIZE = sum(n for _, n in LAYOUT)


def _slices() -> dict[str, slice]:
    out, start = {}, 0
    for name, n in LAYOUT:
        out[name] = slice(start, start + n)
        start += n
    return out


SLICES = _slices()

#: The tracker's gains: alpha (position) and beta (velocity, per control period).
ALPHA, BETA = 0.3, 0.05
#: Fixes before the track counts as settled (the learner's ``estimate[0]``): a choice
#: (0.2 s of fixes), not measured; ``ckf-pd``'s filter waits 0.5 s.
SETTLE_FIXES = 5
#: Below this |det J| the arm is singular and the joint-unit vectors are zero.
SINGULAR = 1e-9


@dataclasses.dataclass(frozen=True)
class TrackParams:
    """What the tracker knows, from the env's calibration (its constants are Python
    numbers and NumPy arrays, so they are compile-time constants under ``jit``).

    Attributes:
        calibration: the env's ``LARSCalibration`` (stereo rig, hand-eye transform, arm
            kinematics, marker geometry).
        position_action: the env's ``position_action(q, xp)``, the joint targets'
            action (the ``control="position"`` map's inverse).
        joint_half: (3,) that map's scale (``q = mid + half * action``).
        alpha, beta: the tracker's gains.
    """

    calibration: object
    position_action: object
    joint_half: np.ndarray
    alpha: float = ALPHA
    beta: float = BETA

    @classmethod
    def of(cls, env: gym.Env, **gains) -> TrackParams:
        """The parameters for ``env`` (a ``LARSCapture-v0`` CPU env, wrapped or not, or the
        setup of one, :func:`auv_envs.tasks.lars.config.params`)."""
        base = getattr(env, "unwrapped", env)
        cal = getattr(base, "calibration", None)
        if getattr(base, "obs_mode", None) != "features" or not hasattr(cal, "stereo"):
            raise ConfigError("the marker tracker needs auv_envs/LARSCapture-v0 with "
                              "obs_mode='features'")
        return cls(cal, base.position_action, np.asarray(base.params.joint_half, float),
                   **gains)


class TrackState(NamedTuple):
    """The tracker between observations (a JAX pytree as it is a tuple)."""

    position: object   # (3,) CG, m
    velocity: object   # (3,) m/s
    pitch: object      # rad (the running mean)
    yaw: object        # rad
    attitudes: object  # attitude fixes taken in
    fixes: object      # position fixes taken in
    since_fix: object  # observations since the last position fix

    @classmethod
    def start(cls, xp=np) -> TrackState:
        zero = xp.zeros(3)
        return cls(zero, zero, xp.asarray(0.0), xp.asarray(0.0), xp.asarray(0), xp.asarray(0),
                   xp.asarray(0))


def _ops_of(xp):
    if xp is np:
        return FLOATS
    from auv_envs.core.ops import jax_ops

    return jax_ops()


def _arm_end(p: TrackParams, q, qd, xp):
    """The arm end's position and velocity (3,) each (the arm's own kinematics)."""
    return xp.stack(p.calibration.arm.end_state(tuple(q[i] for i in range(3)),
                                                tuple(qd[i] for i in range(3)), xp)).reshape(2, 3)


def fix(p: TrackParams, pixels, visible, q, xp=np):
    """The marker corners (3, 3) in the arm's frame and which were triangulated (3,)
    (seen in both images with a disparity above ``MIN_DISPARITY``; the others' rows are
    meaningless)."""
    cal = p.calibration
    rig = cal.stereo
    left, right = pixels[0], pixels[1]
    disparity = rig.disparity(left[:, 0], right[:, 0], xp)
    valid = (visible[0] != 0) & (visible[1] != 0) & (disparity > MIN_DISPARITY)
    # eq. 2 on every row; the rows not triangulated read the principal point at disparity 1
    centre = xp.asarray((rig.left.cx, rig.left.cy))
    camera = points_from_disparity(rig, xp.where(valid[:, None], left, centre),
                                   xp.where(valid, disparity, 1.0), xp)
    # eq. 3: the camera's pose is the levelled arm end's composed with the hand-eye
    # transform (LARSCalibration.camera_poses)
    slew = cal.arm.end_rotation(q, _ops_of(xp))
    end = _arm_end(p, q, xp.zeros(3), xp)[0]
    rotation = slew @ cal.left_in_end[:3, :3]
    origin = end + slew @ cal.left_in_end[:3, 3]
    return camera @ rotation.T + origin, valid


def track(p: TrackParams, state: TrackState, obs: dict, xp=np) -> TrackState:
    """The tracker after the ``features`` observation ``obs`` (module docstring)."""
    ops = _ops_of(xp)
    cal = p.calibration
    corners, valid = fix(p, xp.asarray(obs["pixels"], dtype=float), obs["visible"],
                         xp.asarray(obs["joint_position"], dtype=float), xp)
    full = valid[0] & valid[1] & valid[2]
    body = np.asarray(cal.marker.corners, dtype=float)
    # (without all three corners, the body's own corners stand in: a finite, unused angle)
    pitch, yaw = marker_attitude(xp.where(full, corners, body), cal.marker.depth_offset,
                                 ops=ops)
    attitudes = state.attitudes + full
    weight = 1.0 / xp.maximum(xp.minimum(attitudes, ATTITUDE_MEMORY), 1)
    first = state.attitudes == 0
    pitch = xp.where(full, xp.where(first, pitch, state.pitch + weight * (pitch - state.pitch)),
                     state.pitch)
    yaw = xp.where(full, xp.where(first, yaw, state.yaw + weight * (yaw - state.yaw)),
                   state.yaw)
    rotation = attitude_rotation(pitch, yaw, xp)
    count = xp.sum(valid)
    cg = xp.sum(xp.where(valid[:, None], corners - body @ rotation.T, 0.0), axis=0) \
        / xp.maximum(count, 1)
    measured = (attitudes > 0) & (count > 0)
    started = state.fixes > 0
    predicted = state.position + state.velocity * cal.control_period
    residual = cg - predicted
    position = xp.where(measured, xp.where(started, predicted + p.alpha * residual, cg),
                        xp.where(started, predicted, state.position))
    velocity = xp.where(measured & started,
                        state.velocity + (p.beta / cal.control_period) * residual,
                        state.velocity)
    return TrackState(position, velocity, pitch, yaw, attitudes, state.fixes + measured,
                      xp.where(measured, 0, state.since_fix + 1))


def _solve3(matrix, vectors, xp):
    """``matrix^-1 @ vectors`` for a (3, 3) matrix and (3, m) columns, by its adjugate;
    zero where ``|det| <`` :data:`SINGULAR`."""
    a = matrix
    cof = xp.stack([xp.cross(a[:, 1], a[:, 2]), xp.cross(a[:, 2], a[:, 0]),
                    xp.cross(a[:, 0], a[:, 1])])  # rows: the adjugate's rows
    det = xp.dot(a[:, 0], cof[0])
    ok = xp.abs(det) >= SINGULAR
    return xp.where(ok, cof @ vectors / xp.where(ok, det, 1.0), 0.0)


def observe(p: TrackParams, state: TrackState, obs: dict, xp=np):
    """The learner's observation (:data:`LAYOUT`, float32) from the tracker and the joint
    readings of ``obs``; before the first position fix the offsets and velocities are 0."""
    cal = p.calibration
    q = xp.asarray(obs["joint_position"], dtype=float)
    qd = xp.asarray(obs["joint_velocity"], dtype=float)
    end, end_velocity = _arm_end(p, q, qd, xp)
    tip = end + np.asarray(cal.capture_tip_in_end, dtype=float)  # the head is levelled
    rotation = attitude_rotation(state.pitch, state.yaw, xp)
    capture = state.position + rotation @ np.asarray(cal.capture_point_body, dtype=float)
    offset = capture - tip
    cartesian = xp.stack([offset, state.velocity - end_velocity,
                          offset + state.velocity * HORIZON])
    cartesian = xp.where(state.fixes > 0, cartesian, 0.0)
    # the Jacobian's columns: the end's velocity at unit joint rates (it is linear in them)
    unit = np.eye(3)
    jacobian = xp.stack([_arm_end(p, q, unit[i], xp)[1] for i in range(3)], axis=1)
    joint = _solve3(jacobian, cartesian.T, xp).T / p.joint_half
    estimate = xp.stack([(state.fixes >= SETTLE_FIXES) * 1.0, (state.attitudes > 0) * 1.0,
                         xp.log1p(state.since_fix * 1.0)])
    return xp.concatenate([p.position_action(q, xp), qd, cartesian.reshape(-1),
                           estimate, joint.reshape(-1)]).astype(xp.float32)


class MarkerTrack(FrontEnd):
    """The LARS ``features`` observation replaced by the marker tracker's
    (:data:`LAYOUT`, a ``Box((27,), float32)``; module docstring), on the CPU with NumPy.

    ``marker_track: true`` in a training config or a policy manifest applies it
    (:data:`baselines.rl.config.FRONT_ENDS`); the tracker keeps the episode's state
    (:class:`~baselines.rl.batched_front_end.FrontEnd`).

    Raises:
        ConfigError: the environment is not ``LARSCapture-v0`` in ``features`` mode.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.params = TrackParams.of(env)
        self.observation_space = spaces.Box(-np.inf, np.inf, (SIZE,), np.float32)
        self.clear()

    def start(self) -> TrackState:
        return TrackState.start()

    def advance(self, carry: TrackState, obs) -> tuple:
        carry = track(self.params, carry, obs)
        return carry, observe(self.params, carry, obs)


class MarkerTrackMJX(BatchedFrontEnd):
    """A batched LARS env (:class:`~auv_envs.batched.functional.FunctionalEnv`, ``features``)
    whose observation is the marker tracker's (:data:`LAYOUT`), computed in JAX by the
    functions :class:`MarkerTrack` runs on the CPU. The tracker's state rides in
    ``state.info["marker_track"]`` and starts afresh where an episode restarted
    (:class:`~baselines.rl.batched_front_end.BatchedFrontEnd`)."""

    INFO_KEY = "marker_track"

    def __init__(self, env):
        super().__init__(env)
        self.params = TrackParams.of(env.task.setup)
        self.observation_space = self.around(spaces.Box(-np.inf, np.inf, (SIZE,), np.float32))

    def start(self) -> TrackState:
        return TrackState.start(self._jnp)

    def advance(self, carry: TrackState, obs) -> tuple:
        carry = track(self.params, carry, obs, self._jnp)
        return carry, observe(self.params, carry, obs, self._jnp)
