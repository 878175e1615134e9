"""Reference tests for the pinhole camera model and the docking env's light pixels.

The expected pixels are computed here from first principles (geometry of the
nose camera, ZYX Euler angles, ideal pinhole with ``f = (H/2) / tan(fovy/2)``
and principal point at the image centre), independently of
:mod:`auv_envs.core.camera`, and cross-checked with OpenCV and with MuJoCo's
own rendering.
"""

from __future__ import annotations

import math

import cv2
import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the environments)
from auv_envs.core.camera import (
    CameraIntrinsics,
    add_pixel_noise,
    inside_image,
    pixel_space,
    project,
)
from auv_envs.core.frames import rotation_from_euler

SIX = "auv_envs/DockingStation-v2"
LAMPS = "auv_envs/LampArrayDocking-v2"
#: Camera tilt below the body x axis per layout (deg) and the hull half length.
CAMERA_PITCH_DEG = {SIX: 0.0, LAMPS: 20.0}
NOSE = 0.9  # 1.8 m hull
FOVY_DEG = 45.0


@pytest.fixture
def make_env():
    envs = []

    def _make(env_id=SIX, **kwargs):
        kwargs.setdefault("obs_mode", "features")
        kwargs.setdefault("scenario", "mismatch")
        env = gym.make(env_id, **kwargs)
        envs.append(env)
        return env

    yield _make
    for env in envs:
        env.close()


def _cam_rotation_cv_to_body(tilt_deg: float) -> np.ndarray:
    """OpenCV camera axes in the body frame, from the geometry alone.

    The optical axis (z_cv) points forward, tilted down by ``tilt_deg``; image
    x (right) is body -y (starboard); image y (down) completes the frame.
    """
    t = math.radians(tilt_deg)
    z_cv = np.array([math.cos(t), 0.0, -math.sin(t)])
    x_cv = np.array([0.0, -1.0, 0.0])
    y_cv = np.cross(z_cv, x_cv)
    return np.stack([x_cv, y_cv, z_cv], axis=1)


def _hand_projection(position, euler, lights, width, height, tilt_deg):
    """Pixels of world points for a vehicle at ``position``/``euler``, by hand."""
    f = 0.5 * height / math.tan(math.radians(FOVY_DEG) / 2.0)
    cx, cy = width / 2.0, height / 2.0
    r_body = rotation_from_euler(*euler, np)
    cam_pos = np.asarray(position) + r_body @ np.array([NOSE, 0.0, 0.0])
    r_cam = r_body @ _cam_rotation_cv_to_body(tilt_deg)  # cv -> world
    out = []
    for light in np.asarray(lights):
        xc, yc, zc = r_cam.T @ (light - cam_pos)
        out.append([f * xc / zc + cx, f * yc / zc + cy] if zc > 0 else [np.nan, np.nan])
    return np.array(out)


