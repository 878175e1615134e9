"""Siamese tracker of the AUV's marker, trained offline on our own renders (seed 000, §2.1.1).

Seed 000 tracks the AUV with SiamRPN: a Siamese sub-network embeds a template
crop and a search crop with shared weights, a correlation compares them, and
a region-proposal head outputs the target's centre and box. This module is a
small CPU-sized version of that design in torch:

* **Embedding** (shared): four strided convolutions (total stride 8) and a
  linear adjustment layer; a 64 x 64 template crop gives an 8 x 8 feature
  map, a 128 x 128 search crop a 16 x 16 one.
* **Correlation**: channel-wise (depth-wise) cross-correlation of the two
  maps, 9 x 9 positions, each 8 search pixels apart.
* **Head** (anchor-free region proposal): per position a target score, the
  target centre's offset from the position (in cells), and the log ratio of
  the target box's width and height to the template box's.

Crops follow SiamFC's context rule: a box ``w x h`` is cropped as a square of
side ``s_z = sqrt((w + p)(h + p))``, ``p = (w + h) / 2``, scaled to the
template size; the search crop is ``2 s_z`` around the previous centre.

**What is tracked.** The AUV's marked region: the axis-aligned box of the
three marker corners. At the paper's 0.8 m tracking height the 1.8 m hull
overfills the 640 x 480 view (the exporter's AUV box is the whole image in
most frames), so the hull box carries no position information; the marker
is the part of the AUV whose pixels the pipeline needs (corner extraction,
§2.2).

**Training** (offline, seeded, CPU)::

    python -m baselines.lars.siamese train --out assets/lars/siamese

exports labelled sequences with :mod:`auv_envs.datasets.lars` (seeds in
:data:`TRAIN_SEED_RANGE`, disjoint from the evaluation seeds >= 100000), cuts
a patch around the marker in every other frame of both views, and trains on
random template/search pairs from the same sequence (frames up to
:data:`MAX_PAIR_GAP` apart, random shift and scale of the search crop).
Search crops whose marker is hidden under a wash-over crest are all-negative,
so the score falls when the marker disappears; look-alike "analogs" in a
search crop are negatives like any other background. The weights and a
``meta.json`` (command, seeds, data, iterations, wall time, versions,
SHA-256 of the weights) are written to ``--out``; :func:`load_siamese`
checks them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from auv_envs.core.assets import sha256_file
from baselines.seeds import EVAL_SEED_BASE, TRAIN_SEED_RANGE

TEMPLATE_SIZE = 64
SEARCH_SIZE = 128
STRIDE = 8
#: Positions of the score map per side: (128 - 64) / 8 + 1.
SCORE_SIZE = (SEARCH_SIZE - TEMPLATE_SIZE) // STRIDE + 1
#: Search crop side in units of the template context ``s_z``.
SEARCH_FACTOR = SEARCH_SIZE / TEMPLATE_SIZE
CHANNELS = (16, 32, 48, 64, 64)
#: Recorded in meta.json; loading refuses weights made for another layout.
ARCHITECTURE = {
    "name": "siamese-dwxcorr-anchorfree-nobn",
    "template_size": TEMPLATE_SIZE,
    "search_size": SEARCH_SIZE,
    "stride": STRIDE,
    "channels": list(CHANNELS),
    "head_outputs": 5,
}
META_FORMAT_VERSION = 1
#: Relative to the asset root (``assets/`` in a checkout).
DEFAULT_WEIGHTS_DIR = "lars/siamese"
WEIGHTS_FILE = "weights.pt"
META_FILE = "meta.json"
TRAIN_COMMAND = "python -m baselines.lars.siamese train --out assets/lars/siamese"
#: Frames (of the exported sequence) between a training template and its search.
MAX_PAIR_GAP = 40
#: A training patch spans this many template contexts (search crop plus shifts).
PATCH_FACTOR = 3
PATCH_SIZE = PATCH_FACTOR * TEMPLATE_SIZE


# ---------------------------------------------------------------------- geometry
def context_size(width, height):
    """SiamFC's template context: side of the square crop around a ``w x h`` box.

    Works on floats and, element-wise, on arrays of sizes.
    """
    pad = 0.5 * (width + height)
    return np.sqrt((width + pad) * (height + pad))


def box_centre_size(box) -> tuple[float, float, float, float]:
    """``(cx, cy, w, h)`` of a box ``(x_min, y_min, x_max, y_max)``."""
    x0, y0, x1, y1 = (float(v) for v in box)
    return 0.5 * (x0 + x1), 0.5 * (y0 + y1), x1 - x0, y1 - y0


def box_from_centre(cx: float, cy: float, w: float, h: float) -> np.ndarray:
    return np.array([cx - 0.5 * w, cy - 0.5 * h, cx + 0.5 * w, cy + 0.5 * h])


def marker_box(corners_px, image_size=None) -> np.ndarray:
    """Axis-aligned box of the marker corners (3, 2); NaN if a corner is behind the camera.

    With ``image_size = (W, H)`` the box is clipped to the image and NaN when
    nothing of it is left (the ground truth of the OPE evaluation); without,
    it is the unclipped box (training patches).
    """
    pts = np.asarray(corners_px, dtype=float)
    if not np.isfinite(pts).all():
        return np.full(4, np.nan)
    box = np.array([*pts.min(axis=0), *pts.max(axis=0)])
    if image_size is not None:
        width, height = image_size
        box[[0, 2]] = np.clip(box[[0, 2]], 0.0, width)
        box[[1, 3]] = np.clip(box[[1, 3]], 0.0, height)
        if box[2] - box[0] < 1.0 or box[3] - box[1] < 1.0:
            return np.full(4, np.nan)
    return box


class Pyramid:
    """An image and its ``cv2.pyrDown`` levels, for crops without aliasing.

    Pixel coordinates follow ``auv_envs.core.camera``: continuous, origin at
    the image's top-left corner, pixel centres at half-integers.
    """

    def __init__(self, image: np.ndarray, levels: int = 3):
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise ValueError(f"expected an (H, W, 3) uint8 image, got {image.shape} {image.dtype}")
        self.levels = [image]
        for _ in range(levels - 1):
            self.levels.append(cv2.pyrDown(self.levels[-1]))
        self.fill = tuple(float(v) for v in cv2.mean(self.levels[-1])[:3])

    @property
    def size(self) -> tuple[int, int]:
        h, w = self.levels[0].shape[:2]
        return w, h

    def crop(self, cx: float, cy: float, side: float, out: int) -> np.ndarray:
        """The square of ``side`` pixels centred at ``(cx, cy)``, resampled to ``out`` x ``out``.

        Reads the coarsest level that still has at least ``out`` pixels over
        the square; outside the image it is the image's mean colour (SiamFC).
        """
        level = 0
        while level + 1 < len(self.levels) and side / 2 ** (level + 1) >= out:
            level += 1
        k = 2.0**level
        a = side / k / out
        # Output pixel j (centre j + 0.5) samples continuous x = c - s/2 + (j + 0.5) a,
        # i.e. OpenCV index x - 0.5 (OpenCV puts pixel centres at integers).
        bx = cx / k - 0.5 * side / k + 0.5 * a - 0.5
        by = cy / k - 0.5 * side / k + 0.5 * a - 0.5
        matrix = np.array([[a, 0.0, bx], [0.0, a, by]])
        return cv2.warpAffine(
            self.levels[level], matrix, (out, out),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT, borderValue=self.fill,
        )

    def resized(self, scale: float) -> np.ndarray:
        """The whole image scaled by ``scale`` (< 1), from the nearest finer level."""
        level = 0
        while level + 1 < len(self.levels) and scale * 2 ** (level + 1) <= 1.0:
            level += 1
        w, h = self.size
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        return cv2.resize(self.levels[level], size, interpolation=cv2.INTER_AREA)


# ---------------------------------------------------------------------- network
def _conv_relu(c_in: int, c_out: int, kernel: int, stride: int) -> list[nn.Module]:
    # No batch normalisation: template and search crops pass through the
    # embedding in separate batches with different statistics, and running
    # averages of the mix bias the box head at inference.
    return [nn.Conv2d(c_in, c_out, kernel, stride, kernel // 2), nn.ReLU(inplace=True)]


class SiameseNet(nn.Module):
    """Shared embedding, depth-wise cross-correlation, anchor-free score/box head."""

    def __init__(self):
        super().__init__()
        c = CHANNELS
        self.embedding = nn.Sequential(
            *_conv_relu(3, c[0], 5, 2),
            *_conv_relu(c[0], c[1], 3, 2),
            *_conv_relu(c[1], c[2], 3, 2),
            *_conv_relu(c[2], c[3], 3, 1),
            nn.Conv2d(c[3], c[4], 3, 1, 1),
        )
        self.head = nn.Sequential(
            nn.Conv2d(c[4], c[4], 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(c[4], 5, 1),
        )

    def embed(self, images: torch.Tensor) -> torch.Tensor:
        """Features of uint8-valued crops (B, 3, S, S) (any float dtype)."""
        return self.embedding(images / 255.0 - 0.5)

    def correlate(self, template: torch.Tensor, search: torch.Tensor) -> torch.Tensor:
        """Head outputs (B, 5, 9, 9): score logit, centre offset (2, cells), log size ratio (2)."""
        b, c, h, w = search.shape
        kernel = template.reshape(b * c, 1, *template.shape[2:])
        xcorr = F.conv2d(search.reshape(1, b * c, h, w), kernel, groups=b * c)
        return self.head(xcorr.reshape(b, c, *xcorr.shape[2:]))

    def forward(self, template: torch.Tensor, search: torch.Tensor) -> torch.Tensor:
        return self.correlate(self.embed(template), self.embed(search))


def to_tensor(crops) -> torch.Tensor:
    """(B, S, S, 3) uint8 crops -> (B, 3, S, S) float32."""
    return torch.from_numpy(np.ascontiguousarray(np.stack(crops))).permute(0, 3, 1, 2).float()


def cell_centres() -> np.ndarray:
    """Search-crop pixel coordinate of each score position (9,): the centre of its window."""
    return TEMPLATE_SIZE / 2 + STRIDE * np.arange(SCORE_SIZE, dtype=float)


# ---------------------------------------------------------------------- weights
def default_weights_dir() -> Path:
    from auv_envs.core.assets import asset_root

    return asset_root() / DEFAULT_WEIGHTS_DIR


def load_siamese(directory: str | Path | None = None) -> tuple[SiameseNet, dict]:
    """The trained network (eval mode) and its ``meta.json``.

    Raises:
        FileNotFoundError: ``meta.json`` or the weights file is missing.
        ValueError: ``meta.json`` is not valid JSON or lacks fields, the
            weights' SHA-256 differs from the recorded one (corrupt or
            replaced file), the recorded architecture differs from this
            code's, or the state dict does not fit the network.
    """
    directory = Path(directory) if directory is not None else default_weights_dir()
    meta_path, weights_path = directory / META_FILE, directory / WEIGHTS_FILE
    hint = f"train them with `{TRAIN_COMMAND}`"
    for path in (meta_path, weights_path):
        if not path.is_file():
            raise FileNotFoundError(f"Siamese tracker file missing: {path}; {hint}")
    try:
        meta = json.loads(meta_path.read_text())
        recorded_sha = meta["weights_sha256"]
        recorded_arch = meta["architecture"]
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"corrupt Siamese tracker metadata {meta_path}: {exc}; {hint}") from exc
    actual_sha = sha256_file(weights_path)
    if actual_sha != recorded_sha:
        raise ValueError(
            f"Siamese tracker weights {weights_path} are corrupt or do not match {meta_path}: "
            f"SHA-256 {actual_sha} != recorded {recorded_sha}; {hint}"
        )
    if recorded_arch != ARCHITECTURE:
        raise ValueError(
            f"Siamese tracker weights in {directory} were trained for architecture "
            f"{recorded_arch}, this code builds {ARCHITECTURE}; {hint}"
        )
    net = SiameseNet()
    try:
        state = torch.load(weights_path, map_location="cpu", weights_only=True)
        net.load_state_dict(state, strict=True)
    except Exception as exc:  # noqa: BLE001 - torch raises several types for bad files
        raise ValueError(f"cannot load Siamese tracker weights {weights_path}: {exc}") from exc
    net.eval()
    return net, meta


# ---------------------------------------------------------------------- tracker
@dataclasses.dataclass
class _ViewState:
    cx: float
    cy: float
    w: float
    h: float
    template: torch.Tensor  # (1, C, 8, 8)
    template_w: float  # template box in template-crop pixels
    template_h: float


@dataclasses.dataclass(frozen=True)
class TrackerParams:
    """Inference settings (SiamRPN's, seed 000 §2.1.1).

    Attributes:
        window_influence: weight of the cosine window against the score.
        scale_penalty: ``k`` of SiamRPN's size/aspect change penalty.
        size_rate: learning rate of the box size (times penalty x score).
        template_rate: template features' moving-average rate.
        update_score: the template is updated only above this score, so an
            occluded or drifting target does not overwrite it.
    """

    window_influence: float = 0.35
    scale_penalty: float = 0.04
    size_rate: float = 0.4
    template_rate: float = 0.05
    update_score: float = 0.8


class SiameseTracker:
    """Tracks one box per view (a batch: the stereo pair shares one forward pass).

    ``init(pyramids, boxes)`` then ``track(pyramids) -> (boxes (V, 4), scores (V,))``.
    """

    def __init__(self, net: SiameseNet, params: TrackerParams | None = None):
        self.net = net
        self.params = params or TrackerParams()
        hann = np.hanning(SCORE_SIZE)
        self._window = np.outer(hann, hann).ravel()
        self._centres = cell_centres()
        self.views: list[_ViewState | None] = []

    # -- templates
    @torch.no_grad()
    def embed_crops(self, crops) -> torch.Tensor:
        return self.net.embed(to_tensor(crops))

    def template_crop(self, pyramid: Pyramid, box) -> tuple[np.ndarray, float, float]:
        """Template crop of ``box`` and the box's size in template-crop pixels."""
        cx, cy, w, h = box_centre_size(box)
        side = context_size(w, h)
        crop = pyramid.crop(cx, cy, side, TEMPLATE_SIZE)
        scale = TEMPLATE_SIZE / side
        return crop, w * scale, h * scale

    def init(self, pyramids, boxes) -> None:
        """(Re)start tracking ``boxes[v]`` in view ``v`` (a box of NaN leaves the view empty)."""
        self.views = [None] * len(pyramids)
        for v, (pyr, box) in enumerate(zip(pyramids, boxes, strict=True)):
            self.reseed(v, pyr, box)

    def reseed(self, view: int, pyramid: Pyramid, box, template=None) -> None:
        """Move view ``view`` to ``box``; new template from the crop unless one is given."""
        if box is None or not np.isfinite(box).all():
            self.views[view] = None
            return
        cx, cy, w, h = box_centre_size(box)
        crop, tw, th = self.template_crop(pyramid, box)
        if template is None:
            template = (self.embed_crops([crop]), tw, th)
        feats, tw, th = template
        self.views[view] = _ViewState(cx, cy, w, h, feats, tw, th)

    def template_of(self, view: int) -> tuple[torch.Tensor, float, float]:
        """A copy of view ``view``'s template (features, box width and height in the crop)."""
        s = self.views[view]
        return s.template.clone(), s.template_w, s.template_h

    def box(self, view: int) -> np.ndarray:
        s = self.views[view]
        if s is None:
            return np.full(4, np.nan)
        return box_from_centre(s.cx, s.cy, s.w, s.h)

    def update_templates(self, pyramids, views, rate: float | None = None) -> None:
        """Blend the crops at the views' current boxes into their templates (moving
        average; one forward pass for all ``views``)."""
        if not views:
            return
        crops = [self.template_crop(pyramids[v], self.box(v)) for v in views]
        feats = self.embed_crops([c for c, _, _ in crops])
        r = self.params.template_rate if rate is None else rate
        for k, (v, (_, tw, th)) in enumerate(zip(views, crops, strict=True)):
            s = self.views[v]
            s.template = (1.0 - r) * s.template + r * feats[k : k + 1]
            s.template_w = (1.0 - r) * s.template_w + r * tw
            s.template_h = (1.0 - r) * s.template_h + r * th

    def set_box(self, view: int, box) -> None:
        """Move view ``view``'s box without touching its template."""
        s = self.views[view]
        s.cx, s.cy, s.w, s.h = box_centre_size(box)

    # -- tracking
    @torch.no_grad()
    def score_maps(self, pyramids, views) -> tuple[np.ndarray, list[float]]:
        """Head outputs (len(views), 5, 9, 9) around each view's current box, and search sides."""
        crops, sides, templates = [], [], []
        for v in views:
            s = self.views[v]
            side = SEARCH_FACTOR * context_size(s.w, s.h)
            crops.append(pyramids[v].crop(s.cx, s.cy, side, SEARCH_SIZE))
            sides.append(side)
            templates.append(s.template)
        out = self.net.correlate(torch.cat(templates), self.embed_crops(crops))
        return out.numpy(), sides

    def track(self, pyramids, views=None, update: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One frame: new boxes (V, 4) and peak scores (V,) (NaN for empty views).

        With ``update``, a view whose score reaches ``params.update_score``
        blends its new crop into its template.
        """
        views = [v for v in (range(len(self.views)) if views is None else views)
                 if self.views[v] is not None]
        boxes = np.full((len(self.views), 4), np.nan)
        scores = np.full(len(self.views), np.nan)
        if not views:
            return boxes, scores
        out, sides = self.score_maps(pyramids, views)
        for k, v in enumerate(views):
            scores[v] = self._step(v, out[k], sides[k], pyramids[v].size)
            boxes[v] = self.box(v)
        if update:
            self.update_templates(
                pyramids, [v for v in views if scores[v] >= self.params.update_score]
            )
        return boxes, scores

    def _step(self, view: int, out: np.ndarray, side: float, image_size) -> float:
        """Decode one view's head output (SiamRPN's penalties and window) and move its box."""
        s, p = self.views[view], self.params
        score = 1.0 / (1.0 + np.exp(-out[0].ravel()))
        scale = SEARCH_SIZE / side  # search-crop pixels per image pixel
        w_new = s.template_w * np.exp(out[3].ravel())  # search-crop pixels
        h_new = s.template_h * np.exp(out[4].ravel())
        w_old, h_old = s.w * scale, s.h * scale

        def change(r):
            return np.maximum(r, 1.0 / r)

        size_change = change(context_size(w_new, h_new) / context_size(w_old, h_old))
        ratio_change = change((w_old / h_old) / (w_new / h_new))
        penalty = np.exp(-(ratio_change * size_change - 1.0) * p.scale_penalty)
        pscore = (1.0 - p.window_influence) * score * penalty + p.window_influence * self._window
        best = int(np.argmax(pscore))
        iy, ix = divmod(best, SCORE_SIZE)
        px = self._centres[ix] + STRIDE * out[1, iy, ix]
        py = self._centres[iy] + STRIDE * out[2, iy, ix]
        width, height = image_size
        s.cx = float(np.clip(s.cx + (px - SEARCH_SIZE / 2) / scale, 0.0, width))
        s.cy = float(np.clip(s.cy + (py - SEARCH_SIZE / 2) / scale, 0.0, height))
        rate = float(penalty[best] * score[best] * p.size_rate)
        s.w = float(np.clip((1 - rate) * s.w + rate * w_new[best] / scale, 8.0, width))
        s.h = float(np.clip((1 - rate) * s.h + rate * h_new[best] / scale, 8.0, height))
        return float(score[best])


# ---------------------------------------------------------------------- training data
@dataclasses.dataclass
class PatchSet:
    """Marker-centred patches (scale: ``TEMPLATE_SIZE`` pixels per template context).

    Attributes:
        patches: (N, P, P, 3) uint8, ``P = PATCH_SIZE``.
        sizes: (N, 2) marker box width/height in patch pixels.
        state: (N,) 2 = all corners visible, 1 = some, 0 = none (hidden by
            a crest or outside the image).
        sequence, frame, view: (N,) where each patch comes from.
    """

    patches: np.ndarray
    sizes: np.ndarray
    state: np.ndarray
    sequence: np.ndarray
    frame: np.ndarray
    view: np.ndarray


def read_frame(sequence_dir, view: str, t: int) -> np.ndarray:
    """Frame ``t`` of view ``view`` (``"left"``/``"right"``) of an exported sequence, RGB.

    Raises:
        FileNotFoundError: if the PNG is missing or unreadable.
    """
    path = Path(sequence_dir)
    image = cv2.imread(str(path / view / f"{t:06d}.png"), cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(f"missing or unreadable frame {view}/{t:06d}.png in {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def build_patches(sequence_dirs, frame_step: int = 2) -> PatchSet:
    """Cut a patch around the true marker box in every ``frame_step``-th frame of both views."""
    from auv_envs.datasets.lars import load_sequence

    out = {k: [] for k in ("patches", "sizes", "state", "sequence", "frame", "view")}
    for s, path in enumerate(sequence_dirs):
        path = Path(path)
        _, labels = load_sequence(path)
        for t in range(0, len(labels["time"]), frame_step):
            for view, name in enumerate(("left", "right")):
                box = marker_box(labels["corners_px"][t, view])
                if not np.isfinite(box).all():
                    continue
                cx, cy, w, h = box_centre_size(box)
                side = context_size(w, h)
                pyr = Pyramid(read_frame(path, name, t))
                out["patches"].append(pyr.crop(cx, cy, PATCH_FACTOR * side, PATCH_SIZE))
                out["sizes"].append((w * TEMPLATE_SIZE / side, h * TEMPLATE_SIZE / side))
                seen = int(labels["corners_visible"][t, view].sum())
                out["state"].append(2 if seen == 3 else (1 if seen else 0))
                out["sequence"].append(s)
                out["frame"].append(t)
                out["view"].append(view)
    if not out["patches"]:
        raise ValueError("no marker patches found in the given sequences")
    return PatchSet(
        patches=np.stack(out["patches"]),
        sizes=np.array(out["sizes"], dtype=np.float32),
        state=np.array(out["state"], dtype=np.int8),
        sequence=np.array(out["sequence"]),
        frame=np.array(out["frame"]),
        view=np.array(out["view"]),
    )


def _patch_crop(patch: np.ndarray, cx: float, cy: float, side: float, out: int) -> np.ndarray:
    a = side / out
    matrix = np.array([[a, 0.0, cx - 0.5 * side + 0.5 * a - 0.5],
                       [0.0, a, cy - 0.5 * side + 0.5 * a - 0.5]])
    return cv2.warpAffine(patch, matrix, (out, out), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT)


class PairSampler:
    """Random template/search pairs with score and box targets (seeded)."""

    POSITIVE_RADIUS = 1.5  # cells
    NEGATIVE_RADIUS = 2.5  # cells
    MAX_SHIFT = 0.3  # of a template context, per axis
    SCALE_JITTER = 0.12  # log scale of the search crop

    def __init__(self, data: PatchSet, rng: np.random.Generator):
        self.data = data
        self.rng = rng
        self.templates = np.flatnonzero(data.state == 2)
        if len(self.templates) == 0:
            raise ValueError("no patch with a fully visible marker to use as a template")
        self._by_sequence = {
            s: np.flatnonzero(data.sequence == s) for s in np.unique(data.sequence)
        }
        centres = cell_centres()
        self._gx, self._gy = np.meshgrid(centres, centres)

    def _search_index(self, i: int) -> int:
        d = self.data
        pool = self._by_sequence[int(d.sequence[i])]
        near = pool[np.abs(d.frame[pool] - d.frame[i]) <= MAX_PAIR_GAP]
        return int(self.rng.choice(near))

    def sample(self, batch: int) -> dict:
        """A batch: ``template``, ``search`` crops, per-position ``label``, ``weight``,
        ``regression`` targets and ``positive`` mask, and the search crop's ``state``."""
        d, rng = self.data, self.rng
        zs, xs, labels, weights, reg, pos_mask, states = [], [], [], [], [], [], []
        c = PATCH_SIZE / 2
        for _ in range(batch):
            i = int(rng.choice(self.templates))
            j = self._search_index(i)
            jit = rng.uniform(-0.03, 0.03, 2) * TEMPLATE_SIZE
            tside = TEMPLATE_SIZE * math.exp(rng.uniform(-0.05, 0.05))
            z = _patch_crop(d.patches[i], c + jit[0], c + jit[1], tside, TEMPLATE_SIZE)
            tw, th = d.sizes[i] * TEMPLATE_SIZE / tside
            shift = rng.uniform(-self.MAX_SHIFT, self.MAX_SHIFT, 2) * TEMPLATE_SIZE
            side = SEARCH_SIZE * math.exp(rng.uniform(-self.SCALE_JITTER, self.SCALE_JITTER))
            x = _patch_crop(d.patches[j], c + shift[0], c + shift[1], side, SEARCH_SIZE)
            k = SEARCH_SIZE / side
            tx, ty = SEARCH_SIZE / 2 - shift[0] * k, SEARCH_SIZE / 2 - shift[1] * k
            sw, sh = d.sizes[j] * k
            if rng.uniform() < 0.5:  # a consistent mirror image
                z, x = z[:, ::-1], x[:, ::-1]
                tx = SEARCH_SIZE - tx
            gain = rng.uniform(0.85, 1.15)
            z = np.clip(z * gain, 0, 255).astype(np.uint8)
            x = np.clip(x * rng.uniform(0.85, 1.15), 0, 255).astype(np.uint8)
            dist = np.hypot(self._gx - tx, self._gy - ty) / STRIDE
            state = int(d.state[j])
            pos = (dist <= self.POSITIVE_RADIUS) & (state == 2)
            neg = (dist > self.NEGATIVE_RADIUS) | (state == 0)
            w = np.zeros_like(dist)
            if pos.any():
                w[pos] = 0.5 / pos.sum()
                w[neg] = 0.5 / max(neg.sum(), 1)
            else:
                w[neg] = 1.0 / max(neg.sum(), 1)
            r = np.stack([(tx - self._gx) / STRIDE, (ty - self._gy) / STRIDE,
                          np.full_like(dist, math.log(sw / tw)),
                          np.full_like(dist, math.log(sh / th))])
            zs.append(np.ascontiguousarray(z))
            xs.append(np.ascontiguousarray(x))
            labels.append(pos.astype(np.float32))
            weights.append(w.astype(np.float32))
            reg.append(r.astype(np.float32))
            pos_mask.append(pos)
            states.append(state)
        return {
            "template": to_tensor(zs),
            "search": to_tensor(xs),
            "label": torch.from_numpy(np.stack(labels)),
            "weight": torch.from_numpy(np.stack(weights)),
            "regression": torch.from_numpy(np.stack(reg)),
            "positive": torch.from_numpy(np.stack(pos_mask)),
            "state": np.array(states),
        }


def pair_loss(out: torch.Tensor, batch: dict) -> tuple[torch.Tensor, dict]:
    """Balanced logistic score loss + smooth-L1 box loss on the positive positions."""
    cls = F.binary_cross_entropy_with_logits(
        out[:, 0], batch["label"], weight=batch["weight"], reduction="sum"
    ) / out.shape[0]
    reg = batch["regression"]
    mask = batch["positive"].unsqueeze(1).expand_as(reg)
    if mask.any():
        box = F.smooth_l1_loss(out[:, 1:][mask], reg[mask], beta=0.5)
    else:
        box = out.sum() * 0.0
    return cls + box, {"score": cls.item(), "box": box.item()}


@torch.no_grad()
def validate(net: SiameseNet, sampler: PairSampler, batches: int, batch: int) -> dict:
    """Peak accuracy (peak within 1.5 cells of the truth) on visible pairs, mean peak
    score on visible vs hidden search crops, mean loss."""
    net.eval()
    hits = visible = 0
    peak_visible, peak_hidden, losses = [], [], []
    for _ in range(batches):
        data = sampler.sample(batch)
        out = net(data["template"], data["search"])
        losses.append(pair_loss(out, data)[0].item())
        score = torch.sigmoid(out[:, 0]).reshape(out.shape[0], -1)
        peak, idx = score.max(dim=1)
        pos = data["positive"].reshape(out.shape[0], -1)
        for b in range(out.shape[0]):
            if pos[b].any():
                visible += 1
                hits += bool(pos[b, idx[b]])
                peak_visible.append(float(peak[b]))
            elif data["state"][b] == 0:
                peak_hidden.append(float(peak[b]))
    return {
        "loss": float(np.mean(losses)),
        "peak_accuracy": hits / max(visible, 1),
        "visible_pairs": visible,
        "mean_peak_score_visible": float(np.mean(peak_visible)) if peak_visible else None,
        "hidden_pairs": len(peak_hidden),
        "mean_peak_score_hidden": float(np.mean(peak_hidden)) if peak_hidden else None,
    }


def train_sequences(sea_state: str, count: int) -> list[int]:
    """Training seeds: calm from 1000, severe from 2000 (inside :data:`TRAIN_SEED_RANGE`)."""
    start = 1000 if sea_state == "calm" else 2000
    seeds = list(range(start, start + count))
    lo, hi = TRAIN_SEED_RANGE
    if not all(lo <= s <= hi for s in seeds) or max(seeds) >= EVAL_SEED_BASE:
        raise ValueError("training seeds must stay inside TRAIN_SEED_RANGE")
    return seeds


def export_training_data(
    data_dir: Path, per_sea_state: int, steps: int
) -> tuple[dict[str, list[Path]], int]:
    """Export (or reuse) the training sequences.

    Returns:
        The directories per sea state, and how many sequences were exported
        (the rest were already in ``data_dir`` with the same seed and length).
    """
    from auv_envs.datasets.lars import export_sequence, load_sequence

    dirs, exported = {}, 0
    for sea in ("calm", "severe"):
        dirs[sea] = []
        for seed in train_sequences(sea, per_sea_state):
            path = Path(data_dir) / f"{sea}_{seed}"
            try:
                meta, _ = load_sequence(path)
                reuse = meta["seed"] == seed and meta["frames"] == steps
            except (FileNotFoundError, KeyError, ValueError, OSError):
                reuse = False
            if not reuse:
                export_sequence(path, seed, sea, steps)
                exported += 1
            dirs[sea].append(path)
    return dirs, exported


def train(out: Path, data_dir: Path, seed: int = 0, per_sea_state: int = 12, steps: int = 150,
          iterations: int = 1000, batch: int = 32, lr: float = 3e-3, frame_step: int = 2,
          log=print) -> dict:
    """Train and write ``weights.pt`` + ``meta.json`` to ``out``; returns the metadata.

    The last calm and the last severe sequence are held out for validation.
    """
    import auv_envs
    from auv_envs.datasets.lars import load_sequence

    start = time.perf_counter()
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    dirs, exported = export_training_data(data_dir, per_sea_state, steps)
    export_s = time.perf_counter() - start
    train_dirs = dirs["calm"][:-1] + dirs["severe"][:-1]
    val_dirs = [dirs["calm"][-1], dirs["severe"][-1]]
    train_set = build_patches(train_dirs, frame_step)
    val_set = build_patches(val_dirs, frame_step)
    patches_s = time.perf_counter() - start - export_s
    log(f"patches: {len(train_set.patches)} train, {len(val_set.patches)} validation "
        f"({time.perf_counter() - start:.0f} s)")
    sampler = PairSampler(train_set, rng)
    net = SiameseNet()
    opt = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=iterations,
                                                pct_start=0.1)
    net.train()
    for it in range(iterations):
        data = sampler.sample(batch)
        loss, parts = pair_loss(net(data["template"], data["search"]), data)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if it % 100 == 0 or it == iterations - 1:
            log(f"iter {it:5d} loss {loss.item():.4f} score {parts['score']:.4f} "
                f"box {parts['box']:.4f} ({time.perf_counter() - start:.0f} s)")
    val = validate(net, PairSampler(val_set, np.random.default_rng(seed + 1)), 20, batch)
    log(f"validation: {val}")
    net.eval()

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    weights_path = out / WEIGHTS_FILE
    torch.save(net.state_dict(), weights_path)
    seeds = {s: train_sequences(s, per_sea_state) for s in ("calm", "severe")}
    image_size = load_sequence(train_dirs[0])[0]["image_size"]  # as exported
    meta = {
        "format_version": META_FORMAT_VERSION,
        "command": " ".join(["python -m baselines.lars.siamese", *sys.argv[1:]])
        if sys.argv and sys.argv[0].endswith("siamese.py") else TRAIN_COMMAND,
        "seed": seed,
        "data": {
            "exporter": "auv_envs.datasets.lars.export_sequence",
            "train_seeds": {s: v[:-1] for s, v in seeds.items()},
            "validation_seeds": {s: v[-1:] for s, v in seeds.items()},
            "steps_per_sequence": steps,
            "frame_step": frame_step,
            "image_size": image_size,
            "train_patches": int(len(train_set.patches)),
            "validation_patches": int(len(val_set.patches)),
        },
        "iterations": iterations,
        "batch_size": batch,
        "epochs": round(iterations * batch / len(sampler.templates), 2),
        "learning_rate": lr,
        "wall_time_s": round(time.perf_counter() - start, 1),
        "timings_s": {
            "export": round(export_s, 1),
            "sequences_exported": exported,
            "patches": round(patches_s, 1),
            "training": round(time.perf_counter() - start - export_s - patches_s, 1),
        },
        "torch_threads": torch.get_num_threads(),
        "package_version": auv_envs.__version__,
        "torch_version": torch.__version__,
        "architecture": ARCHITECTURE,
        "validation": val,
        "weights_sha256": sha256_file(weights_path),
    }
    (out / META_FILE).write_text(json.dumps(meta, indent=2) + "\n")
    log(f"wrote {weights_path} ({weights_path.stat().st_size / 1e6:.2f} MB) and {out / META_FILE}")
    return meta


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description="Siamese marker tracker for LARS (seed 000).")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("train", help="export training sequences and train the tracker")
    p.add_argument("--out", default="assets/lars/siamese", help="where weights.pt/meta.json go")
    p.add_argument("--data", default="build/lars_siamese_data", help="exported sequences (cache)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sequences", type=int, default=12, help="sequences per sea state")
    p.add_argument("--steps", type=int, default=150, help="frames per sequence")
    p.add_argument("--iterations", type=int, default=1000)
    p.add_argument("--batch", type=int, default=32)
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    train(Path(args.out), Path(args.data), args.seed, args.sequences, args.steps,
          args.iterations, args.batch, log=lambda msg: print(msg, flush=True))


if __name__ == "__main__":
    main()
