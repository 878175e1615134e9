"""Seed 002's lamp-array vision front end: an image of guide lamps -> labelled pixel tracks.

The pipeline follows seed 002 §2 (Zhang et al., "Monocular vision guided lamp array tracking
method for the UUV recovery process", J. Unmanned Undersea Systems 29(4), 2021):

1. **Improved adaptive thresholding** (§2.1.2): a classic local-mean adaptive threshold
   pre-segments the frame into foreground regions (BLOB analysis); each region then gets its own
   threshold (Otsu's, seed 002 ref. [9]) inside its bounding box; morphological closing, opening
   and hole filling smooth the lamp silhouettes (:func:`segment_lamps`).
2. **Blob analysis** (§2.1.1, §2.2.3 1)): centre, area and bounding box of each lamp blob.
3. **Identity at initialisation** (§2.2.2): when every lamp is detected, the lamps are labelled by
   geometry: for the L-shaped array A, B, C, D by the shape of the L (:func:`identify_l_shape`:
   seed 002 uses edge lengths; we use the line A-B-C, B between A and C, and the side D is on,
   which a perspective view keeps); for a convex ring such as the six symmetric docking lights
   by their cyclic order and the fit of the rigid array with the INS attitude
   (:func:`ring_labelings`, our documented rule; four of the six lights suffice).
4. **One EKF per lamp on its blob features** (§2.2.3 1)): :class:`BlobEKF`.
5. **Cost matrix with the array's rigid-body information + Hungarian assignment** (§2.2.3 2)):
   the EKF prediction of each lamp is weighed with the lamp's position predicted by the rigid
   array (:class:`CameraPositionFilter`); detections are assigned with
   ``scipy.optimize.linear_sum_assignment`` under a gate.
6. **Corrected tracks** (§2.2.3 steps 3-4): matched lamps are corrected by their detection;
   lamps out of view (or occluded) keep a prediction (seed 002 Fig. 10 b, d).

Our choices where seed 002 is silent, each measured on this package's renders:

* The lamp centre is the centre of the blob's minimum enclosing circle, not its first moment: a
  lamp is a sphere whose silhouette is a disc, and the circle through its outermost points is
  unchanged when a structure hides less than half of it (the rail under the lamps of
  ``LampArrayDocking-v1`` clips their lower edge; the first moment was then 1.1-1.2 px off the
  projected centre, the circle centre <= 0.5 px).
* The rigid-array prediction comes from a small EKF on the camera position, fed by the INS
  attitude and DVL velocity that the observation carries and by the tracked lamps; each update
  also estimates that frame's INS attitude error. It keeps out-of-view lamps predicted where
  the array puts them, so they are re-acquired under the right label.
* A lamp is reported visible only when its centre is: the pixels where the rest of the array
  puts the centre must be lit. A lamp half hidden by the fork or the image border leaves a
  blob whose circle is biased; the env, too, calls a lamp visible when the line of sight to
  its centre is clear.
* Lamps whose blobs merge (overlapping in the image) are reported where the array, fitted to
  the merged blob through the mean of its members' projections, puts them.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from auv_envs.core.camera import CameraIntrinsics, pixel_space
from auv_envs.core.frames import rotation_from_euler
from baselines.kalman import constant_velocity_blocks, joseph_covariance, kalman_gain

#: Track status codes (:attr:`LampTracks.status`).
UNINITIALISED, DETECTED, MERGED, PREDICTED = 0, 1, 2, 3
STATUS_NAMES = ("uninitialised", "detected", "merged", "predicted")
#: A disc cut by a straight edge (an occluder, the image border) keeps its centre iff more than
#: half of it is left, which is then also its enclosing circle's share: the least fill of a
#: blob whose centre is trusted.
MIN_FILL = 0.5
#: Noise scale of the centre of a blob cut by the image border (its circle may be biased).
BORDER_SIGMA_SCALE = 4.0


# --------------------------------------------------------------------------- segmentation


@dataclasses.dataclass(frozen=True)
class SegmentationParams:
    """Improved adaptive thresholding (seed 002 §2.1.2).

    Attributes:
        block_size: neighbourhood of the pre-segmentation's local mean (odd), px.
        offset: a pre-segmented pixel is brighter than its local mean by more than this.
        min_peak: a region is a lamp candidate only if its brightest pixel reaches this (the
            lamps are the brightest things in the scene; seed 002 ignores stray light, §4).
        min_area: smallest lamp blob, px.
        margin: the per-region threshold is computed in the region's box grown by this, px.
        kernel: side of the elliptical structuring element of closing and opening, px.
    """

    block_size: int = 31
    offset: float = 25.0
    min_peak: int = 128
    min_area: int = 4
    margin: int = 3
    kernel: int = 3

    def __post_init__(self):
        if self.block_size < 3 or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd and >= 3, got {self.block_size}")
        if not 0 < self.min_peak <= 255:
            raise ValueError(f"min_peak must be in (0, 255], got {self.min_peak}")
        if not (isinstance(self.offset, int | float) and math.isfinite(self.offset)):
            raise ValueError(f"offset must be a finite number of grey levels, got {self.offset!r}")
        if self.min_area < 1 or self.margin < 1 or self.kernel < 1:
            raise ValueError("min_area, margin and kernel must be >= 1")


@dataclasses.dataclass(frozen=True)
class Blobs:
    """Lamp blobs of one frame (m of them), pixel frame of :mod:`auv_envs.core.camera`.

    Attributes:
        centres: (m, 2) centre of each blob's minimum enclosing circle, px.
        radii: (m,) radius of that circle, px.
        areas: (m,) pixel count of the (hole-filled) blob.
        boxes: (m, 4) bounding box ``x, y, w, h`` (integer pixel indices).
        on_border: (m,) whether the blob touches the image border (it may be cut off).
    """

    centres: np.ndarray
    radii: np.ndarray
    areas: np.ndarray
    boxes: np.ndarray
    on_border: np.ndarray

    def __len__(self) -> int:
        return len(self.radii)

    @property
    def fill(self) -> np.ndarray:
        """(m,) share of each blob's enclosing circle that the blob covers."""
        return self.areas / (math.pi * self.radii**2)


