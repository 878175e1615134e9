"""The docking env's per-step Python-float paths against their NumPy / MuJoCo references.

The step path projects the lights with :func:`camera.project_few`, ray-casts them
one ``mj_ray`` each, composes rotations and reads Euler angles in Python floats,
and validates actions without NumPy reductions. Each must agree with the
general-purpose definition it stands in for.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from gymnasium import spaces

from auv_envs.core import frames
from auv_envs.core.camera import (
    CameraIntrinsics,
    inside_image,
    points_in_camera,
    project,
    project_few,
)
from auv_envs.core.env import validate_action
from auv_envs.core.ops import FLOATS
from tests.conftest import make_env

SIX = "auv_envs/DockingStation-v2"
LAMPS = "auv_envs/LampArrayDocking-v2"


def _random_rotation(rng):
    return frames.rotation_from_euler(*rng.uniform(-math.pi, math.pi, size=3), np)


def test_project_few_matches_numpy_projection():
    rng = np.random.default_rng(0)
    intr = CameraIntrinsics.from_fovy(640, 480, 45.0)
    counts = np.zeros(3, dtype=int)  # behind, in front outside the image, inside
    for _ in range(200):
        rot = _random_rotation(rng)
        cam = rng.uniform(-3.0, 3.0, size=3)
        points = cam + rng.normal(0.0, 4.0, size=(8, 3))
        ref_pixels, in_front = project(intr, points_in_camera(points, cam, rot))
        ref_inside = in_front & inside_image(intr, ref_pixels)
        pixels, inside = project_few(intr, [tuple(p) for p in points.tolist()],
                                     tuple(cam.tolist()), rot.tolist(), FLOATS)
        pixels = np.array(pixels)
        np.testing.assert_array_equal(np.isnan(pixels), np.isnan(ref_pixels))
        np.testing.assert_allclose(pixels, ref_pixels, rtol=1e-12, atol=1e-9)
        np.testing.assert_array_equal(inside, ref_inside)
        counts += [(~in_front).sum(), (in_front & ~ref_inside).sum(), ref_inside.sum()]
    assert counts.min() > 50, counts  # every branch exercised


def test_project_few_image_edges_follow_inside_image():
    intr = CameraIntrinsics.from_fovy(640, 480, 45.0)
    # Camera at the origin looking along world +z with identity rotation:
    # pixel = f * (x, y) / z + c, so points can be put on exact pixel edges.
    targets = np.array([[0.0, 0.0], [639.5, 479.5], [640.0, 10.0], [10.0, 480.0],
                        [-0.25, 10.0], [10.0, -0.25]])
    points = [((u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, 1.0) for u, v in targets]
    pixels, inside = project_few(intr, points, (0.0, 0.0, 0.0), np.eye(3).tolist(), FLOATS)
    np.testing.assert_allclose(pixels, targets, atol=1e-9)
    np.testing.assert_array_equal(inside, inside_image(intr, np.array(pixels)))
    assert inside == [True, True, False, False, False, False]


@pytest.mark.parametrize("env_id", [SIX, LAMPS])
def test_unoccluded_matches_multiray(env_id):
    """One mj_ray per light gives the same verdicts as a batched mj_multiRay.

    Origins lie in front of the entrance (where the camera is while an
    episode runs); for mj_multiRay's misses behind it see the next test.
    """
    env = make_env(env_id, "state")
    env.reset(seed=0)
    phys = env.unwrapped.physics
    lights = phys.light_positions
    n = len(lights)
    rng = np.random.default_rng(1)
    blocked_seen = clear_seen = 0
    geomid, dist = np.zeros(n, dtype=np.int32), np.zeros(n)
    for _ in range(300):
        # Close to and off the docking axis, where the funnel, fork and rails hide lights.
        origin = rng.uniform((-4.0, -2.5, -1.4), (-0.3, 2.5, 2.0))
        mujoco.mj_multiRay(
            phys.model, phys.data, origin, (lights - origin).ravel(), phys.ray_groups, 1,
            phys.hull_body, geomid, dist, None, n, mujoco.mjMAXVAL,
        )
        expected = ~((dist >= 0.0) & (dist < 1.0 - 1e-6))
        candidates = rng.random(n) < 0.8
        got = phys.unoccluded(tuple(origin.tolist()), [tuple(p) for p in lights.tolist()],
                              candidates.tolist())
        np.testing.assert_array_equal(got, candidates & expected)
        blocked_seen += int((candidates & ~expected).sum())
        clear_seen += int((candidates & expected).sum())
    env.close()
    assert blocked_seen > 20 and clear_seen > 20, (blocked_seen, clear_seen)


def test_rotation_helpers_match_numpy():
    rng = np.random.default_rng(2)
    for _ in range(100):
        a, b = _random_rotation(rng), _random_rotation(rng)
        np.testing.assert_allclose(frames.compose_rows(a.tolist(), b.tolist()), a @ b,
                                   rtol=0, atol=1e-15)
        np.testing.assert_array_equal(frames.euler_floats(a.tolist(), FLOATS),
                                      frames.euler_from_rotation(a))


def test_wrap_angle_float_path_matches_array_path():
    angles = np.concatenate([np.random.default_rng(3).uniform(-20.0, 20.0, 1000),
                             [math.pi, -math.pi, 3 * math.pi, 0.0, -0.0, 7 * math.pi / 2]])
    scalar = [frames.wrap_angle(float(x)) for x in angles]
    assert all(type(x) is float for x in scalar)
    np.testing.assert_array_equal(scalar, frames.wrap_angle(angles))


def test_validate_action_fast_path_and_fallbacks():
    box = spaces.Box(-1.0, 1.0, shape=(2, 2), dtype=np.float32)
    inside = np.array([[0.5, -1.0], [1.0, 0.0]], dtype=np.float32)
    out = validate_action(inside, box)
    assert out.dtype == np.float64 and not np.shares_memory(out, inside)
    np.testing.assert_array_equal(out, inside)
    np.testing.assert_array_equal(validate_action([[2.0, 0.0], [0.0, -3.0]], box),
                                  [[1.0, 0.0], [0.0, -1.0]])
    unbounded = spaces.Box(-np.inf, np.inf, shape=(3,))
    np.testing.assert_array_equal(validate_action([1e308, -1e308, 0.0], unbounded),
                                  [1e308, -1e308, 0.0])
    for bad in ([np.inf, 0.0, 0.0], [0.0, -np.inf, 0.0], [0.0, 0.0, np.nan]):
        with pytest.raises(ValueError, match="finite"):
            validate_action(bad, unbounded)


def test_unoccluded_finds_rail_that_multiray_misses():
    """A hand-checked hit: behind the lamp-array entrance, below the rail.

    From ``origin`` the line to lamp D crosses the ``rail_long`` box (centre
    (1.8, 0, -0.65), half sizes (0.7, 0.03, 0.02)) for t in [0.8243, 0.8372]
    of the way (slab method, below). MuJoCo 3.17's ``mj_multiRay`` reports no
    hit on this line; ``mj_ray``, which the env uses, reports the rail.
    """
    env = make_env(LAMPS, "state")
    env.reset(seed=0)
    phys = env.unwrapped.physics
    origin = np.array([2.91814237, -2.38691136, -0.99844223])
    lamp_d = phys.light_positions[3]
    np.testing.assert_allclose(lamp_d, [2.4, 0.5, -0.6], atol=1e-12)
    direction = lamp_d - origin
    centre, half = np.array([1.8, 0.0, -0.65]), np.array([0.7, 0.03, 0.02])
    t1, t2 = (centre - half - origin) / direction, (centre + half - origin) / direction
    t_enter, t_exit = np.minimum(t1, t2).max(), np.maximum(t1, t2).min()
    assert 0.0 < t_enter < t_exit < 1.0
    got = phys.unoccluded(tuple(origin), [tuple(lamp_d)], [True])
    env.close()
    assert got == [False]
