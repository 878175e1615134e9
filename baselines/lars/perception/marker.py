"""The marker pose measurement: the AUV's position and attitude from the stereo marker.

[LTAT], §2.2: the marker corners A1, A2 (base) and A3 (apex) matched in the left and right
images are triangulated in the left camera frame (eq. 2, through
:func:`auv_envs.tasks.lars.stereo.triangulate`), carried to the arm base (world)
frame by the hand-eye transform composed with the arm's forward kinematics
(eq. 3, ``LARSCalibration.camera_poses``), and give the AUV's pitch and yaw
(eqs. 4-6, :func:`marker_pitch_yaw`). With the attitude, the marker's known
place on the hull turns the corners into the AUV's centre of gravity and its
capture point (lifting eye).

Eq. 4 adds the marker's offset ``D`` (base midpoint below the hull's top
line) along the world vertical; on a pitched hull it lies along the body's
vertical instead. :func:`marker_attitude` starts from eq. 4 as printed and,
with ``refine=True``, re-applies ``D`` along the body axis of the current
estimate (a fixed point reached in two or three passes).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from auv_envs.core import frames
from auv_envs.core.ops import FLOATS
from auv_envs.tasks.lars.stereo import StereoRig, triangulate

#: Floor on the pixel noise the measurement covariance assumes (px): detectors
#: are never better than sub-pixel, and a zero covariance would make the
#: filter trust one fix absolutely.
MIN_PIXEL_STD = 0.3
#: Corners with a smaller disparity (px) are treated as mismatched: 1 px at
#: the default rig is 50 m away.
MIN_DISPARITY = 1.0
#: Matched corners behind the measured pixel noise before it is trusted.
ADAPT_MIN_CORNERS = 30


def attitude_rotation(pitch: float, yaw: float, xp=np) -> np.ndarray:
    """Body-to-world rotation (3, 3) of the level-rolled AUV with nose-up ``pitch`` and ``yaw``.

    The attitude convention of ``auv_envs/LARSCapture-v0`` (pitch nose up,
    yaw from world +x, counter-clockwise seen from above) through
    :func:`auv_envs.core.frames.rotation_from_euler`, whose ZYX pitch is
    nose-down positive, hence the sign. ``xp``: NumPy, or ``jax.numpy`` for traced angles.
    """
    return frames.rotation_from_euler(0.0, -pitch, yaw, xp)


def marker_pitch_yaw(corners, depth_offset: float, ops=FLOATS) -> tuple[float, float]:
    """AUV pitch and yaw from the marker's corners ([LTAT], eqs. 4-6).

    With A1, A2 the base corners, A3 the apex and ``D`` the marker's offset
    below the hull's top line, the base midpoint raised to the top line is

    * eq. 4: ``(x4, y4, z4) = ((x1 + x2) / 2, (y1 + y2) / 2, (z1 + z2) / 2 + D)``,

    and the apex direction from it gives

    * eq. 5: ``pitch = arctan((z3 - z4) / sqrt((x3 - x4)^2 + (y3 - y4)^2))``,
    * eq. 6: ``yaw = arctan((x3 - x4) / (y3 - y4))`` (``atan2`` here, which keeps
      the quadrant).

    Args:
        corners: (3, 3) A1, A2 (base) and A3 (apex) in a z-up frame whose y
            axis is the reference heading, so that eq. 6's
            ``arctan((x3 - x4) / (y3 - y4))`` is the yaw. For corners in the
            world frame of this task (heading reference +x, yaw counter-
            clockwise), pass them with x and y swapped: ``corners[:, [1, 0, 2]]``.
        depth_offset: ``D`` of eq. 4.
        ops: :data:`~auv_envs.core.ops.FLOATS` (the default) or
            :func:`~auv_envs.core.ops.jax_ops` (traced corners).

    Returns:
        ``(pitch, yaw)`` in radians; pitch is nose-up positive.
    """
    a = ops.xp.asarray(corners, dtype=float)
    x4, y4 = 0.5 * (a[0, 0] + a[1, 0]), 0.5 * (a[0, 1] + a[1, 1])
    z4 = 0.5 * (a[0, 2] + a[1, 2]) + depth_offset  # eq. 4
    dx, dy, dz = a[2, 0] - x4, a[2, 1] - y4, a[2, 2] - z4
    pitch = ops.atan(dz / ops.hypot(dx, dy))  # eq. 5
    yaw = ops.atan2(dx, dy)  # eq. 6 (atan2 keeps the quadrant)
    return pitch, yaw


def marker_attitude(corners, depth_offset: float, refine: bool = True,
                    passes: int = 3, ops=FLOATS) -> tuple[float, float]:
    """AUV pitch (nose up) and yaw (from world +x, counter-clockwise) from A1, A2, A3.

    Args:
        corners: (3, 3) world-frame corners A1, A2, A3 (z up).
        depth_offset: ``D`` of eq. 4, m.
        refine: apply ``D`` along the body vertical (see the module docstring);
            ``False`` is eqs. 4-6 as printed.
        passes: refinement passes.
        ops: as :func:`marker_pitch_yaw`'s.
    """
    xp = ops.xp
    a = xp.asarray(corners, dtype=float)
    swap = [1, 0, 2]  # eq. 6 measures yaw from the y axis; the world's heading is +x
    pitch, yaw = marker_pitch_yaw(a[:, swap], depth_offset, ops)
    if refine:
        for _ in range(passes):
            # shift the base so that eq. 4's "+ D z" lands at "+ D body_z"
            shift = depth_offset * (attitude_rotation(pitch, yaw, xp)[:, 2] - xp.asarray(
                (0.0, 0.0, 1.0)))
            moved = xp.concatenate([a[:2] + shift, a[2:]])
            pitch, yaw = marker_pitch_yaw(moved[:, swap], depth_offset, ops)
    return pitch, yaw


def triangulation_jacobian(rig: StereoRig, left_pixels, right_pixels) -> np.ndarray:
    """d(X, Y, Z) / d(u_left, v_left, u_right) of eq. 2 at each matched pair, (N, 3, 3).

    Eq. 2 reads only the left row coordinate, so ``v_right`` has no column.
    """
    left = np.atleast_2d(np.asarray(left_pixels, dtype=float))
    right = np.atleast_2d(np.asarray(right_pixels, dtype=float))
    k = rig.left
    x = left[:, 0] - k.cx
    y = left[:, 1] - k.cy
    d = rig.disparity(left[:, 0], right[:, 0], np)
    s = rig.baseline / d
    ratio = k.fx / k.fy
    jac = np.zeros((left.shape[0], 3, 3))
    jac[:, 0, 0] = s * (1.0 - x / d)
    jac[:, 0, 2] = s * x / d
    jac[:, 1, 0] = -y * s * ratio / d
    jac[:, 1, 1] = s * ratio
    jac[:, 1, 2] = y * s * ratio / d
    jac[:, 2, 0] = -k.fx * s / d
    jac[:, 2, 2] = k.fx * s / d
    return jac


@dataclasses.dataclass(frozen=True)
class MarkerFix:
    """The marker in one stereo observation.

    Attributes:
        corners: (3, 3) world-frame A1, A2, A3, NaN where not triangulated.
        covariances: (3, 3, 3) world-frame covariance of each corner (NaN
            where not triangulated), from the pixel noise through eq. 2.
        valid: (3,) which corners were triangulated (seen in both images with
            a positive disparity).
        rejected: corners seen in both images but dropped (disparity below
            :data:`MIN_DISPARITY`: a mismatch).
        pitch, yaw: attitude from eqs. 4-6 when all three corners are valid,
            else ``None``.
    """

    corners: np.ndarray
    covariances: np.ndarray
    valid: np.ndarray
    rejected: int
    pitch: float | None
    yaw: float | None

    @property
    def count(self) -> int:
        return int(self.valid.sum())


class MarkerLocaliser:
    """Marker corners, attitude and AUV points from a ``features`` observation.

    The pixel noise the covariances assume starts at ``pixel_std`` and, with
    ``adapt=True``, rises to what the observations show: in a rectified pair
    a corner's row is the same in both images, so ``v_left - v_right`` of
    matched corners is pure detection noise with variance ``2 sigma^2``. The
    running estimate is used once ``ADAPT_MIN_CORNERS`` corners back it, and
    only when it exceeds ``pixel_std`` (a front end noisier than the
    calibration's nominal features is taken at its measured noise). Each
    residual is clipped at 4 sigma of the current assumption, so a few
    mismatched corners cannot inflate it (the filter's gate deals with them).

    Args:
        calibration: the env's ``LARSCalibration`` (stereo rig, hand-eye
            transforms, arm kinematics, marker geometry).
        pixel_std: pixel noise (px) assumed at the start (default: the
            calibration's), floored at :data:`MIN_PIXEL_STD`.
        refine_attitude: see :func:`marker_attitude`.
        adapt: raise the assumed noise to the measured row residuals.
    """

    def __init__(self, calibration, pixel_std: float | None = None,
                 refine_attitude: bool = True, adapt: bool = True):
        std = calibration.pixel_noise_std if pixel_std is None else float(pixel_std)
        if not np.isfinite(std) or std < 0:
            raise ValueError(f"pixel_std must be finite and >= 0, got {pixel_std}")
        self.calibration = calibration
        self.nominal_pixel_std = max(std, MIN_PIXEL_STD)
        self.refine_attitude = refine_attitude
        self.adapt = adapt
        self.reset()
        marker = calibration.marker
        self._body = np.asarray(marker.corners, dtype=float)
        self._body_centre = self._body.mean(axis=0)
        self._depth_offset = float(marker.depth_offset)
        self._capture_body = np.asarray(calibration.capture_point_body, dtype=float)

    def reset(self) -> None:
        """Forget the measured row residuals (a new episode)."""
        self._row_sq, self._rows = 0.0, 0

    @property
    def measured_pixel_std(self) -> float:
        """Pixel noise measured from the rectified rows so far (NaN before any corner)."""
        return math.sqrt(self._row_sq / (2.0 * self._rows)) if self._rows else math.nan

    @property
    def pixel_std(self) -> float:
        """The pixel noise the covariances assume now."""
        if self.adapt and self._rows >= ADAPT_MIN_CORNERS:
            return max(self.nominal_pixel_std, self.measured_pixel_std)
        return self.nominal_pixel_std

    def locate(self, pixels, visible, joint_position) -> MarkerFix:
        """Triangulate the corners seen in both images and express them in the world.

        Args:
            pixels: (2, 3, 2) corner pixels (left, right) x (A1, A2, A3).
            visible: (2, 3) which are valid.
            joint_position: (3,) arm joint angles at the time of the images.

        Raises:
            ValueError: on wrong shapes or non-finite pixels of visible corners.
        """
        px = np.asarray(pixels, dtype=float)
        vis = np.asarray(visible).astype(bool)
        q = np.asarray(joint_position, dtype=float)
        if px.shape != (2, 3, 2) or vis.shape != (2, 3) or q.shape != (3,):
            raise ValueError("expected pixels (2, 3, 2), visible (2, 3) and joint_position (3,), "
                             f"got {px.shape}, {vis.shape}, {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError("joint_position has non-finite entries")
        both = vis[0] & vis[1]
        if not np.all(np.isfinite(px[:, both])):
            raise ValueError("pixels of visible corners must be finite")
        rig = self.calibration.stereo
        disparity = rig.disparity(px[0, :, 0], px[1, :, 0], np)
        valid = both & (disparity > MIN_DISPARITY)
        corners = np.full((3, 3), np.nan)
        covs = np.full((3, 3, 3), np.nan)
        pitch = yaw = None
        if valid.any():
            left, right = px[0, valid], px[1, valid]
            # clipped at 4 sigma of the difference: a mismatch is the gate's business
            limit = 4.0 * math.sqrt(2.0) * self.pixel_std
            rows = np.clip(left[:, 1] - right[:, 1], -limit, limit)
            self._row_sq += float(rows @ rows)
            self._rows += int(rows.size)
            cam = triangulate(rig, left, right)  # eq. 2, left camera frame
            pose = self.calibration.camera_poses(q)[0]  # eq. 3: world <- left camera
            rot = pose[:3, :3]
            corners[valid] = cam @ rot.T + pose[:3, 3]
            jac = rot @ triangulation_jacobian(rig, left, right)
            covs[valid] = self.pixel_std**2 * jac @ jac.transpose(0, 2, 1)
            if valid.all():
                pitch, yaw = marker_attitude(corners, self._depth_offset, self.refine_attitude)
        return MarkerFix(corners, covs, valid, int((both & ~valid).sum()), pitch, yaw)

    def auv_position(self, fix: MarkerFix, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The AUV's CG (3,) and its covariance (3, 3) from the valid corners of ``fix``.

        Each valid corner gives ``A_i - R a_i`` (``a_i`` the corner on the
        hull); the estimate is their mean, its covariance the mean of the
        corner covariances over ``n`` (independent corners; the attitude's
        own uncertainty is left out).

        Raises:
            ValueError: if ``fix`` has no valid corner.
        """
        if not fix.valid.any():
            raise ValueError("the fix has no triangulated corner")
        n = fix.count
        cg = (fix.corners[fix.valid] - self._body[fix.valid] @ rotation.T).mean(axis=0)
        cov = fix.covariances[fix.valid].sum(axis=0) / n**2
        return cg, cov

    def capture_point(self, cg, rotation: np.ndarray) -> np.ndarray:
        """The capture point (lifting eye) in the world for CG ``cg`` and attitude ``rotation``."""
        return np.asarray(cg, dtype=float) + rotation @ self._capture_body

    def marker_centre(self, cg, rotation: np.ndarray) -> np.ndarray:
        """The centroid of the three corners in the world."""
        return np.asarray(cg, dtype=float) + rotation @ self._body_centre
