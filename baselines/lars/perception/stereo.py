"""Marker corners of the two views matched and checked against the stereo pair ([LTAT], §2.2).

* :func:`stereo_check`: corners of the two views matched by label and
  checked against the rectified geometry (same rows, positive disparity)
  and the marker's known size (triangulated sides, [LTAT] eq. 2);
  :func:`rectified_check`, :func:`marker_side_ratios` and
  :func:`marker_size_error` are its parts, :func:`match_stereo` its yes/no.
* :func:`find_marker_pair`: the AUV's marker in a stereo pair without a
  prior box (the look-alike analogs carry a 0.8x marker and fail the size
  check).
"""

from __future__ import annotations

import math

import numpy as np

from auv_envs.tasks.lars.stereo import StereoRig, triangulate
from baselines.lars.perception.corners import MarkerCornerExtractor


def stereo_check(
    left: np.ndarray | None, right: np.ndarray | None, rig: StereoRig, sides,
    row_tolerance: float = 3.0, size_tolerance: float = 0.12,
) -> str:
    """Whether the labelled corners of the two views are one marker of the known size.

    Checks the rectified geometry (each corner on the same row in both views,
    positive disparity) and the sides of the triangulated triangle ([LTAT]
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
    if rig.disparity(left[:, 0], right[:, 0], np).min() <= 0.0:
        return "disparity"
    return "ok"


def marker_side_ratios(left: np.ndarray, right: np.ndarray, rig: StereoRig, sides) -> np.ndarray:
    """Triangulated sides (|A1A2|, |A1A3|, |A2A3|) over ``sides`` ([LTAT] eq. 2)."""
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
