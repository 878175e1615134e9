"""The AHRS heading's deviation from the station's frame, measured with the lights.

A compass near a station's steel, or a station surveyed with an error, reads a heading off
the station's frame by an angle ``b`` that stays through the episode (``hard``:
``AHRS.heading_bias_std`` = 8 deg RMS, :mod:`auv_envs.tasks.docking.navigation`). Dead reckoning
and USBL fixes cannot see it: both are rotated by the same ``R_z(b)`` (the DVL's track
turned by the AHRS, the fix's body-frame vector turned by it too), so the navigation
filter's whole world is the true one turned by ``b`` about the transponder, and a vehicle
homing on it reaches the entrance ``b`` off the docking axis. The lights are fixed in the
station's frame: once enough are detected they give the camera's yaw in that frame, and so
``b``.

It is an iterated extended Kalman filter (Bell and Cathey 1993; the measurement model
of :class:`~baselines.docking.estimation.camera_position.CameraPositionFilter`, with the
heading free) on ``x = (p, b)``: ``p`` the CG position in the station's frame, ``b`` the
deviation, constant over the episode.

* **Start**: ``b ~ N(0, sigma_b^2)`` (the suite's ``heading_bias_std``; 0 where the level
  has none, and the estimate then stays 0). The first frame with ``min_lamps`` detected
  lamps places ``p`` where their rays meet at the heading ``psi_AHRS - b_hat`` (linear
  least squares), variance :data:`START_VAR`.
* **Prediction** (DVL dead reckoning on the corrected heading)::

      p_k = p_{k-1} + R(phi, theta, psi_AHRS - b) v dt,   F = [[I, -e_z x (R v dt)], [0, 1]]
      Q = diag((dt^2 s_v^2 + q) I, 0)

* **Update** with the detected lamps' pixels, the frame's AHRS errors ``e = (e_phi,
  e_theta, e_psi)`` as nuisance states (``N(0, diag(s_rp^2, s_rp^2, s_psi^2))``, white
  from frame to frame, marginalised after the update). The body's attitude is
  ``(phi - e_phi, theta - e_theta, psi_AHRS - b - e_psi)``, the camera's rotation
  ``R_c = R_b R_bc`` and ``q_i = R_c^T (L_i - p - R_b o_c)``::

      h_i = (f_x q_x / q_z + c_x, f_y q_y / q_z + c_y)
      dq_i/dp = -R_c^T
      dq_i/d(angle) = R_bc^T (a x R_b^T (L_i - p)),  a = e_x (roll), R_x(phi)^T e_y (pitch),
                      R_b^T e_z (heading; b and e_psi alike)

  each lamp's noise ``sigma_i^2`` its pixel variance at its range (:func:`pixel_variance`:
  the sensor's, and the water's blur). The frame is taken if its normalised innovation
  squared at the prior is within chi-square's 99.9 % point for its pixel count and every
  detected lamp lies in front of the camera; :data:`MAX_MISSES` rejected frames in a row
  start the position again (the deviation's estimate kept).

What the lamps can tell is their perspective: on this station they sit 2.55 m inside the
entrance on a ring of 0.45 m, so a turn of the station by ``delta`` moves a lamp's image by
about ``f r^2 delta / Z^2`` pixels (2 px a radian at 8 m): the deviation is learnt in the
last few metres, where the perspective grows (``tests/test_light_heading.py``). Neither
dead reckoning nor the lamps' bearings can see it: both live in the body's axes.

Pure functions of arrays over an array namespace (NumPy or ``jax.numpy`` under ``jit`` and
``vmap``), as :mod:`~baselines.docking.estimation.navigation_filter`; the mission's learners
apply both in their front end (:mod:`baselines.rl.nav_filter`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import stats

from auv_envs.core.frames import wrap_angle
from baselines.docking.estimation.navigation_filter import (
    FilterParams,
    NavigationFilter,
    rotation,
)

#: Most lamps a station has (the gates' table is this long).
MAX_LAMPS = 8
#: Normalised innovation squared beyond which a frame's lamps are rejected, by the number of
#: pixel coordinates (twice the lamps): chi-square's 99.9 % point.
NIS_GATES = (0.0,) + tuple(float(stats.chi2.ppf(0.999, k)) for k in range(1, 2 * MAX_LAMPS + 1))
#: Iterations of the iterated EKF's update.
ITERATIONS = 4
#: Variance of the position where the lamps' rays first meet, m^2 (they meet at the yaw the
#: deviation's estimate gives; 2 m standard deviation).
START_VAR = 4.0
#: Consecutive frames the gate may reject before the position starts again.
MAX_MISSES = 10
#: (4, 4) masks: the deviation's variance; the position's block.
_E33 = np.diag([0.0, 0.0, 0.0, 1.0])
_POSITION = np.diag([1.0, 1.0, 1.0, 0.0])


class HeadingParams(NamedTuple):
    """What the estimator knows: the station's lamps and the camera (the calibration), the
    AHRS's noise and the deviation's prior (the navigation suite's figures) and the dead
    reckoning's noise (the navigation filter's). Arrays are NumPy's, built once."""

    lights: np.ndarray           # (n, 3) lamp centres, station frame, m
    camera_position: np.ndarray  # (3,) camera centre, body frame, m
    camera_rotation: np.ndarray  # (3, 3) OpenCV camera frame to body
    intrinsics: tuple            # (fx, fy, cx, cy), px
    pixel_var: float             # the sensor's pixel noise, px^2
    optics: object               # the water (WaterOptics: the centroid's noise) or None
    attitude_cov: np.ndarray     # (3, 3) the AHRS roll's, pitch's and heading's white noise
    deviation_var: float         # the prior of the deviation, rad^2
    motion: FilterParams         # dt, the DVL's noise, the random walk (the nav filter's)
    min_lamps: int = 3

    @classmethod
    def of(cls, calibration, navigation) -> HeadingParams:
        """From a docking env's ``calibration`` and its navigation suite (data-sheet noise;
        the deviation's spread); the dead reckoning's noise is
        :meth:`NavigationFilter.for_suite`'s."""
        k = calibration.intrinsics
        if len(calibration.light_positions) > MAX_LAMPS:
            raise ValueError(f"the lights' heading filter takes at most {MAX_LAMPS} lamps")
        ahrs = navigation.ahrs
        return cls(np.array(calibration.light_positions, dtype=float),
                   np.array(calibration.extrinsics.position, dtype=float),
                   calibration.extrinsics.rotation_matrix.astype(float),
                   (float(k.fx), float(k.fy), float(k.cx), float(k.cy)),
                   float(calibration.pixel_noise_std) ** 2, calibration.optics,
                   np.diag([ahrs.roll_pitch_std, ahrs.roll_pitch_std, ahrs.heading_std]) ** 2,
                   float(ahrs.heading_bias_std) ** 2,
                   NavigationFilter.for_suite(navigation, calibration.control_period).params)


