"""The one place for frame conventions.

Conventions used everywhere in ``auv_envs``:

* **World** frame: right-handed, z up (MuJoCo's convention). For the docking
  tasks the world frame *is* the docking-station (DS) frame: origin at the
  centre of the entrance plane, x along the docking axis (pointing into the
  station), y to the left, z up.
* **Body** frame: forward-left-up (FLU): x to the bow, y to port, z up. The
  body origin is the centre of gravity (CG).
* **Euler angles**: roll, pitch, yaw about body x, y, z, composed ZYX
  (``R = Rz(yaw) Ry(pitch) Rx(roll)``, body -> world). Yaw is counter-clockwise
  seen from above; yaw = 0 points along world +x.
* **Camera** frame: OpenCV's (x right, y down, z along the optical axis).
  MuJoCo cameras look along their -z with y up; :data:`R_MJCAM_TO_CV` maps one
  to the other.

Fossen's textbook equations use NED / forward-right-down frames. The equations
of motion keep their form in any right-handed pair of frames, so parameters
carry over unchanged; only vectors need converting, which
:func:`ned_to_enu` and :func:`frd_to_flu` do.
"""

from __future__ import annotations

import math
import operator

import numpy as np

from auv_envs.core.ops import FLOATS

#: Rotation from MuJoCo's camera frame (-z forward, y up) to OpenCV's
#: (z forward, y down). Its own inverse.
R_MJCAM_TO_CV = np.diag([1.0, -1.0, -1.0])

#: Standard gravity (m/s^2).
GRAVITY = 9.81


def rotation_from_euler(roll, pitch, yaw, ops):
    """Body-to-world rotation matrix for ZYX Euler angles (radians).

    ``ops`` is ``numpy`` (returns a (3, 3) array), ``jax.numpy`` (a
    (3, 3) JAX array) or ``casadi`` (symbolic angles; returns a 3x3 CasADi matrix), as in
    :mod:`auv_envs.core.hydrodynamics`: one definition for the environments and
    the CasADi observers.
    """
    rows = rotation_rows_from_euler(roll, pitch, yaw, ops)
    if hasattr(ops, "vertcat"):
        return ops.vertcat(*(ops.horzcat(*row) for row in rows))
    return ops.array(rows)


def rotation_rows_from_euler(roll, pitch, yaw, ops) -> list:
    """:func:`rotation_from_euler`'s matrix as three rows of three scalars, in the
    arithmetic of ``ops`` (anything with ``cos`` and ``sin``: a module, or an ``ops``
    namespace of :mod:`auv_envs.core.ops`)."""
    cr, sr = ops.cos(roll), ops.sin(roll)
    cp, sp = ops.cos(pitch), ops.sin(pitch)
    cy, sy = ops.cos(yaw), ops.sin(yaw)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


def rotation_rows_from_quat(w, x, y, z) -> tuple:
    """Body-to-world rotation of the unit quaternion ``(w, x, y, z)`` (MuJoCo's order), as
    9 scalars row by row.

    Plain arithmetic on the four components: floats, NumPy arrays or JAX arrays
    (a batch at once, elementwise), as :func:`auv_envs.core.hydrodynamics.hydrodynamic_force`.
    """
    return (
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
        2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
        2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y),
    )


def quat_integrate(quat, omega_body, h, ops):
    """The unit quaternion ``quat`` (w, x, y, z) turned by the body-frame angular velocity
    ``omega_body`` for ``h`` seconds: ``quat * exp(omega h / 2)``, normalised (MuJoCo's
    free-joint position update). ``ops``: ``numpy`` or ``jax.numpy``; the last axis holds
    the components, leading axes are a batch (:func:`quat_turned` on each)."""
    turned = quat_turned(tuple(quat[..., k] for k in range(4)),
                         tuple(omega_body[..., k] for k in range(3)), h, ops)
    return ops.stack(turned, axis=-1)


def quat_turned(quat, omega_body, h, ops) -> tuple:
    """:func:`quat_integrate` in scalar arithmetic: the 4 components of ``quat`` turned by
    the 3 of ``omega_body`` for ``h`` s, normalised. Scalars of any backend of
    :mod:`auv_envs.core.ops` (floats, JAX or NumPy arrays elementwise, CasADi symbols)."""
    wx, wy, wz = omega_body
    angle = ops.sqrt(wx * wx + wy * wy + wz * wz) * h
    half = 0.5 * angle
    # sin(a/2)/a, with its limit 1/2 at a = 0 (the series keeps it smooth there).
    small = angle > 1e-8
    scale = ops.where(small, ops.sin(half) / ops.where(small, angle, 1.0),
                      0.5 - angle * angle / 48.0)
    w2, x2, y2, z2 = ops.cos(half), wx * h * scale, wy * h * scale, wz * h * scale
    w1, x1, y1, z1 = quat
    w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    x = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    y = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    norm = ops.sqrt(w * w + x * x + y * y + z * z)
    return w / norm, x / norm, y / norm, z / norm


