"""Long-term anti-interference tracking (LTAT) of the AUV's marker, and its corners (seed 000 §2.1).

Seed 000, §2.1.2: a Siamese tracker follows the target; a detector that
learns *online* -- trained during the episode on the tracker's confident
outputs -- finds the target again when the tracker's score drops below an
empirical threshold, and its best region above its own threshold re-seeds the
tracker's template and position. The paper's detector is a YOLOv5 trained
online; ours is a linear classifier (scikit-learn ``RidgeClassifier``) on
feature windows of the whole frame, embedded by the tracker's own network at
the target's scale (a discriminative window classifier in the manner of
online-learned correlation trackers).

The parts, each with one role:

* :class:`MarkerCornerExtractor`: the three marker corners inside a box
  (OpenCV colour threshold, contour, the largest triangle inscribed in its
  convex hull; sub-pixel by intersecting lines fitted to the edges near
  each corner), labelled A1 (port base), A2 (starboard base), A3 (apex).
* :func:`stereo_check`: corners of the two views matched by label and
  checked against the rectified geometry (same rows, positive disparity)
  and the marker's known size (triangulated sides, seed 000 eq. 2).
* :class:`OnlineDetector`: the online-learned detector.
* :class:`LTATracker`: the Siamese tracker of both views plus the detector
  and the re-seeding logic.
* :class:`LTATFrontEnd`: stereo images -> the ``features`` observation of
  ``auv_envs/LARSCapture-v0`` (protocol of :mod:`baselines.frontend`).

**First box, without truth.** Until the marker has been found, every frame
is searched for it by colour in both whole images: each red blob with a
triangular outline is a candidate, candidates of the two views are paired
along the rectified rows, and the pair whose triangulated side lengths match
``calibration.marker_sides`` best (within ``size_tolerance``) is the AUV's
marker -- the look-alike analogs carry a 0.8x marker and fail the check. The
tracker starts on that pair's corner boxes.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import itertools
import math
import time

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from sklearn.linear_model import RidgeClassifier
from threadpoolctl import ThreadpoolController

from auv_envs.core.stereo import StereoRig, triangulate
from baselines.lars.siamese import (
    CHANNELS,
    STRIDE,
    TEMPLATE_SIZE,
    Pyramid,
    SiameseNet,
    SiameseTracker,
    TrackerParams,
    box_centre_size,
    box_from_centre,
    context_size,
    load_siamese,
    marker_box,
    to_tensor,
)


# ---------------------------------------------------------------------- corners
@dataclasses.dataclass(frozen=True)
class CornerParams:
    """Colour and shape limits of the painted marker.

    Attributes:
        hue: red hues are ``<= hue`` or ``>= 180 - hue`` (OpenCV's 0..180 scale).
        saturation, value: minimum S and V (0..255).
        min_area: smallest blob, px^2.
        pad: the search region is the box grown by this fraction per side.
        apex_angle: (min, max) of the apex angle, degrees (the 0.15/0.4/0.4
            triangle has 21.6 deg seen from above).
        base_angle_min: the two base angles must exceed this, degrees.
        fill_ratio: (min, max) of the blob's area over its largest inscribed
            triangle's (the base arc adds a little).
        edge_trim: fraction of a leg next to the apex left out of its line fit.
        edge_offset: how far (px) the painted edge lies outside the centres
            of the outermost mask pixels.
    """

    hue: int = 12
    saturation: int = 110
    value: int = 60
    min_area: float = 80.0
    pad: float = 0.25
    apex_angle: tuple[float, float] = (8.0, 50.0)
    base_angle_min: float = 50.0
    fill_ratio: tuple[float, float] = (0.9, 1.15)
    edge_trim: float = 0.08
    edge_offset: float = 0.0


def _line_intersection(p, d, q, e) -> np.ndarray | None:
    """Intersection of lines ``p + s d`` and ``q + t e`` (None when parallel)."""
    den = d[0] * e[1] - d[1] * e[0]
    if abs(den) < 1e-9:
        return None
    s = ((q[0] - p[0]) * e[1] - (q[1] - p[1]) * e[0]) / den
    return p + s * d


class MarkerCornerExtractor:
    """Marker corners A1, A2, A3 of the red isosceles triangle inside a region."""

    def __init__(self, params: CornerParams | None = None):
        self.params = params or CornerParams()

    def red_mask(self, image: np.ndarray) -> np.ndarray:
        p = self.params
        hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
        low = cv2.inRange(hsv, (0, p.saturation, p.value), (p.hue, 255, 255))
        high = cv2.inRange(hsv, (180 - p.hue, p.saturation, p.value), (180, 255, 255))
        return cv2.bitwise_or(low, high)

    def candidates(self, image: np.ndarray, box=None, pad: float | None = None
                   ) -> list[np.ndarray]:
        """All triangles (3, 2) found in ``image`` (inside ``box`` grown by ``pad`` per
        side, default ``params.pad``, if given), largest blob first.

        A blob that touches the edge of the search region inside the image
        is cut by the region, not a whole triangle, and is skipped.
        """
        h, w = image.shape[:2]
        x0, y0, x1, y1 = 0, 0, w, h
        roi = image
        if box is not None:
            pad = self.params.pad if pad is None else pad
            cx, cy, bw, bh = box_centre_size(box)
            gw, gh = bw * (0.5 + pad), bh * (0.5 + pad)
            x0, y0 = max(0, int(cx - gw)), max(0, int(cy - gh))
            x1, y1 = min(w, int(math.ceil(cx + gw))), min(h, int(math.ceil(cy + gh)))
            if x1 - x0 < 4 or y1 - y0 < 4:
                return []
            roi = image[y0:y1, x0:x1]
        out = []
        for contour in self.red_blobs(roi):
            bx, by, bw, bh = cv2.boundingRect(contour)
            if ((bx == 0 < x0) or (by == 0 < y0) or (bx + bw == x1 - x0 and x1 < w)
                    or (by + bh == y1 - y0 and y1 < h)):
                continue
            corners = self.fit_triangle(contour.reshape(-1, 2).astype(float))
            if corners is not None:
                # OpenCV pixel indices -> continuous coordinates (centres at +0.5).
                out.append(corners + (x0 + 0.5, y0 + 0.5))
        return out

    def red_blobs(self, roi: np.ndarray) -> list[np.ndarray]:
        """Outer contours of the red mask of ``roi`` of at least ``params.min_area``,
        largest first (ties in the order OpenCV found them)."""
        contours, _ = cv2.findContours(self.red_mask(roi), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_NONE)
        contours = [c for c in contours if cv2.contourArea(c) >= self.params.min_area]
        contours.sort(key=cv2.contourArea, reverse=True)
        return contours

    def find(self, image: np.ndarray, box, pad: float | None = None) -> np.ndarray | None:
        """Corners (3, 2) of the largest triangle in ``box`` (grown by ``pad``), or None."""
        found = self.candidates(image, box, pad)
        return found[0] if found else None

    def fit_triangle(self, points: np.ndarray) -> np.ndarray | None:
        """Labelled corners (A1, A2, A3) of a triangular contour, or None if it is not one."""
        p = self.params
        approx = self._largest_inscribed_triangle(points)
        if approx is None:
            return None
        (ux, uy), (vx, vy) = approx[1] - approx[0], approx[2] - approx[0]
        area = 0.5 * abs(ux * vy - uy * vx)
        if not (p.fill_ratio[0] <= cv2.contourArea(points.astype(np.float32)) / area
                <= p.fill_ratio[1]):
            return None
        angles = np.array([self._angle(approx, k) for k in range(3)])
        apex = int(np.argmin(angles))
        others = [k for k in range(3) if k != apex]
        if not (p.apex_angle[0] <= angles[apex] <= p.apex_angle[1]):
            return None
        if min(angles[others]) < p.base_angle_min:
            return None
        refined = self._refine(points, approx[apex], approx[others[0]], approx[others[1]])
        if refined is None:
            return None
        a3, b1, b2 = refined
        # Port (A1) lies to the left of the apex direction seen from above; the
        # downward camera's image is the map view (u ~ x, v ~ -y), so "left"
        # of direction (du, dv) is (dv, -du) in pixels.
        mid = 0.5 * (b1 + b2)
        axis = a3 - mid
        left = np.array([axis[1], -axis[0]])
        a1, a2 = (b1, b2) if (b1 - mid) @ left > 0 else (b2, b1)
        return np.array([a1, a2, a3])

    @staticmethod
    def _largest_inscribed_triangle(points: np.ndarray) -> np.ndarray | None:
        """Vertices (3, 2) of the largest triangle on the contour's convex hull.

        On a triangle whose base bulges (an arc), these are the three corners,
        where a polygon approximation may cut a corner off. Searched over a
        simplified hull (a few dozen vertices), all triples at once.
        """
        hull = cv2.convexHull(points.astype(np.float32))
        hull = cv2.approxPolyDP(hull, 0.004 * cv2.arcLength(hull, True), True).reshape(-1, 2)
        n = len(hull)
        if n < 3:
            return None
        i, j, k = np.array(list(itertools.combinations(range(n), 3))).T
        a, b, c = hull[i].astype(float), hull[j].astype(float), hull[k].astype(float)
        area = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                      - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
        best = int(np.argmax(area))
        return np.array([a[best], b[best], c[best]])

    @staticmethod
    def _angle(poly: np.ndarray, k: int) -> float:
        a, b, c = poly[k], poly[(k + 1) % 3], poly[(k - 1) % 3]
        u, v = b - a, c - a
        cos = u @ v / (np.linalg.norm(u) * np.linalg.norm(v) + 1e-12)
        return math.degrees(math.acos(max(-1.0, min(1.0, cos))))

    @staticmethod
    def _side_points(points, a, b, t_range, tol) -> np.ndarray:
        """Contour points within ``tol`` px of segment ``a -> b``, at fractions ``t_range``."""
        d = b - a
        t = (points - a) @ d / (d @ d)
        dist = np.linalg.norm(points - (a + t[:, None] * d), axis=1)
        return points[(t > t_range[0]) & (t < t_range[1]) & (dist < tol)]

    def _fit(self, pts: np.ndarray, inside: np.ndarray):
        """Line (point, direction) through ``pts``, moved ``edge_offset`` px away from ``inside``.

        Contour points are the centres of the outermost mask pixels, a
        fraction of a pixel inside the painted edge.
        """
        if len(pts) < 3:
            return None
        vx, vy, x0, y0 = cv2.fitLine(pts.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
        d = np.array([vx, vy], dtype=float)
        p = np.array([x0, y0], dtype=float)
        normal = np.array([-d[1], d[0]])
        if (inside - p) @ normal > 0:
            normal = -normal
        return p + self.params.edge_offset * normal, d

    def _corner_fits(self, points, apex, base1, base2, slack: float = 0.0) -> list:
        """Sub-pixel corners ``[apex, base1, base2]`` as intersections of local edge lines
        (None where a fit lacks points).

        The legs are curves on the hull (the painted patch narrows around
        the cylinder) and the base is an arc, so each corner is where the
        tangent lines of its two edges *near that corner* meet: A3 from the
        apex halves of the legs, A1/A2 from the base end of the leg and the
        nearest part of the base. ``slack`` (px) widens the point selection
        around the given polygon.
        """
        p = self.params
        centroid = (apex + base1 + base2) / 3.0
        trim = p.edge_trim
        legs = [self._fit(self._side_points(points, apex, b, (trim, 0.5), 2.5 + slack), centroid)
                for b in (base1, base2)]
        corners = [None if legs[0] is None or legs[1] is None
                   else _line_intersection(*legs[0], *legs[1])]
        for base, other in ((base1, base2), (base2, base1)):
            leg = self._fit(self._side_points(points, apex, base, (0.7, 1 - trim), 3.0 + slack),
                            centroid)
            tol = max(3.0, 0.15 * float(np.linalg.norm(other - base))) + slack
            end = self._fit(self._side_points(points, base, other, (trim, 0.2), tol), centroid)
            corners.append(None if leg is None or end is None else _line_intersection(*leg, *end))
        return corners

    def _refine(self, points, apex, base1, base2):
        """All three corners refined (:meth:`_corner_fits`), or None."""
        corners = self._corner_fits(points, apex, base1, base2)
        if any(c is None for c in corners):
            return None
        refined = np.array(corners)
        # A refinement that moved a corner far from the polygon is a bad fit.
        scale = np.linalg.norm(apex - 0.5 * (base1 + base2))
        if np.linalg.norm(refined - np.array([apex, base1, base2]), axis=1).max() > 0.15 * scale:
            return None
        return refined

    def find_partial(self, image: np.ndarray, predicted: np.ndarray, margin: float = 8.0,
                     max_shift: float = 6.0) -> np.ndarray | None:
        """Corners of a marker cut by the image border, near ``predicted`` (3, 2) A1-A3.

        ``predicted`` comes from the other view (the same rows, shifted by the
        disparity). Each predicted corner at least ``margin`` px inside the
        image is refined from the red blob's edges near it and kept if it
        moved at most ``max_shift`` px. Returns (3, 2) with NaN rows for the
        corners not found, or None if none was.
        """
        h, w = image.shape[:2]
        pred = np.asarray(predicted, dtype=float)
        inside = ((pred[:, 0] >= margin) & (pred[:, 0] < w - margin)
                  & (pred[:, 1] >= margin) & (pred[:, 1] < h - margin))
        if not inside.any():
            return None
        pad = self.params.pad * float(np.ptp(pred, axis=0).max())
        x0, y0 = (max(0, int(v - pad)) for v in pred.min(axis=0))
        x1 = min(w, int(math.ceil(pred[:, 0].max() + pad)))
        y1 = min(h, int(math.ceil(pred[:, 1].max() + pad)))
        if x1 - x0 < 4 or y1 - y0 < 4:
            return None
        blobs = self.red_blobs(image[y0:y1, x0:x1])
        if not blobs:
            return None
        contour = blobs[0]
        offset = np.array([x0 + 0.5, y0 + 0.5])
        local = pred - offset
        fits = self._corner_fits(contour.reshape(-1, 2).astype(float), local[2], local[0],
                                 local[1], slack=2.0)
        out = np.full((3, 2), np.nan)
        for k, fit in zip((2, 0, 1), fits, strict=True):
            if inside[k] and fit is not None and np.linalg.norm(fit - local[k]) <= max_shift:
                out[k] = fit + offset
        return out if np.isfinite(out).any() else None


def stereo_check(
    left: np.ndarray | None, right: np.ndarray | None, rig: StereoRig, sides,
    row_tolerance: float = 3.0, size_tolerance: float = 0.12,
) -> str:
    """Whether the labelled corners of the two views are one marker of the known size.

    Checks the rectified geometry (each corner on the same row in both views,
    positive disparity) and the sides of the triangulated triangle (seed 000
    eq. 2) against ``sides`` = (|A1A2|, |A1A3|, |A2A3|) within a relative
    ``size_tolerance``.

    Returns:
        ``"ok"``, or why not: ``"missing"`` (a view has no corners), ``"rows"``,
        ``"disparity"``, ``"size"`` (a consistent triangle of another size:
        a look-alike).
    """
    if left is None or right is None:
        return "missing"
    rectified = rectified_check(left, right, rig, row_tolerance)
    if rectified != "ok":
        return rectified
    if marker_size_error(left, right, rig, sides) > size_tolerance:
        return "size"
    return "ok"


def rectified_check(left: np.ndarray, right: np.ndarray, rig: StereoRig,
                    row_tolerance: float = 3.0) -> str:
    """Whether matched points (N, 2) of the two views fit the rectified pair.

    Returns:
        ``"ok"``, ``"rows"`` (a pair more than ``row_tolerance`` px apart
        vertically) or ``"disparity"`` (a pair with a non-positive disparity).
    """
    if np.abs(left[:, 1] - right[:, 1]).max() > row_tolerance:
        return "rows"
    if rig.disparity(left[:, 0], right[:, 0]).min() <= 0.0:
        return "disparity"
    return "ok"


def marker_side_ratios(left: np.ndarray, right: np.ndarray, rig: StereoRig, sides) -> np.ndarray:
    """Triangulated sides (|A1A2|, |A1A3|, |A2A3|) over ``sides`` (seed 000 eq. 2)."""
    pts = triangulate(rig, left, right)
    measured = np.array([np.linalg.norm(pts[0] - pts[1]), np.linalg.norm(pts[0] - pts[2]),
                         np.linalg.norm(pts[1] - pts[2])])
    return measured / np.asarray(sides)


def marker_size_error(left: np.ndarray, right: np.ndarray, rig: StereoRig, sides) -> float:
    """Largest relative error of the triangulated sides against ``sides`` (rows must match)."""
    return float(np.abs(marker_side_ratios(left, right, rig, sides) - 1.0).max())


def match_stereo(left, right, rig: StereoRig, sides, row_tolerance: float = 3.0,
                 size_tolerance: float = 0.12) -> bool:
    """``stereo_check(...) == "ok"``."""
    return stereo_check(left, right, rig, sides, row_tolerance, size_tolerance) == "ok"


# ---------------------------------------------------------------------- detector
@dataclasses.dataclass(frozen=True)
class DetectorParams:
    """Online detector settings.

    Attributes:
        threshold: a detection needs a classifier score at least this
            (targets are +1 / -1; the seed's "empirical threshold"; set low
            because every detection is verified before it re-seeds the
            tracker, see :class:`LTATracker`).
        alpha: ridge regularisation.
        candidates: windows per frame tried, best first.
        max_positives, max_negatives: sample buffers (oldest dropped first).
        random_negatives, hard_negatives: negatives added per confident view
            (random background windows, and the windows the current
            classifier scores highest: distractors).
        negative_distance: windows farther than this (cells) from the target
            are negatives.
        fit_every: refit after this many positives (two per sampled frame).
        min_positives: no detection before this many positives.
    """

    threshold: float = -0.5
    alpha: float = 10.0
    candidates: int = 5
    max_positives: int = 60
    max_negatives: int = 300
    random_negatives: int = 6
    hard_negatives: int = 4
    negative_distance: float = 2.0
    fit_every: int = 6
    min_positives: int = 6


@dataclasses.dataclass
class _FrameFeatures:
    """Window descriptors of one frame at one scale."""

    descriptors: np.ndarray  # (N, D) L2-normalised
    centres: np.ndarray  # (N, 2) image pixels
    cell: float  # image pixels per feature cell

    def window_on(self, box, reach: float = 0.75) -> tuple[int | None, np.ndarray]:
        """The window on ``box``'s centre and every window's distance to it (cells).

        The index is None when no window centre lies within ``reach`` cells
        (or the frame has no window).
        """
        if len(self.descriptors) == 0:
            return None, np.zeros(0)
        cx, cy, _, _ = box_centre_size(box)
        dist = np.hypot(self.centres[:, 0] - cx, self.centres[:, 1] - cy) / self.cell
        nearest = int(np.argmin(dist))
        return (None if dist[nearest] > reach else nearest), dist


@functools.cache
def _thread_pools() -> ThreadpoolController:
    """The process's BLAS/OpenMP thread pools, found once.

    ``threadpool_limits`` scans the loaded libraries on every call (about
    13 ms here, more than the ridge solve); the controller scans them at its
    first use, by which time numpy, scipy, scikit-learn and torch are loaded.
    """
    return ThreadpoolController()


class OnlineDetector:
    """A window classifier learnt during the episode (seed 000 §2.1.2's online detector).

    The frame is embedded by the Siamese network at the target's scale
    (``TEMPLATE_SIZE / s_z`` of the last confident box), every 8 x 8 window
    of the feature map (a template-sized region) is pooled to a 4 x 4 x C
    descriptor, and a ridge classifier (scikit-learn) separates the windows
    on the tracker's confident boxes (positives) from background and
    distractor windows (negatives; the highest-scoring ones are kept as
    hard negatives). ``detect`` returns the best window over the whole frame.
    """

    def __init__(self, net: SiameseNet, rng: np.random.Generator,
                 params: DetectorParams | None = None):
        self.net = net
        self.rng = rng
        self.params = params or DetectorParams()
        p = self.params
        self.positives: collections.deque = collections.deque(maxlen=p.max_positives)
        self.negatives: collections.deque = collections.deque(maxlen=p.max_negatives)
        self.classifier: RidgeClassifier | None = None
        self.fits = 0
        self._since_fit = 0

    @property
    def ready(self) -> bool:
        return self.classifier is not None

    @torch.no_grad()
    def features(self, pyramids, box) -> list[_FrameFeatures]:
        """Window descriptors of whole frames (one per pyramid, same size) at the scale of
        ``box`` (one forward pass)."""
        _, _, w, h = box_centre_size(box)
        scale = TEMPLATE_SIZE / context_size(w, h)
        half = TEMPLATE_SIZE // 2
        # Padded by half a window (the image's mean colour, as the tracker's
        # crops are) so that a window can centre on a target at the border.
        images = [cv2.copyMakeBorder(pyr.resized(scale), half, half, half, half,
                                     cv2.BORDER_CONSTANT, value=pyr.fill) for pyr in pyramids]
        win = TEMPLATE_SIZE // STRIDE  # 8 cells
        height, width = images[0].shape[:2]
        rows = math.ceil(height / STRIDE) - (win - 1)
        cols = math.ceil(width / STRIDE) - (win - 1)
        if rows <= 0 or cols <= 0:  # the frame is smaller than one window
            empty = _FrameFeatures(np.zeros((0, CHANNELS[-1] * (win // 2) ** 2)),
                                   np.zeros((0, 2)), 1.0)
            return [empty for _ in pyramids]
        fmap = self.net.embed(to_tensor(images))
        pooled = F.avg_pool2d(fmap, 2, stride=1)
        # Window (y, x) covers feature cells y..y+7: a 4 x 4 grid of 2 x 2 means.
        desc = F.unfold(pooled, kernel_size=win // 2, dilation=2).transpose(1, 2).numpy()
        desc = desc / (np.linalg.norm(desc, axis=2, keepdims=True) + 1e-9)
        sx = pyramids[0].size[0] / (width - 2 * half)
        sy = pyramids[0].size[1] / (height - 2 * half)
        gy, gx = np.mgrid[0:rows, 0:cols]
        # Window (y, x) spans padded pixels [8x, 8x + 64): centre 8x + 32, i.e.
        # 8x in the unpadded resized image.
        centres = np.stack([STRIDE * gx * sx, STRIDE * gy * sy], axis=-1).reshape(-1, 2)
        return [_FrameFeatures(d, centres, STRIDE * sx) for d in desc]

    def scores(self, feats: _FrameFeatures) -> np.ndarray:
        if self.classifier is None or len(feats.descriptors) == 0:
            return np.full(len(feats.descriptors), -np.inf)
        return self.classifier.decision_function(feats.descriptors)

    def add_samples(self, feats: _FrameFeatures, box) -> bool:
        """Learn from one confident box: the window on it is a positive, far windows negatives.

        Returns whether a positive was added (the box centre must fall within
        0.75 of a cell of a window centre).
        """
        nearest, dist = feats.window_on(box)
        if nearest is None:
            return False
        p = self.params
        self.positives.append(feats.descriptors[nearest])
        far = np.flatnonzero(dist > p.negative_distance)
        if len(far):
            picks = list(self.rng.choice(far, size=min(p.random_negatives, len(far)),
                                         replace=False))
            if self.classifier is not None and p.hard_negatives:
                s = self.scores(feats)[far]
                picks += list(far[np.argsort(s)[-p.hard_negatives:]])
            self.negatives.extend(feats.descriptors[i] for i in set(picks))
        self._since_fit += 1
        if len(self.positives) >= p.min_positives and self._since_fit >= p.fit_every:
            self.fit()
        return True

    def add_negative(self, feats: _FrameFeatures, box) -> bool:
        """A box known to hold a distractor: its window becomes a negative; refit at once."""
        nearest, _ = feats.window_on(box)
        if nearest is None:
            return False
        self.negatives.append(feats.descriptors[nearest])
        if len(self.positives) >= self.params.min_positives:
            self.fit()
        return True

    def fit(self) -> None:
        x = np.concatenate([np.array(self.positives), np.array(self.negatives)])
        y = np.r_[np.ones(len(self.positives)), -np.ones(len(self.negatives))]
        clf = RidgeClassifier(alpha=self.params.alpha, class_weight="balanced")
        # A few hundred samples: one BLAS thread. Several threads on a busy
        # 2-core machine made this solve 20x slower (measured).
        with _thread_pools().limit(limits=1):
            self.classifier = clf.fit(x, y)
        self.fits += 1
        self._since_fit = 0

    def detect(self, feats: _FrameFeatures, count: int = 1) -> list[tuple[np.ndarray, float]]:
        """The best ``count`` windows above the threshold: ``(centre (2,), score)``, best
        first; empty before the first fit."""
        s = self.scores(feats)
        if len(s) == 0 or not self.ready:
            return []
        order = np.argsort(s)[::-1][:count]
        return [(feats.centres[i].copy(), float(s[i])) for i in order
                if s[i] >= self.params.threshold]


# ---------------------------------------------------------------------- LTAT
@dataclasses.dataclass(frozen=True)
class LTATParams:
    """Thresholds of the long-term logic (seed 000 §2.1.2's "empirical thresholds").

    Attributes:
        lost_score: a view whose tracker score falls below this has lost the target.
        confident_score: above this in both views, with corners that pass the
            stereo check, a frame trains the detector and the templates.
        sample_every: confident frames between template updates and detector samples.
        row_tolerance: px; corners of the two views on the same row.
        size_tolerance: relative error allowed on the triangulated marker sides.
        lookalike_frames, lookalike_spread: a tracked triangle is a look-alike
            when it has had the wrong size in this many consecutive frames,
            with its mean side ratio varying by less than the spread. (A
            crest sweeping over the marker leaves a truncated triangle whose
            size changes from frame to frame; a look-alike's does not.)
        snap_to_corners: when the corners are verified, the output box (and
            the tracker's) becomes the corners' box: the verified marker
            corrects the tracker's drift in position and size.
        verify_pad: a detection's corners are searched in its box grown by
            this fraction per side.
        partial_corners: when one view sees the whole marker and the other
            only part of it (cut by the image border), report the corners
            seen in both (:meth:`LTATracker._partial`).
    """

    lost_score: float = 0.35
    confident_score: float = 0.7
    sample_every: int = 3
    row_tolerance: float = 3.0
    size_tolerance: float = 0.12
    lookalike_frames: int = 6
    lookalike_spread: float = 0.04
    snap_to_corners: bool = True
    verify_pad: float = 0.5
    partial_corners: bool = True


@dataclasses.dataclass
class LTATOutput:
    """One stereo frame of LTAT.

    Attributes:
        boxes: (2, 4) marker boxes (left, right), x_min, y_min, x_max, y_max.
        scores: (2,) the Siamese tracker's scores (NaN on a frame where a
            verified detection re-seeded the tracker).
        lost: (2,) whether each view has lost the target this frame.
        corners: (2, 3, 2) A1, A2, A3 in both views, NaN for a corner not
            seen in both; None when none passed the stereo check.
        visible: (2, 3) which corners are given.
    """

    boxes: np.ndarray
    scores: np.ndarray
    lost: np.ndarray
    corners: np.ndarray | None
    visible: np.ndarray


class LTATracker:
    """Siamese tracker of both views + online detector + corner extraction (seed 000 §2.1.2).

    Per frame:

    1. The Siamese tracker moves both boxes (one batched forward pass).
    2. A view whose score is below ``lost_score`` has lost the target. If the
       other view still has it, the lost view is re-seeded from it along the
       rectified row at the last verified disparity (and kept if its score
       then clears ``lost_score``). If both lost it, the online detector
       searches the whole frame; its best windows above its threshold are
       verified in turn (corners in both views, :func:`stereo_check`) and
       the first verified one re-seeds the tracker: position, and the
       templates stored at the last confident frame. Otherwise the boxes
       hold their last position (no drifting onto the background) and the
       next frame tries again.
    3. The marker corners are extracted inside both boxes and checked by
       :func:`stereo_check`. A whole, row-consistent triangle of a wrong but
       steady size over ``lookalike_frames`` frames means the tracker sits
       on a look-alike: its windows become
       negatives of the detector (refitted at once), which then searches
       the whole frames for the target.
    4. A confident frame (both scores >= ``confident_score``, corners
       verified) adds the boxes as positives (and far windows as negatives)
       to the detector and updates the stored templates.
    """

    def __init__(self, net: SiameseNet, rig: StereoRig, marker_sides,
                 tracker_params: TrackerParams | None = None,
                 detector_params: DetectorParams | None = None,
                 corner_params: CornerParams | None = None,
                 params: LTATParams | None = None):
        self.net = net
        self.rig = rig
        self.marker_sides = tuple(float(s) for s in marker_sides)
        self.params = params or LTATParams()
        self._tracker_params = tracker_params or TrackerParams()
        self._detector_params = detector_params
        self.extractor = MarkerCornerExtractor(corner_params)
        self.reset(np.random.default_rng())

    def reset(self, rng: np.random.Generator) -> None:
        """Forget the episode (templates, detector samples, counters)."""
        self.tracker = SiameseTracker(self.net, self._tracker_params)
        self.detector = OnlineDetector(self.net, rng, self._detector_params)
        self.anchors: list = [None, None]
        self.sizes: list = [None, None]
        self.disparity: float | None = None
        self.started = False
        self._confident = 0
        self._wrong_size: collections.deque = collections.deque(
            maxlen=self.params.lookalike_frames)
        self.counts = collections.Counter()

    def start(self, pyramids, boxes) -> None:
        """Begin tracking the marker boxes (2, 4) of both views."""
        self.tracker.init(pyramids, boxes)
        for v in range(2):
            self.anchors[v] = self.tracker.template_of(v)
            self.sizes[v] = box_centre_size(boxes[v])[2:]
        l_cx, l_cy = box_centre_size(boxes[0])[:2]
        r_cx = box_centre_size(boxes[1])[0]
        self.disparity = l_cx - r_cx
        self.started = True

    def step(self, pyramids, images) -> LTATOutput:
        if not self.started:
            raise RuntimeError("LTATracker.step() before start()")
        p = self.params
        before = [self.tracker.box(v) for v in range(2)]
        boxes, scores = self.tracker.track(pyramids, update=False)
        lost = scores < p.lost_score
        if lost.all():
            self._redetect(pyramids, images, boxes, scores, lost)
        elif lost.any():
            v = int(np.flatnonzero(lost)[0])
            self._transfer(v, pyramids, boxes, scores, lost)
        for v in np.flatnonzero(lost):
            self.tracker.set_box(v, before[v])
            boxes[v] = before[v]
        self.counts["frames"] += 1
        self.counts["lost_views"] += int(lost.sum())

        corners = None
        if not lost.any():
            found = [self.extractor.find(images[v], boxes[v]) for v in range(2)]
            check = stereo_check(found[0], found[1], self.rig, self.marker_sides,
                                 p.row_tolerance, p.size_tolerance)
            if check == "ok":
                corners = np.stack(found)
                self.counts["verified"] += 1
                if p.snap_to_corners:
                    for v in range(2):
                        boxes[v] = marker_box(corners[v])
                        self.tracker.set_box(v, boxes[v])
                if scores.min() >= p.confident_score:
                    self._learn(pyramids, boxes, corners)
            elif check == "missing" and p.partial_corners:
                corners = self._partial(images, found)
            if check == "size":
                self._wrong_size.append(float(np.mean(
                    marker_side_ratios(found[0], found[1], self.rig, self.marker_sides))))
            else:
                self._wrong_size.clear()
            history = self._wrong_size
            if (len(history) == p.lookalike_frames
                    and max(history) - min(history) < p.lookalike_spread):
                # A steady, whole, row-consistent triangle of the wrong size: the
                # tracker is on a look-alike. Teach the detector so and search again.
                self.counts["analog_rejections"] += 1
                history.clear()
                self._reject(pyramids, images, boxes, scores)
        else:
            self._wrong_size.clear()
        visible = np.zeros((2, 3), dtype=bool) if corners is None else np.isfinite(corners[..., 0])
        return LTATOutput(boxes, scores, lost, corners, visible)

    def _partial(self, images, found) -> np.ndarray | None:
        """Corners of a marker that one view sees whole and the other cut by its border.

        The cut view's corners are searched near the whole view's, moved by
        the last verified disparity along the rows
        (:meth:`MarkerCornerExtractor.find_partial`); those found must sit on
        the same rows with a positive disparity, and with both base corners
        the triangulated base must have the marker's length. Returns (2, 3, 2)
        with NaN for the corners not seen in both views, or None.
        """
        if (found[0] is None) == (found[1] is None) or self.disparity is None:
            return None
        p = self.params
        whole = 0 if found[0] is not None else 1
        cut = 1 - whole
        shift = -self.disparity if cut == 1 else self.disparity
        partial = self.extractor.find_partial(images[cut], found[whole] + (shift, 0.0))
        if partial is None:
            return None
        corners = np.full((2, 3, 2), np.nan)
        corners[whole], corners[cut] = found[whole], partial
        seen = np.isfinite(partial[:, 0])
        left, right = corners[0, seen], corners[1, seen]
        if rectified_check(left, right, self.rig, p.row_tolerance) != "ok":
            return None
        if seen[0] and seen[1]:
            ends = triangulate(self.rig, left[:2], right[:2])
            base = float(np.linalg.norm(ends[0] - ends[1]))
            if abs(base / self.marker_sides[0] - 1.0) > p.size_tolerance:
                return None
        corners[:, ~seen] = np.nan
        # Follow the depth while the marker stays cut (the next prediction).
        self.disparity = float(np.mean(left[:, 0] - right[:, 0]))
        self.counts["partial"] += 1
        return corners

    def _reject(self, pyramids, images, boxes, scores) -> None:
        """The tracked boxes are a distractor: negatives for the detector, then re-detect.

        If the detector finds nothing better the boxes stay (no corners are
        reported from them) and the next frame checks again.
        """
        lost = np.ones(2, dtype=bool)
        for v, feats in enumerate(self.detector.features(pyramids, boxes[0])):
            self.detector.add_negative(feats, boxes[v])
        self._redetect(pyramids, images, boxes, scores, lost)

    def _retrack(self, v, pyramids, box, boxes, scores, lost) -> None:
        """Re-seed view ``v`` at ``box`` with its stored template and track it on this frame."""
        self.tracker.reseed(v, pyramids[v], box, template=self.anchors[v])
        b, s = self.tracker.track(pyramids, views=[v], update=False)
        if s[v] >= self.params.lost_score:
            boxes[v], scores[v], lost[v] = b[v], s[v], False

    def _transfer(self, v, pyramids, boxes, scores, lost) -> None:
        """Re-seed lost view ``v`` from the other view along the rectified row."""
        if self.disparity is None:
            return
        cx, cy, _, _ = box_centre_size(boxes[1 - v])
        shift = -self.disparity if v == 1 else self.disparity
        w, h = self.sizes[v]
        self._retrack(v, pyramids, box_from_centre(cx + shift, cy, w, h), boxes, scores, lost)
        self.counts["transfers"] += int(not lost[v])

    def _redetect(self, pyramids, images, boxes, scores, lost) -> None:
        """Search the whole left frame with the online detector; re-seed on a verified hit.

        The detector's best windows (``candidates``, best first, above its
        threshold) are tried in turn: the right view's box is the left one
        moved by the last verified disparity along the rectified row, the
        corners are extracted in both, and the first candidate that passes
        :func:`stereo_check` re-seeds both views (their corner boxes, the
        templates stored at the last confident frame). A candidate of the
        wrong size is skipped, not learnt as a negative: a crest sweeping
        over the marker also leaves smaller (truncated) triangles.
        """
        if not self.detector.ready or self.disparity is None:
            return
        p = self.params
        self.counts["detector_runs"] += 1
        feats = self.detector.features([pyramids[0]], (0.0, 0.0, *self.sizes[0]))[0]
        for centre, _ in self.detector.detect(feats, self.detector.params.candidates):
            left = box_from_centre(*centre, *self.sizes[0])
            right = box_from_centre(centre[0] - self.disparity, centre[1], *self.sizes[1])
            # The window lies up to half a cell (~20 px) off the target: search wider.
            found = [self.extractor.find(images[0], left, p.verify_pad),
                     self.extractor.find(images[1], right, p.verify_pad)]
            check = stereo_check(found[0], found[1], self.rig, self.marker_sides,
                                 p.row_tolerance, p.size_tolerance)
            if check != "ok":
                continue
            for v in range(2):
                boxes[v] = marker_box(found[v])
                self.tracker.reseed(v, pyramids[v], boxes[v], template=self.anchors[v])
            scores[:] = np.nan
            lost[:] = False
            self.counts["redetections"] += 1
            return

    def _learn(self, pyramids, boxes, corners) -> None:
        """A confident, verified frame: sizes and disparity; every ``sample_every``-th
        one also the templates and the detector's samples."""
        self._confident += 1
        for v in range(2):
            self.sizes[v] = box_centre_size(boxes[v])[2:]
        self.disparity = float(np.mean(corners[0, :, 0] - corners[1, :, 0]))
        if (self._confident - 1) % self.params.sample_every:
            return
        self.tracker.update_templates(pyramids, [0, 1])
        for v, feats in enumerate(self.detector.features(pyramids, boxes[0])):
            self.anchors[v] = self.tracker.template_of(v)
            self.counts["positives"] += int(self.detector.add_samples(feats, boxes[v]))


# ---------------------------------------------------------------------- front end
def find_marker_pair(extractor: MarkerCornerExtractor, left: np.ndarray, right: np.ndarray,
                     rig: StereoRig, sides, row_tolerance: float = 3.0,
                     size_tolerance: float = 0.12) -> np.ndarray | None:
    """The AUV's marker in a stereo pair without prior: corners (2, 3, 2) or None.

    Every triangular red blob of each whole image is a candidate; a left and
    a right candidate form a pair when :func:`match_stereo` accepts them
    (same rows, positive disparity, triangulated sides within
    ``size_tolerance`` of ``sides``). Of several pairs the one with the
    smallest size error wins; the 0.8x analogs fail the size check.
    """
    best, best_err = None, math.inf
    right_candidates = extractor.candidates(right)  # searched once, not per left candidate
    for cl in extractor.candidates(left):
        for cr in right_candidates:
            # match_stereo's checks, with the size error (a triangulation) computed once
            if rectified_check(cl, cr, rig, row_tolerance) != "ok":
                continue
            err = marker_size_error(cl, cr, rig, sides)
            if err > size_tolerance:
                continue
            if err < best_err:
                best, best_err = np.stack([cl, cr]), err
    return best


class LTATFrontEnd:
    """Stereo images -> ``features`` observation of ``auv_envs/LARSCapture-v0`` (seed 000 §2.1).

    Front-end protocol of :mod:`baselines.frontend`: ``reset(seed)``,
    ``__call__(observation, info) -> features`` (``pixels`` (2, 3, 2)
    float32, zero where not visible; ``visible`` (2, 3) int8;
    ``joint_position``/``joint_velocity`` passed through), ``stats()``.
    ``info`` is never read. Corners are reported when found in both views
    and verified by :func:`stereo_check` (all three), or, with the marker
    cut by one image's border, those seen in both that pass the row and
    base-length checks (:meth:`LTATracker._partial`).

    Until the marker is first found the front end runs
    :func:`find_marker_pair` on every frame (see the module docstring);
    afterwards :class:`LTATracker`.

    Args:
        calibration: the env's ``LARSCalibration`` (stereo rig, marker sides).
        weights_dir: the Siamese tracker's weights (default: the shipped ones).
    """

    def __init__(self, calibration, weights_dir=None, params: LTATParams | None = None,
                 tracker_params: TrackerParams | None = None,
                 detector_params: DetectorParams | None = None):
        net, self.weights_meta = load_siamese(weights_dir)
        self.rig = calibration.stereo
        self.marker_sides = tuple(calibration.marker_sides)
        self.params = params or LTATParams()
        self.ltat = LTATracker(net, self.rig, self.marker_sides, tracker_params,
                               detector_params, params=self.params)
        self._size = (self.rig.left.height, self.rig.left.width, 3)
        self.reset(None)

    def reset(self, seed: int | None = None) -> None:
        self.ltat.reset(np.random.default_rng(seed))
        #: The last frame's :class:`LTATOutput` (None before the marker is found).
        self.last_output: LTATOutput | None = None
        self.frames = 0
        self.initialised_at: int | None = None
        self.seconds = 0.0

    def __call__(self, observation, info=None) -> dict:
        start = time.perf_counter()
        keys = ("left", "right", "joint_position", "joint_velocity")
        if not isinstance(observation, dict) or any(k not in observation for k in keys):
            raise ValueError(f"LTATFrontEnd expects the 'stereo' observation dict with keys {keys}")
        left, right = observation["left"], observation["right"]
        for name, image in (("left", left), ("right", right)):
            if image.shape != self._size or image.dtype != np.uint8:
                raise ValueError(f"{name} image must be {self._size} uint8 (the calibration's "
                                 f"size), got {image.shape} {image.dtype}")
        if not self.ltat.started:
            corners = find_marker_pair(self.ltat.extractor, left, right, self.rig,
                                       self.marker_sides, self.params.row_tolerance,
                                       self.params.size_tolerance)
            if corners is not None:
                boxes = np.array([marker_box(corners[v]) for v in range(2)])
                self.ltat.start([Pyramid(left), Pyramid(right)], boxes)
                self.initialised_at = self.frames
                self.last_output = LTATOutput(boxes, np.ones(2), np.zeros(2, bool), corners,
                                              np.ones((2, 3), dtype=bool))
        else:
            self.last_output = self.ltat.step([Pyramid(left), Pyramid(right)], (left, right))
        self.frames += 1
        pixels = np.zeros((2, 3, 2), dtype=np.float32)
        visible = np.zeros((2, 3), dtype=np.int8)
        out = self.last_output
        if out is not None and out.corners is not None:
            pixels[out.visible] = out.corners[out.visible]
            visible[out.visible] = 1
        self.seconds += time.perf_counter() - start
        return {
            "pixels": pixels,
            "visible": visible,
            "joint_position": np.asarray(observation["joint_position"], dtype=np.float32).copy(),
            "joint_velocity": np.asarray(observation["joint_velocity"], dtype=np.float32).copy(),
        }

    def stats(self) -> dict:
        c = self.ltat.counts
        return {
            "ltat_frames": self.frames,
            "ltat_initialised_at": -1 if self.initialised_at is None else self.initialised_at,
            "ltat_verified_frames": c["verified"],
            "ltat_lost_views": c["lost_views"],
            "ltat_redetections": c["redetections"],
            "ltat_stereo_transfers": c["transfers"],
            "ltat_partial_frames": c["partial"],
            "ltat_detector_fits": self.ltat.detector.fits,
            "ltat_ms_per_frame": 1e3 * self.seconds / max(self.frames, 1),
        }
