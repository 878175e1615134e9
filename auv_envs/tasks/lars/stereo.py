"""Rectified binocular camera: calibration, projection and triangulation ([LTAT], eq. 2).

Both cameras share intrinsics and orientation; the right camera sits
``baseline`` metres along the left camera's +x axis (OpenCV axes: x right,
y down, z forward). The left camera frame is the stereo reference frame.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from auv_envs.core.camera import CameraIntrinsics, project


@dataclasses.dataclass(frozen=True)
class StereoRig:
    """A rectified stereo pair.

    Attributes:
        left: intrinsics of the left camera (pixels).
        right: intrinsics of the right camera (equal to ``left`` here).
        baseline: distance between the optical centres along the left
            camera's x axis, m.
    """

    left: CameraIntrinsics
    right: CameraIntrinsics
    baseline: float

    def project(self, points_left: np.ndarray) -> np.ndarray:
        """Pixels (2, N, 2) in the (left, right) images of left-camera-frame points (N, 3).

        Points at or behind the image plane get NaN pixels.
        """
        pts = np.asarray(points_left, dtype=float)
        right = pts - (self.baseline, 0.0, 0.0)  # the right camera sits at +baseline along x
        return np.stack([project(self.left, pts)[0], project(self.right, right)[0]])

    def disparity(self, u_left, u_right, xp) -> np.ndarray:
        """``x_L - x_R`` with image x measured from each camera's principal point (px);
        ``xp``: NumPy, or ``jax.numpy`` for traced pixels."""
        return (xp.asarray(u_left, dtype=float) - self.left.cx) - (
            xp.asarray(u_right, dtype=float) - self.right.cx
        )


def triangulate(rig: StereoRig, left_pixels, right_pixels) -> np.ndarray:
    """Left-camera-frame points (N, 3) from matched pixels ([LTAT], eq. 2).

    Eq. 2 with image coordinates measured from the principal point
    (``x = u - cx``, ``y = v - cy``) and the disparity ``d = x_L - x_R``:
    ``X = x_L B / d``, ``Y = y_L B fx / (fy d)``, ``Z = fx B / d``.

    Raises:
        ValueError: on mismatched shapes or non-positive disparity.
    """
    left = np.atleast_2d(np.asarray(left_pixels, dtype=float))
    right = np.atleast_2d(np.asarray(right_pixels, dtype=float))
    if left.shape != right.shape or left.shape[-1] != 2:
        raise ValueError(f"pixel arrays must both be (N, 2), got {left.shape} and {right.shape}")
    disparity = rig.disparity(left[:, 0], right[:, 0], np)
    if np.any(~(disparity > 0.0)):
        raise ValueError("disparity must be positive (point in front of both cameras)")
    return points_from_disparity(rig, left, disparity, np)


def points_from_disparity(rig: StereoRig, left_pixels, disparity, xp):
    """Eq. 2's arithmetic (:func:`triangulate` without its checks): left-camera-frame
    points (N, 3) from the left pixels (N, 2) and the disparities (N,), which the caller
    keeps positive; ``xp``: NumPy, or ``jax.numpy`` for traced pixels."""
    k = rig.left
    x_left = left_pixels[:, 0] - k.cx
    y_left = left_pixels[:, 1] - k.cy
    scale = rig.baseline / disparity
    return xp.stack([x_left * scale, y_left * scale * k.fx / k.fy, k.fx * scale], axis=1)
