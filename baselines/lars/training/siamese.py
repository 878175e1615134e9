"""Offline training of the Siamese marker tracker on our own renders ([LTAT], §2.1.1).

The network, crops and weight files are :mod:`baselines.lars.perception.siamese`'s;
this module only makes the training data and fits the weights::

    python -m baselines.lars.training.siamese train --out assets/lars/siamese

exports labelled sequences with :mod:`auv_envs.datasets.lars` (seeds in
:data:`TRAIN_SEED_RANGE`, disjoint from the evaluation seeds >= 100000), cuts
a patch around the marker in every other frame of both views, and trains on
random template/search pairs from the same sequence (frames up to
:data:`MAX_PAIR_GAP` apart, random shift and scale of the search crop).
Search crops whose marker is hidden under a wash-over crest are all-negative,
so the score falls when the marker disappears; look-alike "analogs" in a
search crop are negatives like any other background. The weights and a
``meta.json`` (command, seeds, data, iterations, wall time, versions,
SHA-256 of the weights) are written to ``--out``;
:func:`~baselines.lars.perception.siamese.load_siamese` checks them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from auv_envs.core.assets import sha256_file
from baselines.lars.perception.siamese import (
    ARCHITECTURE,
    META_FILE,
    META_FORMAT_VERSION,
    SEARCH_SIZE,
    STRIDE,
    TEMPLATE_SIZE,
    TRAIN_COMMAND,
    WEIGHTS_FILE,
    Pyramid,
    SiameseNet,
    box_centre_size,
    cell_centres,
    context_size,
    marker_box,
    to_tensor,
)
from baselines.seeds import EVAL_SEED_BASE, TRAIN_SEED_RANGE

#: Frames (of the exported sequence) between a training template and its search.
MAX_PAIR_GAP = 40
#: A training patch spans this many template contexts (search crop plus shifts).
PATCH_FACTOR = 3
PATCH_SIZE = PATCH_FACTOR * TEMPLATE_SIZE


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
        "command": " ".join(["python -m baselines.lars.training.siamese", *sys.argv[1:]])
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
    parser = argparse.ArgumentParser(description="Siamese marker tracker for LARS [LTAT].")
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
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    train(Path(args.out), Path(args.data), args.seed, args.sequences, args.steps,
          args.iterations, args.batch, log=lambda msg: print(msg, flush=True))


if __name__ == "__main__":
    main()
