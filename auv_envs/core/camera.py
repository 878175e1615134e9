"""Pinhole camera model: intrinsics, extrinsics, projection, visibility, pixel noise.

Pixel coordinates are continuous with the origin at the top-left *corner* of
the image: pixel ``(i, j)`` (column, row) covers ``[i, i+1) x [j, j+1)``, so
its centre is at ``(i + 0.5, j + 0.5)``. This matches MuJoCo's renderer, whose
principal point is the image centre ``(W/2, H/2)``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from gymnasium import spaces

from auv_envs.core.frames import R_MJCAM_TO_CV
from auv_envs.core.ops import FLOATS


@dataclasses.dataclass(frozen=True)
class CameraIntrinsics:
    """Ideal pinhole intrinsics (no distortion), square pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float) -> CameraIntrinsics:
        """Intrinsics of a MuJoCo camera with vertical field of view ``fovy_deg``."""
        if width <= 0 or height <= 0:
            raise ValueError(f"image size must be positive, got {width}x{height}")
        f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(width, height, f, f, width / 2.0, height / 2.0)

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclasses.dataclass(frozen=True)
class CameraExtrinsics:
    """Pose of the camera in the body frame.

    Attributes:
        position: camera centre in the body frame, m.
        rotation: rotation from the OpenCV camera frame to the body frame.
    """

    position: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...]

    @classmethod
    def from_mujoco(cls, pos: np.ndarray, mat: np.ndarray) -> CameraExtrinsics:
        """From MuJoCo's ``cam_pos`` and the camera frame's body-relative rotation."""
        rot = np.asarray(mat).reshape(3, 3) @ R_MJCAM_TO_CV
        return cls(tuple(float(x) for x in pos), tuple(tuple(float(x) for x in r) for r in rot))

    @property
    def rotation_matrix(self) -> np.ndarray:
        return np.array(self.rotation)


def points_in_camera(points_world, cam_position_world, cam_rotation_world) -> np.ndarray:
    """World points expressed in the (OpenCV) camera frame.

    Args:
        points_world: (N, 3).
        cam_position_world: camera centre in the world, (3,).
        cam_rotation_world: rotation from the OpenCV camera frame to the world.
    """
    return (np.asarray(points_world) - cam_position_world) @ np.asarray(cam_rotation_world)