# --------------------------------------------------------------------- calibration
@pytest.mark.parametrize("env_id", [SIX, LAMPS])
def test_calibration_matches_camera_geometry(make_env, env_id):
    cal = make_env(env_id).unwrapped.calibration
    np.testing.assert_allclose(cal.extrinsics.position, [NOSE, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(
        cal.extrinsics.rotation_matrix, _cam_rotation_cv_to_body(CAMERA_PITCH_DEG[env_id]),
        atol=1e-12,
    )
    f = 240.0 / math.tan(math.radians(22.5))
    intr = cal.intrinsics
    assert (intr.width, intr.height) == (640, 480)
    assert intr.fx == pytest.approx(f, rel=1e-12)
    assert intr.fy == pytest.approx(f, rel=1e-12)
    assert (intr.cx, intr.cy) == (320.0, 240.0)


def test_intrinsics_from_fovy_formula():
    intr = CameraIntrinsics.from_fovy(640, 480, 45.0)
    assert intr.fx == pytest.approx(579.4112549695428, rel=1e-12)
    assert intr.fy == intr.fx
    assert (intr.cx, intr.cy) == (320.0, 240.0)
    # fovy = 90 deg: f = H / 2.
    intr90 = CameraIntrinsics.from_fovy(320, 200, 90.0)
    assert intr90.fy == pytest.approx(100.0, rel=1e-12)
    np.testing.assert_allclose(
        intr90.matrix, [[100.0, 0.0, 160.0], [0.0, 100.0, 100.0], [0.0, 0.0, 1.0]], atol=1e-12
    )
    # A point on the upper edge of the vertical field of view lands on row 0,
    # on the lower edge on row H.
    half = math.tan(math.radians(45.0) / 2.0)
    pix, front = project(intr, np.array([[0.0, -half, 1.0], [0.0, half, 1.0]]))
    assert front.all()
    np.testing.assert_allclose(pix, [[320.0, 0.0], [320.0, 480.0]], atol=1e-9)
    with pytest.raises(ValueError):
        CameraIntrinsics.from_fovy(0, 480, 45.0)


# --------------------------------------------------------------------- projection
@pytest.mark.parametrize(
    "position, euler",
    [
        ((-6.0, 0.3, -0.2), (0.0, 0.0, 0.1)),
        ((-8.0, -0.7, 0.4), (0.08, -0.05, 0.12)),
        ((-4.5, 0.2, 0.1), (-0.1, 0.06, -0.05)),
    ],
)
def test_truth_pixels_match_hand_projection(make_env, position, euler):
    env = make_env(SIX)
    u = env.unwrapped
    env.reset(seed=0)
    u.physics.set_state(position, euler, np.zeros(6))
    pixels, visible = u.lights_in_view()
    lights = u.calibration.light_positions
    expected = _hand_projection(position, euler, lights, 640, 480, 0.0)
    np.testing.assert_allclose(pixels, expected, atol=1e-8)
    # All six lights are in view (through the open funnel) from these poses.
    assert visible.all()


def test_known_pose_known_pixels(make_env):
    """Pinned numbers for position (-6, 0.3, -0.2), yaw 0.1 rad."""
    env = make_env(SIX)
    u = env.unwrapped
    env.reset(seed=0)
    u.physics.set_state((-6.0, 0.3, -0.2), (0.0, 0.0, 0.1), np.zeros(6))
    pixels = u.lights_in_view()[0]
    # Yawed to port (counter-clockwise) and displaced to port: the station
    # appears right of the image centre; light_0 (top) above light_3 (bottom).
    assert np.all(pixels[:, 0] > 320.0)
    assert pixels[0, 1] < 240.0 < pixels[3, 1]
    # Lights on the station's port side (+y: light_1, light_2) appear left of
    # those on its starboard side (light_4, light_5).
    assert pixels[1, 0] < pixels[5, 0]
    np.testing.assert_allclose(pixels[0], [408.0951, 190.2969], atol=1e-3)


def test_info_true_pixels_match_hand_projection_after_reset(make_env):
    env = make_env(SIX)
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        lights = env.unwrapped.calibration.light_positions
        expected = _hand_projection(
            info["true_position"], info["true_euler"], lights, 640, 480, 0.0
        )
        vis = info["true_visible"]
        assert vis.sum() >= 3
        np.testing.assert_allclose(info["true_pixels"][vis], expected[vis], atol=1e-8)
        # Documented convention: zero where not visible, as in the observation.
        np.testing.assert_array_equal(info["true_pixels"][~vis], 0.0)
        # Noise-free scenario: observed pixels are the true ones (float32).
        np.testing.assert_allclose(obs["pixels"][vis], expected[vis], atol=1e-3)
        np.testing.assert_array_equal(obs["visible"], vis.astype(np.int8))


@pytest.mark.parametrize("env_id", [SIX, LAMPS])
@pytest.mark.parametrize("light_index", [0, 2])
def test_light_on_optical_axis_projects_to_principal_point(make_env, env_id, light_index):
    env = make_env(env_id, image_size=(400, 300))
    u = env.unwrapped
    env.reset(seed=0)
    light = u.calibration.light_positions[light_index]
    euler = (0.3, 0.1, 0.2)  # rolling about the optical axis keeps it centred
    r_body = rotation_from_euler(*euler, np)
    axis_world = r_body @ _cam_rotation_cv_to_body(CAMERA_PITCH_DEG[env_id])[:, 2]
    cam_pos = light - 5.0 * axis_world
    position = cam_pos - r_body @ np.array([NOSE, 0.0, 0.0])
    u.physics.set_state(position, euler, np.zeros(6))
    pixels = u.lights_in_view()[0]
    np.testing.assert_allclose(pixels[light_index], [200.0, 150.0], atol=1e-8)
    # The other lights are off-centre.
    others = np.delete(pixels, light_index, axis=0)
    assert np.all(np.linalg.norm(others - [200.0, 150.0], axis=1) > 5.0)


@pytest.mark.parametrize("env_id", [SIX, LAMPS])
def test_truth_pixels_match_opencv_project_points(make_env, env_id):
    env = make_env(env_id)
    u = env.unwrapped
    env.reset(seed=0)
    position, euler = (-7.0, 0.4, 0.3), (0.05, -0.03, -0.08)
    u.physics.set_state(position, euler, np.zeros(6))
    pixels = u.lights_in_view()[0]
    cal = u.calibration
    r_body = rotation_from_euler(*euler, np)
    cam_pos = np.asarray(position) + r_body @ np.asarray(cal.extrinsics.position)
    r_world_to_cam = (r_body @ cal.extrinsics.rotation_matrix).T
    rvec, _ = cv2.Rodrigues(r_world_to_cam)
    tvec = -r_world_to_cam @ cam_pos
    cv_pixels, _ = cv2.projectPoints(
        np.ascontiguousarray(cal.light_positions, dtype=np.float64),
        rvec, tvec, cal.intrinsics.matrix, np.zeros(5),
    )
    np.testing.assert_allclose(pixels, cv_pixels.reshape(-1, 2), atol=1e-6)


def test_points_behind_camera_have_nan_pixels():
    intr = CameraIntrinsics.from_fovy(640, 480, 45.0)
    pts = np.array([[0.1, 0.2, 3.0], [0.1, 0.2, -3.0], [0.0, 0.0, 0.0], [0.5, -0.3, 2.0]])
    pix, front = project(intr, pts)
    np.testing.assert_array_equal(front, [True, False, False, True])
    assert np.isnan(pix[1]).all() and np.isnan(pix[2]).all()
    np.testing.assert_allclose(pix[0], [320 + intr.fx * 0.1 / 3, 240 + intr.fy * 0.2 / 3])
    np.testing.assert_array_equal(inside_image(intr, pix), [True, False, False, True])


def test_vehicle_facing_away_sees_no_lights(make_env):
    env = make_env(SIX)
    u = env.unwrapped
    env.reset(seed=0)
    u.physics.set_state((-6.0, 0.0, 0.0), (0.0, 0.0, math.pi), np.zeros(6))
    pixels, visible = u.lights_in_view()
    assert not visible.any()
    assert np.isnan(pixels).all()


def test_inside_image_boundaries():
    intr = CameraIntrinsics.from_fovy(640, 480, 45.0)
    pix = np.array(
        [
            [0.0, 0.0],
            [639.999, 479.999],
            [640.0, 10.0],
            [10.0, 480.0],
            [-1e-9, 10.0],
            [10.0, -1e-9],
            [np.nan, 10.0],
        ]
    )
    np.testing.assert_array_equal(
        inside_image(intr, pix), [True, True, False, False, False, False, False]
    )
    pm = np.array([[9.99, 100.0], [10.0, 100.0], [629.99, 100.0], [630.0, 100.0],
                   [100.0, 469.99], [100.0, 470.0]])
    np.testing.assert_array_equal(
        inside_image(intr, pm, margin=10.0), [False, True, True, False, True, False]
    )


def test_pixel_space_bounds_twice_the_image_each_way():
    space = pixel_space(640, 480, (2, 3))
    assert space.shape == (2, 3, 2) and space.dtype == np.float32
    np.testing.assert_array_equal(space.low[1, 2], [-640.0, -480.0])
    np.testing.assert_array_equal(space.high[0, 0], [1280.0, 960.0])
    assert (space.low == space.low[0, 0]).all() and (space.high == space.high[0, 0]).all()
    # Bounds are the space's own arrays (not broadcast views of one row).
    assert space.low.flags.writeable and not np.shares_memory(space.low[0], space.low[1])
    corners = np.array([[0.0, 0.0], [639.9, 479.9], [-640.0, 960.0]], np.float32)
    assert space.contains(np.broadcast_to(corners, (2, 3, 2)).copy())
    assert not space.contains(np.full((2, 3, 2), 1280.5, np.float32))


def test_add_pixel_noise_zero_std_returns_copy():
    pix = np.array([[1.0, 2.0], [3.0, 4.0]])
    rng = np.random.default_rng(0)
    state_before = rng.bit_generator.state
    out = add_pixel_noise(pix, 0.0, rng)
    np.testing.assert_array_equal(out, pix)
    assert out is not pix
    out[0, 0] = 99.0
    assert pix[0, 0] == 1.0
    assert rng.bit_generator.state == state_before  # no draw consumed


def test_add_pixel_noise_std_five():
    pix = np.full((20000, 2), 100.0)
    out = add_pixel_noise(pix, 5.0, np.random.default_rng(0))
    err = out - pix
    assert err.std() == pytest.approx(5.0, rel=0.02)
    assert abs(err.mean()) < 0.1
    # Independent columns.
    assert abs(np.corrcoef(err[:, 0], err[:, 1])[0, 1]) < 0.03
    # Reproducible from the generator.
    again = add_pixel_noise(pix, 5.0, np.random.default_rng(0))
    np.testing.assert_array_equal(out, again)
    assert (pix == 100.0).all()


# --------------------------------------------------------------------- rendering
def _bright_blob_centroid(image, pixel, half=7, threshold=150):
    """Centroid (continuous pixel coordinates) of the bright pixels near ``pixel``."""
    col, row = int(math.floor(pixel[0])), int(math.floor(pixel[1]))
    win = image[row - half : row + half + 1, col - half : col + half + 1].astype(float)
    bright = win.min(axis=2) > threshold
    rows, cols = np.nonzero(bright)
    centroid = np.array([cols.mean() + col - half + 0.5, rows.mean() + row - half + 0.5])
    return win, bright, centroid


@pytest.mark.parametrize(
    "env_id, position, euler, light_indices",
    [
        (SIX, (-4.0, 0.2, 0.1), (0.0, 0.0, 0.05), range(6)),
        (SIX, (-5.0, -0.3, -0.1), (0.05, 0.03, -0.06), range(6)),
        # Lamp D is the only lamp not in line with others in the tilted view.
        (LAMPS, (-4.0, 0.1, 0.3), (0.0, 0.0, 0.05), [3]),
    ],
)
def test_rendered_lamps_lie_at_projected_pixels(make_env, env_id, position, euler, light_indices):
    width, height = 320, 240
    env = make_env(env_id, obs_mode="image", image_size=(width, height))
    u = env.unwrapped
    env.reset(seed=0)
    u.physics.set_state(position, euler, np.zeros(6))
    pixels, visible = u.lights_in_view()
    image = u.camera_renderer.render(u.physics.data)
    assert image.shape == (height, width, 3) and image.dtype == np.uint8
    expected = _hand_projection(
        position, euler, u.calibration.light_positions, width, height, CAMERA_PITCH_DEG[env_id]
    )
    for i in light_indices:
        assert visible[i]
        np.testing.assert_allclose(pixels[i], expected[i], atol=1e-8)
        win, bright, centroid = _bright_blob_centroid(image, expected[i])
        assert win.max(axis=(0, 1)).min() > 150, f"light {i}: no bright lamp near {expected[i]}"
        assert bright.sum() >= 4
        # The brief allows ~3 px; measured error is below 0.3 px.
        assert np.linalg.norm(centroid - expected[i]) < 1.5, (i, centroid, expected[i])
    # Dark water away from the station (top-left corner).
    assert image[:10, :10].max() < 60
