"""Reference tests for the frame conventions in :mod:`auv_envs.core.frames`.

Conventions under test (module docstring of ``frames``): world z up, body
forward-left-up, ZYX Euler angles with ``R = Rz(yaw) Ry(pitch) Rx(roll)``
(body -> world), MuJoCo quaternion order ``(w, x, y, z)``, OpenCV camera axes.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from auv_envs.core import frames


def _random_angles(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    roll = rng.uniform(-math.pi, math.pi, n)
    # Stay away from the gimbal-lock singularity |pitch| = pi/2.
    pitch = rng.uniform(-0.49 * math.pi, 0.49 * math.pi, n)
    yaw = rng.uniform(-math.pi, math.pi, n)
    return np.stack([roll, pitch, yaw], axis=1)


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_euler_round_trip_random_angles():
    for roll, pitch, yaw in _random_angles(200):
        rot = frames.rotation_from_euler(roll, pitch, yaw, np)
        back = frames.euler_from_rotation(rot)
        np.testing.assert_allclose(back, [roll, pitch, yaw], atol=1e-9)
        # Also accepts a nested list (the env passes ``rot.tolist()``).
        np.testing.assert_allclose(frames.euler_from_rotation(rot.tolist()), back, atol=0)


def test_rotation_is_zyx_composition():
    for roll, pitch, yaw in _random_angles(50, seed=1):
        expected = _rz(yaw) @ _ry(pitch) @ _rx(roll)
        np.testing.assert_allclose(
            frames.rotation_from_euler(roll, pitch, yaw, np), expected, atol=1e-12
        )


def test_rotation_is_orthonormal_with_det_one():
    for roll, pitch, yaw in _random_angles(100, seed=2):
        rot = frames.rotation_from_euler(roll, pitch, yaw, np)
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-12)


def test_quat_from_euler_matches_mujoco():
    for roll, pitch, yaw in _random_angles(100, seed=3):
        quat = frames.quat_from_euler(roll, pitch, yaw, np)
        assert np.linalg.norm(quat) == pytest.approx(1.0, abs=1e-12)
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, quat)
        np.testing.assert_allclose(
            mat.reshape(3, 3), frames.rotation_from_euler(roll, pitch, yaw, np), atol=1e-12
        )


def test_quat_from_euler_matches_mujoco_euler_composition():
    # MuJoCo's own quaternion product: q = qz(yaw) * qy(pitch) * qx(roll).
    for roll, pitch, yaw in _random_angles(30, seed=4):
        qx = np.array([math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0])
        qy = np.array([math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0])
        qz = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
        qzy = np.zeros(4)
        q = np.zeros(4)
        mujoco.mju_mulQuat(qzy, qz, qy)
        mujoco.mju_mulQuat(q, qzy, qx)
        ours = frames.quat_from_euler(roll, pitch, yaw, np)
        # Same rotation: q and -q are equivalent.
        assert min(np.abs(ours - q).max(), np.abs(ours + q).max()) < 1e-12


def test_yaw_plus_90_maps_body_x_to_world_y():
    rot = frames.rotation_from_euler(0.0, 0.0, math.radians(90.0), np)
    np.testing.assert_allclose(rot @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    # Body y (port) then points to world -x; z stays up.
    np.testing.assert_allclose(rot @ [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(rot @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-12)


def test_positive_pitch_is_nose_down_and_positive_roll_is_starboard_down():
    # z up, right-handed: a positive rotation about body y (port) lowers the bow.
    rot = frames.rotation_from_euler(0.0, math.radians(30.0), 0.0, np)
    bow = rot @ [1.0, 0.0, 0.0]
    assert bow[2] == pytest.approx(-0.5, abs=1e-12)
    # A positive rotation about body x (forward) raises the port side.
    rot = frames.rotation_from_euler(math.radians(30.0), 0.0, 0.0, np)
    port = rot @ [0.0, 1.0, 0.0]
    assert port[2] == pytest.approx(0.5, abs=1e-12)


def test_world_to_body_is_transpose():
    rot = frames.rotation_from_euler(0.2, -0.3, 1.1, np)
    v = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(rot @ frames.world_to_body(rot, v), v, atol=1e-12)
    # yaw 90 deg: world +y is body +x.
    rot90 = frames.rotation_from_euler(0.0, 0.0, math.pi / 2, np)
    np.testing.assert_allclose(frames.world_to_body(rot90, [0, 1, 0]), [1, 0, 0], atol=1e-12)


def test_wrap_angle_range_and_equivalence():
    angles = np.linspace(-20.0, 20.0, 4001)
    wrapped = frames.wrap_angle(angles)
    assert np.all(wrapped >= -math.pi)
    assert np.all(wrapped < math.pi)
    # Same angle modulo 2 pi.
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles), atol=1e-12)
    np.testing.assert_allclose(np.sin(wrapped), np.sin(angles), atol=1e-12)
    # Already-wrapped angles are unchanged; pi maps to -pi (half-open range).
    np.testing.assert_allclose(frames.wrap_angle([0.0, 1.0, -3.0]), [0.0, 1.0, -3.0], atol=1e-15)
    assert float(frames.wrap_angle(math.pi)) == pytest.approx(-math.pi)
    assert float(frames.wrap_angle(3 * math.pi / 2)) == pytest.approx(-math.pi / 2)
    assert float(frames.wrap_angle(-3 * math.pi / 2)) == pytest.approx(math.pi / 2)


def test_ned_enu_known_vector_and_inverse():
    # north 1, east 2, down 3 -> east 2, north 1, up -3
    np.testing.assert_allclose(frames.ned_to_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_allclose(frames.enu_to_ned([2.0, 1.0, -3.0]), [1.0, 2.0, 3.0])
    rng = np.random.default_rng(5)
    for v in rng.normal(size=(20, 3)):
        np.testing.assert_allclose(frames.enu_to_ned(frames.ned_to_enu(v)), v)
        np.testing.assert_allclose(frames.ned_to_enu(frames.enu_to_ned(v)), v)


def test_ned_to_enu_is_a_proper_rotation():
    # The map between two right-handed frames must be a rotation (det +1).
    mat = np.stack([frames.ned_to_enu(e) for e in np.eye(3)], axis=1)
    assert np.linalg.det(mat) == pytest.approx(1.0)


def test_frd_to_flu():
    np.testing.assert_allclose(frames.frd_to_flu([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
    mat = np.stack([frames.frd_to_flu(e) for e in np.eye(3)], axis=1)
    # A rotation by pi about x: proper and its own inverse.
    assert np.linalg.det(mat) == pytest.approx(1.0)
    np.testing.assert_allclose(mat @ mat, np.eye(3))


def test_r_mjcam_to_cv_is_involution_and_flips_view_axis():
    r = frames.R_MJCAM_TO_CV
    np.testing.assert_allclose(r @ r, np.eye(3))
    assert np.linalg.det(r) == pytest.approx(1.0)
    # MuJoCo cameras look along -z with y up; OpenCV looks along +z with y down.
    np.testing.assert_allclose(r @ [0.0, 0.0, -1.0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(r @ [0.0, 1.0, 0.0], [0.0, -1.0, 0.0])
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0])


def test_rotation_from_euler_casadi_equals_numpy():
    """The CasADi form (the docking observers' camera model) is the same rotation."""
    import casadi as ca

    angles = ca.SX.sym("a", 3)
    rotation = ca.Function("R", [angles], [frames.rotation_from_euler(angles[0], angles[1],
                                                                      angles[2], ops=ca)])
    rng = np.random.default_rng(2)
    for roll, pitch, yaw in rng.uniform(-3.0, 3.0, (20, 3)):
        np.testing.assert_allclose(np.array(rotation([roll, pitch, yaw])),
                                   frames.rotation_from_euler(roll, pitch, yaw, np), atol=1e-15)


def test_quaternion_helpers_match_mujoco():
    """rotation_rows_from_quat is mju_quat2Mat; quat_integrate is mju_quatIntegrate
    (the free joint's position update), also for a batch and at zero angular velocity."""
    rng = np.random.default_rng(5)
    quats = rng.normal(size=(6, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    omegas = rng.normal(size=(6, 3)) * 2.0
    omegas[0] = 0.0
    for quat, omega in zip(quats, omegas, strict=True):
        expected = np.zeros(9)
        mujoco.mju_quat2Mat(expected, quat)
        np.testing.assert_allclose(frames.rotation_rows_from_quat(*quat), expected, atol=1e-15)
        turned = quat.copy()
        mujoco.mju_quatIntegrate(turned, omega, 0.03)
        np.testing.assert_allclose(frames.quat_integrate(quat, omega, 0.03, np), turned, atol=1e-15)
    batch = frames.quat_integrate(quats, omegas, 0.03, np)
    for k in range(len(quats)):
        np.testing.assert_allclose(batch[k], frames.quat_integrate(quats[k], omegas[k], 0.03, np))