def project(intrinsics: CameraIntrinsics, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points; returns ``(pixels (N, 2), in_front (N,))``.

    Points behind the camera get NaN pixels.
    """
    pts = np.asarray(points_cam, dtype=float)
    z = pts[:, 2]
    in_front = z > 1e-6
    pixels = pts[:, :2] / np.maximum(z, 1e-6)[:, None]
    pixels *= (intrinsics.fx, intrinsics.fy)
    pixels += (intrinsics.cx, intrinsics.cy)
    if not in_front.all():
        pixels[~in_front] = np.nan
    return pixels, in_front


def inside_image(
    intrinsics: CameraIntrinsics, pixels: np.ndarray, margin: float = 0.0
) -> np.ndarray:
    """Which pixels fall inside the image (optionally shrunk by ``margin``)."""
    # NaN (behind the camera) compares False: not inside.
    upper = (intrinsics.width - margin, intrinsics.height - margin)
    return ((pixels >= margin) & (pixels < upper)).all(axis=1)


def inside_image_flat(intrinsics: CameraIntrinsics, pixels) -> list[bool]:
    """:func:`inside_image` of flat ``u, v, u, v, ...`` Python floats (a step's few
    pixels, e.g. a compiled truth's outputs), as a list of bools; NaN is not inside."""
    width, height = intrinsics.width, intrinsics.height
    return [0.0 <= u < width and 0.0 <= v < height
            for u, v in zip(pixels[0::2], pixels[1::2], strict=True)]


def project_point(intrinsics: CameraIntrinsics, dx, dy, dz, cam_rotation_world, ops):
    """The pinhole projection of one world offset from the camera centre, in scalar arithmetic.

    The model of :func:`points_in_camera`, :func:`project` and
    :func:`inside_image` (tested equal to them), written once (in
    :func:`project_few`) for every backend of :mod:`auv_envs.core.ops`: Python
    floats (an environment's per-step path) or JAX arrays (the batched
    environments, a batch of points elementwise).

    Args:
        intrinsics: camera intrinsics.
        dx, dy, dz: the point minus the camera centre, world frame.
        cam_rotation_world: rotation from the OpenCV camera frame to the
            world as 3 rows of 3 scalars.
        ops: the backend (:data:`auv_envs.core.ops.FLOATS` for Python floats).

    Returns:
        ``(u, v, in_image)``: the pixel (NaN behind the camera) and whether
        the point is in front of the camera and inside the image.
    """
    (pixel,), (inside,) = project_few(intrinsics, ((dx, dy, dz),), (0.0, 0.0, 0.0),
                                      cam_rotation_world, ops)
    return (*pixel, inside)


def project_few(
    intrinsics: CameraIntrinsics,
    points_world,
    cam_position_world: tuple,
    cam_rotation_world,
    ops,
    inside: bool = True,
) -> tuple[list, list]:
    """Project a handful of world points into the image: an environment's per-step path.

    Scalar arithmetic point by point (for the few points an environment projects
    every step, six lights say, NumPy's per-call overhead is several times the
    arithmetic); the camera's numbers are read once.

    Args:
        intrinsics: camera intrinsics.
        points_world: the points as ``(x, y, z)`` scalar sequences.
        cam_position_world: camera centre in the world, 3 scalars.
        cam_rotation_world: rotation from the OpenCV camera frame to the
            world as 3 rows of 3 scalars.
        ops: the backend (:data:`auv_envs.core.ops.FLOATS` on the CPU).
        inside: whether to say which points are in the image (False: ``in_image``
            is empty).

    Returns:
        ``(pixels, in_image)``: a ``(u, v)`` tuple per point (NaN for points
        behind the camera) and whether each point is in front of the camera
        and inside the image.
    """
    px, py, pz = cam_position_world
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = cam_rotation_world
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    width, height = intrinsics.width, intrinsics.height
    where, both = ops.where, ops.logical_and
    pixels, in_image = [], []
    for x, y, z in points_world:
        dx, dy, dz = x - px, y - py, z - pz
        depth = dx * r02 + dy * r12 + dz * r22
        front = depth > 1e-6
        depth = where(front, depth, 1.0)
        u = (dx * r00 + dy * r10 + dz * r20) / depth * fx + cx
        v = (dx * r01 + dy * r11 + dz * r21) / depth * fy + cy
        pixels.append((where(front, u, math.nan), where(front, v, math.nan)))
        if inside:
            in_image.append(both(both(both(both(front, 0.0 <= u), u < width), 0.0 <= v),
                                 v < height))
    return pixels, in_image


def pixel_space(width: int, height: int, shape: tuple[int, ...]) -> spaces.Box:
    """The observation space of feature pixels ``(*shape, 2)``: ``[-W, 2W] x [-H, 2H]``.

    Wider than the image because pixel noise can push a visible point out of it;
    the environments clip their noisy pixels to these bounds.
    """
    bound = np.array([width, height], dtype=np.float32)
    full = (*shape, 2)
    return spaces.Box(np.broadcast_to(-bound, full).copy(),
                      np.broadcast_to(2 * bound, full).copy(), dtype=np.float32)


def seen_pixels(pixels, noise, seen, low, high, ops) -> list:
    """The noisy pixels of the points seen, clipped to their bounds; zero for the others.

    Args:
        pixels: ``u, v`` of every point, flat (2 n scalars).
        noise: the noise to add, flat (2 n), or None.
        seen: per point, whether it is seen (n).
        low, high: bounds of ``u, v`` of every point, flat (2 n floats each).
        ops: the backend (:data:`auv_envs.core.ops.FLOATS`: Python floats, a loop over
            the seen points; JAX: arrays, selected).

    Returns:
        2 n scalars: a list of Python floats, or a JAX array.
    """
    if ops is not FLOATS:
        xp = ops.xp
        values = xp.stack(list(pixels)) + (0.0 if noise is None else noise)
        mask = xp.repeat(xp.stack(list(seen)), 2)
        return xp.where(mask, xp.clip(values, xp.asarray(low), xp.asarray(high)), 0.0)
    noise = [0.0] * len(pixels) if noise is None else noise.tolist()
    out = [0.0] * len(pixels)
    for k, point_seen in enumerate(seen):
        if point_seen:  # clipped by comparisons (cheaper than min/max)
            for i in (2 * k, 2 * k + 1):
                x, lo, hi = pixels[i] + noise[i], low[i], high[i]
                out[i] = lo if x < lo else (hi if x > hi else x)
    return out


def add_pixel_noise(pixels, std: float, rng):
    """Zero-mean Gaussian pixel noise drawn from the episode's draws (NumPy's ``Generator``,
    or a JAX key's): ``std`` times standard normals, the numbers ``normal(0, std)`` gives."""
    if std <= 0.0:
        return pixels.copy()
    return pixels + std * rng.standard_normal(pixels.shape)