def euler_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """ZYX Euler angles ``(roll, pitch, yaw)`` of a body-to-world rotation."""
    r = rotation.tolist() if isinstance(rotation, np.ndarray) else rotation
    return np.array(euler_floats(r, FLOATS))


def rotation_rows(roll: float, pitch: float, yaw: float, ops) -> tuple:
    """:func:`rotation_from_euler` as rows of scalars (per-step use): Python floats, or
    any backend of :mod:`auv_envs.core.ops`."""
    cr, sr = ops.cos(roll), ops.sin(roll)
    cp, sp = ops.cos(pitch), ops.sin(pitch)
    cy, sy = ops.cos(yaw), ops.sin(yaw)
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


def rotate_rows(rows, point) -> tuple[float, float, float]:
    """``rows @ point`` in scalar arithmetic (Python floats, CasADi symbols or JAX arrays;
    ``rows`` as from :func:`rotation_rows`)."""
    x, y, z = point
    return tuple(a * x + b * y + c * z for a, b, c in rows)


def euler_floats(rows, ops) -> tuple[float, float, float]:
    """:func:`euler_from_rotation` in scalar arithmetic: Python floats for per-step use,
    or any backend of :mod:`auv_envs.core.ops` (JAX arrays elementwise).

    Args:
        rows: the rotation as 3 rows of 3 scalars (nested sequences).
        ops: the backend (:data:`auv_envs.core.ops.FLOATS` for Python floats).
    """
    pitch = -ops.asin(ops.clip(rows[2][0], -1.0, 1.0))
    roll = ops.atan2(rows[2][1], rows[2][2])
    yaw = ops.atan2(rows[1][0], rows[0][0])
    return roll, pitch, yaw


def compose_rows(a, b) -> tuple:
    """Product ``a @ b`` of two 3x3 rotations given as 3 rows of 3 floats, in Python floats.

    For per-step use, where NumPy's call overhead exceeds the 27 products.
    """
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return (
        (a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21,
         a00 * b02 + a01 * b12 + a02 * b22),
        (a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21,
         a10 * b02 + a11 * b12 + a12 * b22),
        (a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21,
         a20 * b02 + a21 * b12 + a22 * b22),
    )


def quat_from_euler(roll, pitch, yaw, xp):
    """Unit quaternion ``(w, x, y, z)`` (MuJoCo order) for ZYX Euler angles.

    ``xp``: the array module, ``numpy`` or ``jax.numpy``.
    """
    cr, sr = xp.cos(roll / 2), xp.sin(roll / 2)
    cp, sp = xp.cos(pitch / 2), xp.sin(pitch / 2)
    cy, sy = xp.cos(yaw / 2), xp.sin(yaw / 2)
    return xp.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def wrap_angle(angle, mod=operator.mod):
    """Wrap an angle to ``[-pi, pi)``: plain arithmetic, so a Python float stays a float and
    a NumPy or JAX array stays one (a list or tuple becomes a NumPy array). ``mod``: the
    remainder with the divisor's sign (Python's ``%``; an ``ops`` namespace's ``mod`` for
    CasADi symbols, :mod:`auv_envs.core.ops`)."""
    if isinstance(angle, list | tuple):
        angle = np.asarray(angle, dtype=float)
    return mod(angle + math.pi, 2.0 * math.pi) - math.pi


def ned_to_enu(vector) -> np.ndarray:
    """North-east-down vector to the z-up world frame (x east, y north, z up)."""
    v = np.asarray(vector, dtype=float)
    return np.array([v[1], v[0], -v[2]])


def enu_to_ned(vector) -> np.ndarray:
    """Inverse of :func:`ned_to_enu` (the map is an involution up to order)."""
    v = np.asarray(vector, dtype=float)
    return np.array([v[1], v[0], -v[2]])


def frd_to_flu(vector) -> np.ndarray:
    """Forward-right-down body vector to forward-left-up."""
    v = np.asarray(vector, dtype=float)
    return np.array([v[0], -v[1], -v[2]])


def world_to_body(rotation: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Express a world-frame vector in the body frame of ``rotation``."""
    return np.asarray(rotation).T @ np.asarray(vector)