class HeadingState(NamedTuple):
    """The filter between observations (a JAX pytree, as it is a tuple)."""

    position: object    # (3,) CG position, station frame, m (meaningful once started)
    deviation: object   # b_hat, rad
    covariance: object  # (4, 4) of (position, deviation)
    velocity: object    # (3,) the last bottom-locked DVL velocity, body, m/s
    started: object     # whether the lamps have placed the position
    misses: object      # consecutive frames whose lamps the gate rejected
    updates: object     # frames taken
    rejected: object    # frames gated out

    @classmethod
    def start(cls, params: HeadingParams, xp=np) -> HeadingState:
        dtype = np.float64 if xp is np else xp.float32
        covariance = xp.asarray(params.deviation_var * _E33, dtype)
        return cls(xp.zeros(3, dtype), xp.asarray(0.0, dtype), covariance,
                   xp.zeros(3, dtype), xp.asarray(False), xp.asarray(0), xp.asarray(0),
                   xp.asarray(0))


def _projection(params: HeadingParams, q, xp):
    """Pixels (n, 2) of the camera-frame points ``q`` (n, 3), and d(pixel)/dq (n, 2, 3)."""
    fx, fy, cx, cy = params.intrinsics
    z = xp.maximum(q[:, 2], 1e-3)
    u, v = fx * q[:, 0] / z + cx, fy * q[:, 1] / z + cy
    zero = xp.zeros_like(z)
    du = xp.stack([fx / z, zero, -fx * q[:, 0] / z**2], axis=-1)
    dv = xp.stack([zero, fy / z, -fy * q[:, 1] / z**2], axis=-1)
    return xp.stack([u, v], axis=-1), xp.stack([du, dv], axis=1)