def _empty_blobs() -> Blobs:
    return Blobs(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 4), int),
                 np.zeros(0, bool))


def _merge_boxes(boxes: list[list[int]]) -> list[list[int]]:
    """Union overlapping boxes ``[x0, y0, x1, y1)`` until none overlap (few boxes per frame)."""
    boxes = [b[:] for b in boxes]
    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    boxes[i] = [min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]),
                                max(a[3], b[3])]
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return boxes


def segment_lamps(gray: np.ndarray, params: SegmentationParams | None = None) -> Blobs:
    """Lamp blobs in a grayscale frame by seed 002's improved adaptive thresholding (§2.1.2).

    1. Pre-segmentation: ``cv2.adaptiveThreshold`` (local mean + offset) and its connected
       regions (external contours) give foreground regions; regions without a pixel of at
       least ``min_peak`` are dropped. (Inside a large saturated lamp the local mean is
       saturated too, so the pre-segmentation keeps only its rim; the next step recovers
       the disc.)
    2. Per-region threshold: Otsu's threshold inside each region's box (grown by ``margin``;
       overlapping boxes are united first).
    3. Morphological closing then opening, and hole filling (filled external contours).
    4. Blob analysis: minimum enclosing circle, area and bounding box of each blob.

    Args:
        gray: (H, W) uint8 image.
        params: segmentation parameters (defaults: :class:`SegmentationParams`).

    Returns:
        The blobs (possibly none).

    Raises:
        ValueError: not a 2-D uint8 array.
    """
    p = params or SegmentationParams()
    if not isinstance(gray, np.ndarray) or gray.ndim != 2 or gray.dtype != np.uint8:
        raise ValueError("gray must be a 2-D uint8 array")
    if gray.size == 0 or int(gray.max()) < p.min_peak:
        return _empty_blobs()
    height, width = gray.shape
    pre = cv2.adaptiveThreshold(
        gray, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY, p.block_size, -p.offset
    )
    # External contours give the regions' boxes (OpenCV 5's connectedComponentsWithStats took
    # ~6 ms per 640x480 frame here, findContours ~0.1 ms).
    regions, _ = cv2.findContours(pre, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    boxes = []
    for region in regions:
        x, y, w, h = cv2.boundingRect(region)
        x0, y0 = max(x - p.margin, 0), max(y - p.margin, 0)
        x1, y1 = min(x + w + p.margin, width), min(y + h + p.margin, height)
        if gray[y0:y1, x0:x1].max() >= p.min_peak:
            boxes.append([int(x0), int(y0), int(x1), int(y1)])
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (p.kernel, p.kernel))
    centres, radii, areas, out_boxes, border = [], [], [], [], []
    for x0, y0, x1, y1 in _merge_boxes(boxes):
        roi = gray[y0:y1, x0:x1]
        _, mask = cv2.threshold(roi, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        for contour in contours:
            filled = np.zeros_like(mask)
            cv2.drawContours(filled, [contour], -1, 255, cv2.FILLED)
            area = int(cv2.countNonZero(filled))
            if area < p.min_area or roi[filled > 0].max() < p.min_peak:
                continue
            (cx, cy), radius = cv2.minEnclosingCircle(contour)
            bx, by, bw, bh = cv2.boundingRect(contour)
            bx, by = bx + x0, by + y0
            # +0.5: OpenCV indexes pixel centres, the camera model's origin is the corner.
            centres.append((cx + x0 + 0.5, cy + y0 + 0.5))
            # +0.5: the circle passes through boundary pixel centres, the disc edge is beyond.
            radii.append(radius + 0.5)
            areas.append(area)
            out_boxes.append((bx, by, bw, bh))
            border.append(bx == 0 or by == 0 or bx + bw == width or by + bh == height)
    if not centres:
        return _empty_blobs()
    return Blobs(np.array(centres, float), np.array(radii, float), np.array(areas, float),
                 np.array(out_boxes, int), np.array(border, bool))


# --------------------------------------------------------------------------- identity


def identify_l_shape(centres: np.ndarray, layout: np.ndarray,
                     collinear_tol: float = 0.08) -> np.ndarray | None:
    """Label four detections as lamps A, B, C, D of seed 002's L-shaped array (§2.2.2).

    A, B, C lie on a line and D beside C (seed 002 §1.2, Fig. 2). Seed 002 tells them apart
    by the edge lengths of the detected quadrilateral; a perspective view changes lengths, so
    this rule uses the properties that survive it:

    * lines stay straight: the three collinear detections are A, B, C and the fourth is D;
    * along the line, B lies between A and C (AC is the longest edge of the triple);
    * the L keeps its sense: seen from the lamps' upper side (the camera above the plane of
      the lamps, as for a vehicle approaching the station), D lies on the same side of the
      directed line A -> C in every view. Which side, in image coordinates, follows from
      ``layout``.

    Args:
        centres: (4, 2) detection centres, px.
        layout: (4, 3) positions of A, B, C, D in the station frame (z up).
        collinear_tol: largest ratio of the second to the first singular value of the centred
            triple that counts as collinear; the next-best triple must exceed twice it.

    Returns:
        Detection index of A, B, C, D, or None when the geometry is ambiguous.
    """
    pts = np.asarray(centres, dtype=float)
    if pts.shape != (4, 2) or not np.isfinite(pts).all():
        raise ValueError(f"need four finite (u, v) centres, got shape {pts.shape}")
    lamps = np.asarray(layout, dtype=float)
    if lamps.shape != (4, 3):
        raise ValueError(f"layout must be the (4, 3) positions of A, B, C, D, got {lamps.shape}")
    scores = []
    for d in range(4):
        tri = pts[[k for k in range(4) if k != d]]
        sv = np.linalg.svd(tri - tri.mean(axis=0), compute_uv=False)
        scores.append(sv[1] / sv[0] if sv[0] > 0 else np.inf)
    order = np.argsort(scores)
    d = int(order[0])
    if not (scores[d] <= collinear_tol < 0.5 * scores[order[1]]):
        return None
    line = [k for k in range(4) if k != d]
    tri = pts[line]
    direction = np.linalg.svd(tri - tri.mean(axis=0))[2][0]
    end0, b, end1 = (line[k] for k in np.argsort(tri @ direction))
    # Sense of the L seen from above: the image's v axis points down, so a counter-clockwise
    # turn A -> C -> D in the station's xy plane (z up) is clockwise (negative) in the image.
    normal_z = np.cross(lamps[2] - lamps[0], lamps[3] - lamps[2])[2]
    (ax, ay), (bx, by) = pts[end1] - pts[end0], pts[d] - pts[end1]
    turn = ax * by - ay * bx
    span = np.linalg.norm(pts[end1] - pts[end0]) * np.linalg.norm(pts[d] - pts[end1])
    if abs(turn) < 0.05 * span or normal_z == 0.0:
        return None  # D (nearly) on the line: the sense cannot be read
    a, c = (end0, end1) if np.sign(turn) == -np.sign(normal_z) else (end1, end0)
    return np.array([a, b, c, d])


def ring_labelings(centres: np.ndarray, ring_order: np.ndarray) -> list[np.ndarray]:
    """Candidate labellings of k detections of a convex planar ring of n lights (k <= n).

    Our rule for symmetric layouts such as the six docking lights, where edge lengths cannot
    tell the lights apart: seen from its front, a convex planar array keeps the cyclic order
    of its lights in the image. So the detections, in their order about their centroid, are
    the lights of some k-subset of the ring in ring order, up to a cyclic shift:
    C(n, k) * k candidates (6 for six of six lights, 30 for five). The front end keeps the
    one that fits the rigid array with the measured attitude best (:meth:`LampArrayFrontEnd
    ._identify_ring`).

    Args:
        centres: (k, 2) detection centres, px (k >= 3).
        ring_order: the n light indices in their cyclic order in the image (the order of
            their angles about their centroid in a projection of the layout).

    Returns:
        Arrays ``labels`` (k,): ``labels[j]`` is the light of detection j.
    """
    pts = np.asarray(centres, dtype=float)
    ring = np.asarray(ring_order, dtype=int)
    if pts.ndim != 2 or pts.shape[1] != 2 or not 3 <= len(pts) <= len(ring):
        raise ValueError(f"need 3..{len(ring)} (u, v) centres, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("centres must be finite")
    k = len(pts)
    rel = pts - pts.mean(axis=0)
    det_order = np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))
    out = []
    for subset in itertools.combinations(range(len(ring)), k):
        lights = ring[list(subset)]
        for shift in range(k):
            labels = np.empty(k, dtype=int)
            labels[np.roll(det_order, -shift)] = lights
            out.append(labels)
    return out


