"""Siamese tracker of the AUV's marker at inference ([LTAT], §2.1.1).

[LTAT] tracks the AUV with SiamRPN: a Siamese sub-network embeds a template
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

**Weights.** Trained offline by :mod:`baselines.lars.training.siamese`
(:data:`TRAIN_COMMAND`); :func:`load_siamese` reads them with their
``meta.json`` and checks the recorded SHA-256 and architecture.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from auv_envs.core.assets import sha256_file

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
TRAIN_COMMAND = "python -m baselines.lars.training.siamese train --out assets/lars/siamese"


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
class SiameseTrackerParams:
    """Inference settings (SiamRPN's, [LTAT] §2.1.1).

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

    def __init__(self, net: SiameseNet, params: SiameseTrackerParams | None = None):
        self.net = net
        self.params = params or SiameseTrackerParams()
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

