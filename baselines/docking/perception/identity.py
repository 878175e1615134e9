"""Lamp identity at initialisation ([LAMP] §2.2.2): which detection is which lamp.

When every lamp is detected, the lamps are labelled by geometry: for the L-shaped array A, B,
C, D by the shape of the L (:func:`identify_l_shape`: [LAMP] uses edge lengths; we use the
line A-B-C, B between A and C, and the side D is on, which a perspective view keeps); for a
convex ring such as the six symmetric docking lights by their cyclic order
(:func:`ring_labelings`, our documented rule), the front end keeping the candidate that fits
the rigid array with the INS attitude best (four of the six lights suffice).
"""

from __future__ import annotations

import itertools

import numpy as np


def identify_l_shape(centres: np.ndarray, layout: np.ndarray,
                     collinear_tol: float = 0.08) -> np.ndarray | None:
    """Label four detections as lamps A, B, C, D of [LAMP]'s L-shaped array (§2.2.2).

    A, B, C lie on a line and D beside C ([LAMP] §1.2, Fig. 2). [LAMP] tells them apart
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


__all__ = ["identify_l_shape", "ring_labelings"]
