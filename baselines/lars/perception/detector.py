"""The online-learned detector that finds the lost marker again ([LTAT], §2.1.2).

[LTAT]'s detector is a YOLOv5 trained *online*, during the episode, on the
tracker's confident outputs. Ours is a linear classifier (scikit-learn
``RidgeClassifier``) on feature windows of the whole frame, embedded by the
Siamese tracker's own network at the target's scale (a discriminative
window classifier in the manner of online-learned correlation trackers).
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from sklearn.linear_model import RidgeClassifier
from threadpoolctl import ThreadpoolController

from baselines.lars.perception.siamese import (
    CHANNELS,
    STRIDE,
    TEMPLATE_SIZE,
    SiameseNet,
    box_centre_size,
    context_size,
    to_tensor,
)


@dataclasses.dataclass(frozen=True)
class DetectorParams:
    """Online detector settings.

    Attributes:
        threshold: a detection needs a classifier score at least this
            (targets are +1 / -1; the seed's "empirical threshold"; set low
            because every detection is verified before it re-seeds the
            tracker, see :class:`~baselines.lars.perception.ltat.LTATracker`).
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
    """A window classifier learnt during the episode ([LTAT] §2.1.2's online detector).

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