# --------------------------------------------------------------------------- filters


class BlobEKF:
    """EKF on one lamp's blob features (seed 002 §2.2.3 1)).

    State ``x = (u, v, du, dv, s, ds)``: blob centre (px), its velocity (px/s), the lamp's
    apparent radius ``s`` (px) and its rate, each pair a constant-velocity model. Measurement
    ``z = (u, v, area, w, h)``: the blob's centre, area and bounding-box sides. A lamp is a
    sphere, so its blob is a disc: ``area = pi s^2`` and ``w = h = 2 s`` -- the nonlinear
    measurement function whose Jacobian the update linearises.
    """

    def __init__(self, x0: np.ndarray, p0: np.ndarray):
        self.x = np.asarray(x0, dtype=float).copy()
        self.P = np.asarray(p0, dtype=float).copy()

    @property
    def position(self) -> np.ndarray:
        return self.x[0:2].copy()

    @property
    def position_cov(self) -> np.ndarray:
        return self.P[0:2, 0:2].copy()

    @staticmethod
    def transition(dt: float, accel_sigma: float,
                   size_accel_sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """Transition matrix F and process noise Q over ``dt`` s (accelerations in px/s^2)."""
        f_pos, q_pos = constant_velocity_blocks(dt, accel_sigma)
        f_size, q_size = constant_velocity_blocks(dt, size_accel_sigma)
        F = np.zeros((6, 6))
        Q = np.zeros((6, 6))
        for idx, (f, q) in zip(((0, 2), (1, 3), (4, 5)), ((f_pos, q_pos), (f_pos, q_pos),
                                                           (f_size, q_size)), strict=True):
            F[np.ix_(idx, idx)] = f
            Q[np.ix_(idx, idx)] = q
        return F, Q

    def predict(self, F: np.ndarray, Q: np.ndarray) -> None:
        """Prediction with :meth:`transition`'s matrices."""
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q

    @staticmethod
    def measure(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``h(x)`` and its Jacobian."""
        s = x[4]
        h = np.array([x[0], x[1], math.pi * s * s, 2.0 * s, 2.0 * s])
        H = np.zeros((5, 6))
        H[0, 0] = H[1, 1] = 1.0
        H[2, 4] = 2.0 * math.pi * s
        H[3, 4] = H[4, 4] = 2.0
        return h, H

    def update(self, z: np.ndarray, R: np.ndarray, rows=slice(None)) -> None:
        """EKF update with the measurement rows ``rows`` of ``(u, v, area, w, h)``."""
        h, H = self.measure(self.x)
        self._correct(np.asarray(z)[rows] - h[rows], H[rows], np.asarray(R)[rows][:, rows])

    def update_position(self, uv: np.ndarray, cov: np.ndarray) -> None:
        """Linear update with a position-only (pseudo-)measurement."""
        H = np.zeros((2, 6))
        H[0, 0] = H[1, 1] = 1.0
        self._correct(np.asarray(uv) - self.x[0:2], H, cov)

    def _correct(self, innovation: np.ndarray, H: np.ndarray, R: np.ndarray) -> None:
        K = kalman_gain(self.P, H, R)
        self.x = self.x + K @ innovation
        self.P = joseph_covariance(self.P, K, H, R)
        self.x[4] = max(self.x[4], 0.5)


def _skew(v: np.ndarray) -> np.ndarray:
    """Matrices [v]x of the rows of ``v`` (n, 3) -> (n, 3, 3), with [v]x w = v x w."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


class CameraPositionFilter:
    """EKF on the camera centre in the array's (DS) frame: the rigid-array observer.

    The camera rotation comes from the INS attitude of each observation (``set_rotation``), so
    the unknown of the array's rigid-body pose is the camera position ``t``. It is propagated
    with the DVL displacement and corrected with the pixel centres of the tracked lamps through
    the pinhole model; projecting the array from it predicts every lamp, in view or not.

    The INS attitude is noisy (``attitude_sigma``, white from frame to frame), and 0.2 deg is
    2 px at this camera's focal length; each update therefore also estimates that frame's
    small camera rotation error ``dtheta`` (prior N(0, attitude_sigma^2 I), forgotten at the
    next frame), and projections use it until then.

    Args:
        intrinsics: camera intrinsics.
        points: (n, 3) lamp positions in the DS frame.
    """

    def __init__(self, intrinsics: CameraIntrinsics, points: np.ndarray):
        self.intrinsics = intrinsics
        self.points = np.asarray(points, dtype=float)
        self.t = np.zeros(3)
        self.P = np.eye(3)
        self.dtheta = np.zeros(3)
        self.attitude_sigma = 0.0
        self.world_to_cam = np.eye(3)

    def set_rotation(self, cam_to_world: np.ndarray, attitude_sigma: float = 0.0) -> None:
        """The new frame's measured camera rotation and its noise (rad); clears ``dtheta``."""
        self.world_to_cam = np.asarray(cam_to_world).T
        self.attitude_sigma = float(attitude_sigma)
        self.dtheta = np.zeros(3)

    def project(self, t: np.ndarray | None = None, dtheta: np.ndarray | None = None):
        """Pixels (n, 2), Jacobians d pixel / d t and d pixel / d dtheta (n, 2, 3 each) and
        the in-front mask (n,)."""
        k = self.intrinsics
        t = self.t if t is None else t
        dtheta = self.dtheta if dtheta is None else dtheta
        measured = (self.points - t) @ self.world_to_cam.T
        skew = _skew(measured)
        cam = measured + skew @ dtheta  # turned by the small rotation error dtheta
        z = np.maximum(cam[:, 2], 1e-6)
        pix = np.column_stack([k.fx * cam[:, 0] / z + k.cx, k.fy * cam[:, 1] / z + k.cy])
        d_pix_d_cam = np.zeros((len(cam), 2, 3))
        d_pix_d_cam[:, 0, 0] = k.fx / z
        d_pix_d_cam[:, 0, 2] = -k.fx * cam[:, 0] / z**2
        d_pix_d_cam[:, 1, 1] = k.fy / z
        d_pix_d_cam[:, 1, 2] = -k.fy * cam[:, 1] / z**2
        jac_t = -d_pix_d_cam @ self.world_to_cam
        jac_theta = d_pix_d_cam @ skew
        return pix, jac_t, jac_theta, cam[:, 2] > 0.05

    def prediction_cov(self, jac_t: np.ndarray, jac_theta: np.ndarray) -> np.ndarray:
        """(n, 2, 2) covariance of the projected lamps from ``P`` and the attitude noise."""
        cov = jac_t @ self.P @ jac_t.transpose(0, 2, 1)
        return cov + self.attitude_sigma**2 * jac_theta @ jac_theta.transpose(0, 2, 1)

    def _linear_position(self, lamp_ids: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """Least-squares camera position from the collinearity equations (each pixel's ray
        passes through its lamp), linear in the position once the rotation is known."""
        k = self.intrinsics
        m = self.world_to_cam
        x = (pixels[:, 0] - k.cx) / k.fx
        y = (pixels[:, 1] - k.cy) / k.fy
        rows = np.concatenate([x[:, None] * m[2] - m[0], y[:, None] * m[2] - m[1]])
        points = self.points[np.concatenate([lamp_ids, lamp_ids])]
        rhs = np.einsum("ij,ij->i", rows, points)
        return np.linalg.lstsq(rows, rhs, rcond=None)[0]

    def fit_residual(self, lamp_ids: np.ndarray, pixels: np.ndarray) -> float:
        """RMS pixel error (per axis) of the best linear fit of the camera position to
        labelled lamps; inf if a lamp lands behind the camera. Leaves the filter unchanged."""
        pix, _, _, front = self.project(self._linear_position(lamp_ids, pixels))
        if not front[lamp_ids].all():
            return math.inf
        return float(np.sqrt(np.mean((pixels - pix[lamp_ids]) ** 2)))

    def initialise(self, lamp_ids: np.ndarray, pixels: np.ndarray, sigma: float) -> float:
        """Camera position from >= 2 labelled lamps; returns the RMS reprojection error (px,
        per axis).

        The linear solve of :meth:`fit_residual` followed by three Gauss-Newton steps on the
        pixel error.
        """
        lamp_ids = np.asarray(lamp_ids, dtype=int)
        pixels = np.asarray(pixels, dtype=float)
        self.t = self._linear_position(lamp_ids, pixels)
        for _ in range(3):
            pix, jac, _, _ = self.project()
            J = jac[lamp_ids].reshape(-1, 3)
            r = (pixels - pix[lamp_ids]).ravel()
            self.t = self.t + np.linalg.lstsq(J, r, rcond=None)[0]
        pix, jac, _, front = self.project()
        J = jac[lamp_ids].reshape(-1, 3)
        self.P = np.linalg.inv(J.T @ J / sigma**2 + 1e-6 * np.eye(3))
        if not front[lamp_ids].all():
            return math.inf
        return float(np.sqrt(np.mean((pixels - pix[lamp_ids]) ** 2)))

    def predict(self, displacement: np.ndarray, sigma: float) -> None:
        self.t = self.t + displacement
        self.P = self.P + sigma**2 * np.eye(3)

    def snapshot(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.t.copy(), self.P.copy(), self.dtheta.copy()

    def restore(self, state: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        self.t, self.P, self.dtheta = (x.copy() for x in state)

    def update(self, groups: list[np.ndarray], pixels: np.ndarray, sigmas: np.ndarray,
               iterations: int = 2) -> None:
        """Iterated EKF update of ``(t, dtheta)``; measurement k is the mean projection of the
        lamps in ``groups[k]`` (one lamp, or the members of a merged blob)."""
        if not groups:
            return
        z = np.asarray(pixels, dtype=float).ravel()
        R = np.diag(np.repeat(np.asarray(sigmas, float) ** 2, 2))
        prior = np.concatenate([self.t, np.zeros(3)])
        P = np.zeros((6, 6))
        P[:3, :3] = self.P
        P[3:, 3:] = self.attitude_sigma**2 * np.eye(3)
        mean = np.zeros((len(groups), len(self.points)))  # row k averages groups[k]
        for k, g in enumerate(groups):
            mean[k, g] = 1.0 / len(g)
        x = prior
        for _ in range(iterations):
            pix, jac_t, jac_theta, _ = self.project(x[:3], x[3:])
            h = (mean @ pix).ravel()
            jac = np.concatenate([jac_t, jac_theta], axis=2).reshape(len(pix), 12)
            H = (mean @ jac).reshape(-1, 6)
            K = kalman_gain(P, H, R)
            x = prior + K @ (z - h - H @ (prior - x))
        P = joseph_covariance(P, K, H, R)
        self.t, self.dtheta = x[:3], x[3:]
        self.P = P[:3, :3]


# --------------------------------------------------------------------------- tracker


@dataclasses.dataclass(frozen=True)
class TrackerParams:
    """Tracking parameters (our defaults, tuned on seeded renders, not on test data).

    Attributes:
        pixel_sigma: noise of a blob centre, px.
        accel_sigma: white-noise acceleration of a lamp in the image, px/s^2.
        size_accel_sigma: same for the apparent radius, px/s^2.
        rigid_sigma: floor on the rigid-array prediction's noise, px (attitude noise, model).
        velocity_sigma: error of the camera displacement per step from the DVL, m/s.
        gate_chi2: Mahalanobis^2 gate of a lamp-detection pair (2 dof).
        gate_px: largest distance of a pair, px.
        merge_margin: an unmatched lamp predicted this close to a blob's circle is inside it, px.
        init_max_residual: largest RMS reprojection error of the array at initialisation, px.
        lost_after: frames without any detection after which the tracks are dropped and the
            array must be initialised again.
        centre_halo: a lamp is seen when the (2 halo + 1)^2 pixels around the array's
            prediction of its centre are all lamp-bright.
        ring_init_min: lights of a ring that must be detected to initialise (the L-shaped
            array needs all four, as in seed 002).
    """

    pixel_sigma: float = 0.7
    accel_sigma: float = 150.0
    size_accel_sigma: float = 20.0
    rigid_sigma: float = 2.0
    velocity_sigma: float = 0.05
    gate_chi2: float = 16.0
    gate_px: float = 40.0
    merge_margin: float = 2.0
    init_max_residual: float = 8.0
    lost_after: int = 300
    centre_halo: int = 1
    ring_init_min: int = 4

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.type in (int, "int"):
                low = {"centre_halo": 0, "ring_init_min": 3}.get(field.name, 1)
                if not (isinstance(value, int) and value >= low):
                    raise ValueError(f"{field.name} must be an integer >= {low}, got {value!r}")
            elif not (math.isfinite(value) and value > 0):
                raise ValueError(f"{field.name} must be finite and > 0, got {value}")


@dataclasses.dataclass(frozen=True)
class LampTracks:
    """Every lamp's track after a frame.

    Attributes:
        labels: lamp names in calibration order.
        pixels: (n, 2) corrected position of each lamp (a prediction unless detected), px;
            NaN before initialisation or behind the camera.
        radii: (n,) apparent radius, px (NaN before initialisation).
        status: (n,) one of UNINITIALISED, DETECTED, MERGED, PREDICTED.
    """

    labels: tuple[str, ...]
    pixels: np.ndarray
    radii: np.ndarray
    status: np.ndarray

    @property
    def reported(self) -> np.ndarray:
        """Lamps reported visible (detected alone or inside a merged blob)."""
        return (self.status == DETECTED) | (self.status == MERGED)


class LampArrayFrontEnd:
    """Seed 002's lamp tracker as a front end (see :mod:`baselines.frontend`).

    ``front_end(observation, info)`` turns an ``image`` observation of a docking env into its
    ``features`` observation: ``pixels`` (n, 2) float32 (zero where not visible), ``visible``
    (n,) int8, ``velocity`` and ``attitude`` passed through. A lamp is reported visible when it
    was detected in this frame (alone or inside a merged blob), at its corrected position.
    Predictions of the other lamps are in :attr:`tracks`. ``info`` is never read: the front end
    sees only the observation and the calibration.

    Args:
        calibration: the env's ``calibration`` (intrinsics, extrinsics, light positions and
            labels, control period).
        identity: ``"l-shape"`` (lamps A, B, C, D of seed 002), ``"ring"`` (a convex planar
            array seen from the front) or ``"auto"`` (l-shape for labels A, B, C, D, else ring).
        segmentation: :class:`SegmentationParams`.
        tracking: :class:`TrackerParams`.
    """

    def __init__(self, calibration, identity: str = "auto",
                 segmentation: SegmentationParams | None = None,
                 tracking: TrackerParams | None = None):
        labels = tuple(calibration.light_labels)
        if identity == "auto":
            identity = "l-shape" if labels == ("A", "B", "C", "D") else "ring"
        if identity not in ("l-shape", "ring"):
            raise ValueError(f"unknown identity rule {identity!r}; valid: 'auto', 'l-shape', "
                             "'ring'")
        if identity == "l-shape" and len(labels) != 4:
            raise ValueError("the l-shape identity rule needs four lamps")
        self.identity = identity
        self.labels = labels
        self.intrinsics = calibration.intrinsics
        self.segmentation = segmentation or SegmentationParams()
        self.params = tracking or TrackerParams()
        self._points = np.array(calibration.light_positions, dtype=float)
        self._cam_rot_body = np.array(calibration.extrinsics.rotation, dtype=float)
        self._cam_pos_body = np.array(calibration.extrinsics.position, dtype=float)
        self._dt = float(calibration.control_period)
        self._n = len(labels)
        self._image_shape = (self.intrinsics.height, self.intrinsics.width, 3)
        # The bounds of the env's features ``pixels`` space, which the output must lie in.
        pixels = pixel_space(self.intrinsics.width, self.intrinsics.height, (self._n,))
        self._pixel_bounds = (pixels.low, pixels.high)
        self._pose = CameraPositionFilter(self.intrinsics, self._points)
        self._transition = BlobEKF.transition(self._dt, self.params.accel_sigma,
                                              self.params.size_accel_sigma)
        # Sensor noise of the scenario (calibration) on top of the model's own allowances.
        self._attitude_sigma = float(calibration.attitude_noise_std)
        self._displacement_sigma = self._dt * math.hypot(self.params.velocity_sigma,
                                                         calibration.velocity_noise_std)
        self.reset()

    @classmethod
    def from_env(cls, env, **kwargs) -> LampArrayFrontEnd:
        """Front end for a docking env in ``image`` mode (wrapped or not)."""
        env = getattr(env, "unwrapped", env)
        if getattr(env, "obs_mode", None) != "image":
            raise ValueError("the lamp-array front end needs an env with obs_mode='image'")
        return cls(env.calibration, **kwargs)

    # ------------------------------------------------------------------ protocol
    def reset(self, seed: int | None = None) -> None:
        del seed  # deterministic
        self._tracks: list[BlobEKF] | None = None
        self._status = np.full(self._n, UNINITIALISED)
        self._prev_motion: tuple[np.ndarray, np.ndarray] | None = None  # body rot, velocity
        self._frames_without_detection = 0
        self._counts = {"frames": 0, "initialisations": 0, "track_losses": 0,
                        "detected": 0, "merged": 0, "predicted": 0}

    def __call__(self, observation, info: dict | None = None) -> dict:
        del info  # never read: no ground truth in the front end
        image, velocity, attitude = self._check_observation(observation)
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        blobs = segment_lamps(gray, self.segmentation)
        body_rot = rotation_from_euler(*attitude)
        self._pose.set_rotation(body_rot @ self._cam_rot_body, self._attitude_sigma)
        world_velocity = body_rot @ velocity[:3]
        if self._tracks is None:
            self._initialise(gray, blobs)
        else:
            self._track(gray, blobs, self._camera_displacement(body_rot, world_velocity))
        self._prev_motion = (body_rot, world_velocity)
        self._count()
        return self._features(velocity, attitude)

    def stats(self) -> dict:
        """Counts over the episode: frames, initialisations, track losses, and the fraction of
        initialised lamp-frames that were detected, merged or only predicted."""
        c = self._counts
        lamp_frames = max(c["detected"] + c["merged"] + c["predicted"], 1)
        return {
            "lamp_frames": c["frames"],
            "lamp_initialisations": c["initialisations"],
            "lamp_track_losses": c["track_losses"],
            "lamp_detected_fraction": c["detected"] / lamp_frames,
            "lamp_merged_fraction": c["merged"] / lamp_frames,
            "lamp_predicted_fraction": c["predicted"] / lamp_frames,
        }

    @property
    def initialised(self) -> bool:
        return self._tracks is not None

    @property
    def tracks(self) -> LampTracks:
        """Every lamp's corrected position or prediction after the last frame."""
        if self._tracks is None:
            nan = np.full((self._n, 2), np.nan)
            return LampTracks(self.labels, nan, np.full(self._n, np.nan), self._status.copy())
        pixels = np.array([t.position for t in self._tracks])
        front = self._pose.project()[3]
        pixels[~front] = np.nan
        radii = np.array([t.x[4] for t in self._tracks])
        return LampTracks(self.labels, pixels, radii, self._status.copy())

    # ------------------------------------------------------------------ steps
    def _check_observation(self, observation):
        if not isinstance(observation, dict):
            raise TypeError(f"observation must be a dict (image obs mode), got "
                            f"{type(observation).__name__}")
        missing = {"image", "velocity", "attitude"} - set(observation)
        if missing:
            raise KeyError(f"observation lacks {sorted(missing)}; the lamp-array front end "
                           "needs the image obs mode")
        image = observation["image"]
        if (not isinstance(image, np.ndarray) or image.dtype != np.uint8
                or image.shape != self._image_shape):
            raise ValueError(f"image must be a uint8 array of shape {self._image_shape} (the "
                             f"calibration's size), got "
                             f"{getattr(image, 'dtype', None)} {np.shape(image)}")
        velocity = np.asarray(observation["velocity"], dtype=float)
        attitude = np.asarray(observation["attitude"], dtype=float)
        if velocity.shape != (4,) or attitude.shape != (3,):
            raise ValueError(f"velocity must be (4,) and attitude (3,), got {velocity.shape} "
                             f"and {attitude.shape}")
        if not (np.isfinite(velocity).all() and np.isfinite(attitude).all()):
            raise ValueError("velocity and attitude must be finite")
        return image, velocity, attitude

    def _initialise(self, gray: np.ndarray, blobs: Blobs) -> None:
        """Label the lamps once enough are detected, alone and whole (seed 002 §2.2.1-2.2.2):
        all four of the L-shaped array, at least ``ring_init_min`` lights of a ring."""
        p = self.params
        k = len(blobs)
        need = self._n if self.identity == "l-shape" else min(p.ring_init_min, self._n)
        if not need <= k <= self._n or blobs.on_border.any():
            return
        if ((blobs.fill < MIN_FILL).any()
                or not all(self._centre_is_bright(gray, c) for c in blobs.centres)):
            return  # a lamp is partly hidden: its centre is not reliable yet
        if self.identity == "l-shape":
            order = identify_l_shape(blobs.centres, self._points)
            labels = None if order is None else np.argsort(order)
        else:
            labels = self._identify_ring(blobs.centres)
        if labels is None:
            return
        residual = self._pose.initialise(labels, blobs.centres, p.pixel_sigma)
        if not residual <= p.init_max_residual:
            return  # the labelled array does not fit the rigid layout: wait for a better frame
        # The lamps are identical (seed 002 §1.2), so radius x depth is the same for all; a
        # blob much smaller than its depth allows is a lamp partly hidden.
        depth = (self._points[labels] - self._pose.t) @ self._pose.world_to_cam[2]
        size = blobs.radii * depth
        if size.max() > 1.3 * size.min():
            return
        projected, _, _, _ = self._pose.project()
        typical_radius = float(np.median(blobs.radii))
        detected = np.full(self._n, -1)
        detected[labels] = np.arange(k)
        self._tracks = []
        for i in range(self._n):
            j = detected[i]
            if j >= 0:  # from its blob
                x0, var = [*blobs.centres[j], 0.0, 0.0, blobs.radii[j], 0.0], 1.0
            else:  # not seen: where the array puts it
                x0, var = [*projected[i], 0.0, 0.0, typical_radius, 0.0], 25.0
            p0 = np.diag([var, var, 100.0**2, 100.0**2, 1.0, 10.0**2])
            self._tracks.append(BlobEKF(x0, p0))
        self._status = np.where(detected >= 0, DETECTED, PREDICTED)
        self._frames_without_detection = 0
        self._counts["initialisations"] += 1

    def _identify_ring(self, centres: np.ndarray) -> np.ndarray | None:
        """The :func:`ring_labelings` candidate that best fits the rigid array with the
        measured attitude, if it fits (RMS <= ``init_max_residual`` px) and no other comes
        close (the runner-up must be twice as far off, and 2 px farther)."""
        centre = self._points.mean(axis=0)
        # The lights' cyclic order in the image, as seen from 5 m in front of them (DS -x).
        view, _, _, front = self._pose.project(centre - np.array([5.0, 0.0, 0.0]))
        if not front.all():
            return None  # turned away from the station: no nominal view to order them by
        rel = view - view.mean(axis=0)
        ring_order = np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))
        scored = []
        for labels in ring_labelings(centres, ring_order):
            scored.append((self._pose.fit_residual(labels, centres), labels))
        scored.sort(key=lambda item: item[0])
        best = scored[0][0]
        runner_up = scored[1][0] if len(scored) > 1 else math.inf
        if best > self.params.init_max_residual or runner_up < max(2.0 * best, best + 2.0):
            return None
        return scored[0][1]

    def _camera_displacement(self, body_rot: np.ndarray, world_velocity: np.ndarray):
        """Camera motion since the last frame: the DVL velocity (trapezoidal rule) moves the
        body, the change of INS attitude swings the camera about it."""
        prev_rot, prev_velocity = self._prev_motion
        return (0.5 * (prev_velocity + world_velocity) * self._dt
                + (body_rot - prev_rot) @ self._cam_pos_body)

    def _track(self, gray: np.ndarray, blobs: Blobs, displacement: np.ndarray) -> None:
        p = self.params
        pose = self._pose
        pose.predict(displacement, self._displacement_sigma)
        rigid, jac_t, jac_theta, front = pose.project()
        rigid_cov = pose.prediction_cov(jac_t, jac_theta) + p.rigid_sigma**2 * np.eye(2)

        # Predict each lamp, then weigh the prediction with the rigid array's (§2.2.3 2)).
        for i, track in enumerate(self._tracks):
            track.predict(*self._transition)
            if front[i]:
                track.update_position(rigid[i], rigid_cov[i])
        predicted = np.array([t.position for t in self._tracks])
        members = self._blob_members(blobs, predicted, front)

        # A lamp is seen when its centre is: a blob left by a lamp whose centre is hidden (a
        # sliver beside the fork, half a lamp at the border) has a biased circle. The test
        # point is where the rest of the array puts the centre: the array updated with every
        # other candidate blob (which absorbs this frame's INS attitude error). The lamp's own
        # blob and track are left out, as they may be the biased ones. A disc cut by a straight
        # edge keeps its centre iff more than half of it is left, which is then also its
        # circle's share: a blob cut by the image border must fill half its circle. The array
        # is then updated with the seen blobs only.
        prior = pose.snapshot()
        seen = {}
        for j, lamps in members.items():
            pose.restore(prior)
            others = [k for k in members if k != j]
            pose.update(*self._pose_measurements(blobs, members, others))
            test_points = pose.project()[0]
            lit = [i for i in lamps if self._centre_is_bright(gray, test_points[i])]
            if lit and not (len(lamps) == 1 and blobs.on_border[j] and blobs.fill[j] < MIN_FILL):
                seen[j] = lit
        pose.restore(prior)
        pose.update(*self._pose_measurements(blobs, members, seen))

        status = np.full(self._n, PREDICTED)
        rigid = pose.project()[0]
        for j, lamps in seen.items():
            if len(members[j]) == 1:
                self._update_with_blob(self._tracks[lamps[0]], blobs, j)
                status[lamps[0]] = DETECTED
            else:
                # Lamps in a merged blob are where the array, just fitted to it, puts them.
                for i in lamps:
                    self._tracks[i].update_position(rigid[i], p.pixel_sigma**2 * np.eye(2))
                status[lamps] = MERGED
        self._status = status

        if seen:
            self._frames_without_detection = 0
        else:
            self._frames_without_detection += 1
            if self._frames_without_detection >= p.lost_after:
                self._counts["track_losses"] += 1
                self._tracks = None
                self._status[:] = UNINITIALISED

    def _pose_measurements(self, blobs: Blobs, members: dict[int, list[int]],
                           used) -> tuple[list, np.ndarray, np.ndarray]:
        """Array-filter measurements from the blobs ``used`` (indices): a blob measures the
        mean projection of all its member lamps (one, or several when merged)."""
        groups, pixels, sigmas = [], [], []
        for j in used:
            lamps = members[j]
            groups.append(np.array(lamps))
            pixels.append(blobs.centres[j])
            if len(lamps) == 1:
                scale = BORDER_SIGMA_SCALE if blobs.on_border[j] else 1.0
                sigmas.append(self.params.pixel_sigma * scale)
            else:
                sigmas.append(max(blobs.radii[j] / 2.0, self.params.pixel_sigma))
        return groups, np.array(pixels).reshape(-1, 2), np.array(sigmas)

    def _blob_members(self, blobs: Blobs, predicted: np.ndarray,
                      front: np.ndarray) -> dict[int, list[int]]:
        """Which lamps each blob holds: its Hungarian match, plus the unmatched lamps predicted
        inside its circle (lamps whose images overlap form one merged blob)."""
        if not len(blobs):
            return {}
        members = {j: [i] for i, j in self._assign(blobs, front)}
        matched = {i for lamps in members.values() for i in lamps}
        margin = self.params.merge_margin
        for k in range(self._n):
            if k in matched or not front[k]:
                continue
            gap = np.linalg.norm(blobs.centres - predicted[k], axis=1) - blobs.radii
            j = int(np.argmin(gap))
            if gap[j] <= margin:
                members.setdefault(j, []).append(k)
        return members

    def _centre_is_bright(self, gray: np.ndarray, uv: np.ndarray) -> bool:
        """Whether every pixel within ``centre_halo`` px of ``uv`` is lamp-bright and inside
        the image (a lamp whose centre is near an occluder's edge is not claimed)."""
        col, row = math.floor(uv[0]), math.floor(uv[1])
        halo = self.params.centre_halo
        height, width = gray.shape
        if not (halo <= col < width - halo and halo <= row < height - halo):
            return False
        patch = gray[row - halo : row + halo + 1, col - halo : col + halo + 1]
        return bool(patch.min() >= self.segmentation.min_peak)

    def _assign(self, blobs: Blobs, front: np.ndarray) -> list[tuple[int, int]]:
        """Hungarian assignment of detections to lamps on the gated Mahalanobis cost."""
        p = self.params
        n, m = self._n, len(blobs)
        cost = np.full((n, m), np.inf)
        for i, track in enumerate(self._tracks):
            if not front[i]:
                continue
            diff = blobs.centres - track.position
            S = track.position_cov + p.pixel_sigma**2 * np.eye(2)
            maha = np.einsum("ij,ij->i", diff @ np.linalg.inv(S), diff)
            dist = np.linalg.norm(diff, axis=1)
            ok = (maha <= p.gate_chi2) & (dist <= p.gate_px)
            cost[i, ok] = maha[ok]
        valid = np.isfinite(cost)
        if not valid.any():
            return []
        # A gated-out pair costs more than any full set of valid pairs (FACTS.md: no inf).
        big = p.gate_chi2 * (min(n, m) + 1) + 1.0
        rows, cols = linear_sum_assignment(np.where(valid, cost, big))
        return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if valid[i, j]]

    def _update_with_blob(self, track: BlobEKF, blobs: Blobs, j: int) -> None:
        p = self.params
        s = max(track.x[4], 0.5)
        _, _, w, h = blobs.boxes[j]
        z = np.array([blobs.centres[j, 0], blobs.centres[j, 1], blobs.areas[j], w, h], float)
        sigma_edge = 1.0
        R = np.diag([p.pixel_sigma**2, p.pixel_sigma**2,
                     (2.0 * math.pi * s * sigma_edge + 2.0) ** 2, 1.5**2, 1.5**2])
        if blobs.on_border[j]:
            # A blob cut by the image border: its size says nothing, its centre little.
            R[:2, :2] *= BORDER_SIGMA_SCALE**2
            track.update(z, R, rows=[0, 1])
        else:
            track.update(z, R)

    def _count(self) -> None:
        c = self._counts
        c["frames"] += 1
        if self._tracks is not None:
            c["detected"] += int(np.sum(self._status == DETECTED))
            c["merged"] += int(np.sum(self._status == MERGED))
            c["predicted"] += int(np.sum(self._status == PREDICTED))

    def _features(self, velocity: np.ndarray, attitude: np.ndarray) -> dict:
        pixels = np.zeros((self._n, 2), dtype=np.float32)
        visible = np.zeros(self._n, dtype=np.int8)
        if self._tracks is not None:
            reported = (self._status == DETECTED) | (self._status == MERGED)
            for i in np.flatnonzero(reported):
                pixels[i] = self._tracks[i].position
            visible[reported] = 1
            np.clip(pixels, *self._pixel_bounds, out=pixels)
        return {
            "pixels": pixels,
            "visible": visible,
            "velocity": velocity.astype(np.float32),
            "attitude": attitude.astype(np.float32),
        }


__all__ = [
    "DETECTED",
    "MERGED",
    "PREDICTED",
    "STATUS_NAMES",
    "UNINITIALISED",
    "BlobEKF",
    "Blobs",
    "CameraPositionFilter",
    "LampArrayFrontEnd",
    "LampTracks",
    "SegmentationParams",
    "TrackerParams",
    "identify_l_shape",
    "ring_labelings",
    "segment_lamps",
]
