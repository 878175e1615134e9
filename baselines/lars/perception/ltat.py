"""Long-term anti-interference tracking (LTAT) of the AUV's marker in both views ([LTAT] §2.1.2).

[LTAT], §2.1.2: a Siamese tracker follows the target; a detector that
learns *online* -- trained during the episode on the tracker's confident
outputs -- finds the target again when the tracker's score drops below an
empirical threshold, and its best region above its own threshold re-seeds the
tracker's template and position.

:class:`LTATracker` composes the parts, each in its own module:
the Siamese tracker (:mod:`baselines.lars.perception.siamese`), the online
detector (:mod:`baselines.lars.perception.detector`), the corner extractor
(:mod:`baselines.lars.perception.corners`) and the stereo checks
(:mod:`baselines.lars.perception.stereo`).
"""

from __future__ import annotations

import collections
import dataclasses

import numpy as np

from auv_envs.tasks.lars.stereo import StereoRig, triangulate
from baselines.lars.perception.corners import CornerParams, MarkerCornerExtractor
from baselines.lars.perception.detector import DetectorParams, OnlineDetector
from baselines.lars.perception.siamese import (
    SiameseNet,
    SiameseTracker,
    SiameseTrackerParams,
    box_centre_size,
    box_from_centre,
    marker_box,
)
from baselines.lars.perception.stereo import marker_side_ratios, rectified_check, stereo_check


@dataclasses.dataclass(frozen=True)
class LTATParams:
    """Thresholds of the long-term logic ([LTAT] §2.1.2's "empirical thresholds").

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
    """Siamese tracker of both views + online detector + corner extraction ([LTAT] §2.1.2).

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
                 tracker_params: SiameseTrackerParams | None = None,
                 detector_params: DetectorParams | None = None,
                 corner_params: CornerParams | None = None,
                 params: LTATParams | None = None):
        self.net = net
        self.rig = rig
        self.marker_sides = tuple(float(s) for s in marker_sides)
        self.params = params or LTATParams()
        self._tracker_params = tracker_params or SiameseTrackerParams()
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