def _rays_meet(params: HeadingParams, R_c, pixels, weight, xp):
    """The point nearest the detected lamps' rays (least squares): for each lamp the
    direction ``d_i = R_c K^-1 (u, v, 1)``, and ``c = (sum A_i)^-1 sum A_i L_i`` with
    ``A_i = I - d_i d_i^T``."""
    fx, fy, cx, cy = params.intrinsics
    lights = xp.asarray(params.lights, dtype=R_c.dtype)
    rays = xp.stack([(pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy,
                     xp.ones_like(pixels[:, 0])], axis=-1) @ R_c.T
    d = rays / xp.linalg.norm(rays, axis=-1, keepdims=True)
    A = (xp.eye(3, dtype=R_c.dtype)[None] - d[:, :, None] * d[:, None, :]) * weight[:, None, None]
    total = xp.sum(A, axis=0) + 1e-6 * xp.eye(3, dtype=R_c.dtype)
    return xp.linalg.solve(total, xp.sum(A @ lights[:, :, None], axis=0))[:, 0]


def pixel_variance(params: HeadingParams, distance, xp=np):
    """Each lamp's pixel variance at ``distance`` (m): the sensor's noise, the centroid's
    in the water (:meth:`WaterOptics.centroid_std`) and a quarter pixel squared (the
    pixel grid's)."""
    var = params.pixel_var + 0.25
    if params.optics is not None:
        var = var + params.optics.centroid_std(distance, params.intrinsics[0], xp) ** 2
    return var


def _measurement(params: HeadingParams, lights, x, attitude, xp):
    """The lamps' pixels (n, 2) at ``x = (p, b, e_roll, e_pitch, e_yaw)`` (the attitude
    ``attitude - (e_roll, e_pitch, b + e_yaw)``), their Jacobian (n, 2, 6) and the lamps in
    the camera frame (n, 3)."""
    roll, pitch = attitude[0] - x[4], attitude[1] - x[5]
    yaw = attitude[2] - x[3] - x[6]
    R_b = rotation(xp.stack([roll, pitch, yaw]), xp)
    R_bc = xp.asarray(params.camera_rotation, dtype=R_b.dtype)
    R_c = R_b @ R_bc
    camera = x[:3] + R_b @ xp.asarray(params.camera_position, dtype=R_b.dtype)
    w = lights - x[:3]
    q = (lights - camera) @ R_c  # rows R_c^T (L_i - c)
    pixels, dpix = _projection(params, q, xp)
    # d q / d angle = -R_bc^T (a x R_b^T w) for R_b turned by [a]x on the right: roll
    # a = e_x, pitch a = R_x(roll)^T e_y, yaw R_b^T e_z; the angles enter with a minus
    body = w @ R_b  # rows R_b^T w
    axes = (xp.asarray([1.0, 0.0, 0.0], R_b.dtype),
            xp.stack([xp.zeros_like(roll), xp.cos(roll), -xp.sin(roll)]), R_b[2])
    turns = [(xp.cross(a, body) @ R_bc)[:, :, None] for a in axes]
    dq = xp.concatenate([xp.broadcast_to(-R_c.T, (lights.shape[0], 3, 3)), turns[2],
                         turns[0], turns[1], turns[2]], axis=-1)
    return pixels, dpix @ dq, q


def step(params: HeadingParams, state: HeadingState, obs, xp=np) -> HeadingState:
    """Take one ``nav_features`` observation (after the step it describes): dead reckoning
    with its DVL velocity, then its detected lamps (the module docstring)."""
    dtype = state.deviation.dtype
    motion = params.motion
    attitude = xp.asarray(obs["attitude"], dtype)
    roll, pitch, yaw_measured = attitude[0], attitude[1], attitude[2]
    # dead reckoning on the corrected heading: p += R(yaw - b) v dt, d(moved)/db = -e_z x moved
    locked = xp.asarray(obs["dvl_valid"])[0] > 0
    velocity = xp.where(locked, xp.asarray(obs["dvl_velocity"], dtype), state.velocity)
    R = rotation(xp.stack([roll, pitch, yaw_measured - state.deviation]), xp)
    moved = R @ velocity * motion.dt
    e_z = xp.asarray([0.0, 0.0, 1.0], dtype)
    column = xp.concatenate([-xp.cross(e_z, moved), xp.zeros(1, dtype)])
    F = xp.eye(4, dtype=dtype) + column[:, None] * xp.asarray(_E33[3], dtype)[None, :]
    walk = motion.dt**2 * (motion.dvl_var + xp.where(locked, 0.0, motion.held_dvl_var)) \
        + motion.random_walk
    predicted = F @ state.covariance @ F.T + walk * xp.asarray(_POSITION, dtype)
    predicted = xp.where(state.started, predicted, state.covariance)
    reckoned = xp.where(state.started, state.position + moved, state.position)
    seen = xp.asarray(obs["visible"]) > 0
    if xp is np and not seen.any():  # NumPy skips the update: without lamps it changes nothing
        return state._replace(position=reckoned, covariance=predicted, velocity=velocity)
    # the lamps: the first frame with min_lamps of them starts the position where their
    # rays meet, with START_VAR
    lights = xp.asarray(params.lights, dtype)
    pixels = xp.asarray(obs["pixels"], dtype)
    count = xp.sum(seen)
    R_c = R @ xp.asarray(params.camera_rotation, dtype)
    first = _rays_meet(params, R_c, pixels, seen.astype(dtype), xp) \
        - R @ xp.asarray(params.camera_position, dtype)
    starting = ~state.started & (count >= params.min_lamps)
    position = xp.where(state.started, reckoned, first)
    prior = xp.where(state.started, predicted,
                     state.covariance + START_VAR * xp.asarray(_POSITION, dtype))
    # iterated EKF on x = (p, b, e), e the frame's attitude noise (roll, pitch, heading)
    x_bar = xp.concatenate([position, state.deviation[None], xp.zeros(3, dtype)])
    noise = xp.asarray(params.attitude_cov, dtype)
    P_bar = xp.block([[prior, xp.zeros((4, 3), dtype)], [xp.zeros((3, 4), dtype), noise]])
    mask = xp.repeat(seen, 2)
    z = pixels.reshape(-1)
    x = x_bar
    for k in range(ITERATIONS):
        h, H, q = _measurement(params, lights, x, attitude, xp)
        variance = xp.repeat(pixel_variance(params, xp.linalg.norm(q, axis=-1), xp), 2)
        H = xp.where(mask[:, None], H.reshape(-1, 7), 0.0)
        r = xp.where(mask, z - h.reshape(-1), 0.0)
        S_inv = xp.linalg.inv(H @ P_bar @ H.T + xp.diag(xp.where(mask, variance, 1.0)))
        if k == 0:  # the gate, at the prior
            nis = r @ S_inv @ r
            in_front = xp.all((q[:, 2] > 0.1) | ~seen)
        K = P_bar @ H.T @ S_inv
        x = x_bar + K @ (r + H @ (x - x_bar))
    fitted = (xp.eye(7, dtype=dtype) - K @ H) @ P_bar
    tried = (state.started | starting) & (count > 0)
    took = tried & in_front & (nis <= xp.asarray(NIS_GATES, dtype)[2 * count]) \
        & xp.all(xp.isfinite(x))
    covariance = xp.where(took, 0.5 * (fitted[:4, :4] + fitted[:4, :4].T), prior)
    misses = xp.where(took, 0, state.misses + (tried & ~took))
    # a filter the lamps keep rejecting starts again at the next frame's rays (the
    # deviation's estimate and variance kept)
    started = (state.started | (starting & took)) & (misses < MAX_MISSES)
    covariance = xp.where(started, covariance, covariance * xp.asarray(_E33, dtype))
    return HeadingState(xp.where(took, x[:3], reckoned),
                        xp.where(took, x[3], state.deviation).astype(dtype),
                        covariance.astype(dtype), velocity, started,
                        xp.where(started, misses, 0), state.updates + took,
                        state.rejected + (tried & ~took))


def corrected_attitude(state: HeadingState, attitude, xp=np):
    """The AHRS ``attitude`` with the estimated deviation taken off its heading."""
    attitude = xp.asarray(attitude)
    yaw = wrap_angle(attitude[2] - state.deviation.astype(attitude.dtype))
    return xp.concatenate([attitude[:2], yaw[None]]).astype(attitude.dtype)
