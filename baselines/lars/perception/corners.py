"""The three corners of the AUV's painted triangle marker in one image ([LTAT], §2.2).

:class:`MarkerCornerExtractor` finds them inside a box (OpenCV colour
threshold, contour, the largest triangle inscribed in its convex hull;
sub-pixel by intersecting lines fitted to the edges near each corner) and
labels them A1 (port base), A2 (starboard base), A3 (apex).
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import cv2
import numpy as np

from baselines.lars.perception.siamese import box_centre_size


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

