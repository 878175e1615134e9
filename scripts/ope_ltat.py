"""[LTAT] Fig. 6: OPE success and precision of the Siamese tracker alone vs LTAT.

One-pass evaluation (OTB, Wu et al. 2013), as in [LTAT] §3: each tracker
starts from the true box of the first frame and runs through the sequence
without restarts. The target is the AUV's marker box (the axis-aligned box of
the three projected marker corners, clipped to the image; see
:mod:`baselines.lars.perception.siamese`); both views of every frame count, frames
whose marker lies outside the image are left out.

* success(t): fraction of frames with IoU(output, truth) > t, t in [0, 1];
  its area under the curve (AUC, the mean over 21 thresholds) ranks trackers.
* precision(t): fraction of frames with a centre error <= t px; the value at
  20 px ranks trackers.

Three rows: the Siamese tracker alone (same network; its own template
update: every frame a view scores >= ``SiameseTrackerParams.update_score``), LTAT as
shipped (templates updated on every ``sample_every``-th confident, verified
frame), and LTAT with its boxes left as the tracker's (never snapped to the
verified corners), which isolates what re-detection alone adds.

Sequences come from the LARS exporter (:mod:`auv_envs.datasets.lars`) at
``--difficulty`` (default ``paper``; ``easy`` is the released scene) with
evaluation seeds >= 100000 (the tracker trained on seeds 1000-2011): the
calm sequences are the first seeds from ``--first-seed`` N (default 100000)
whose marker is in view at frame 0, the severe ones the first seeds from
N + 50000 whose labels also show a wash-over (a corner hidden by a crest) and
an analog in view.

    python scripts/ope_ltat.py [--difficulty paper] [--first-seed 100000] [--sequences 4]
        [--steps 250] [--out results/ope_ltat] [--json PATH]

Prints a Markdown table (success AUC and precision with 95 % bootstrap
intervals over the scored views) and writes ``ope_ltat.png`` and
``ope_ltat.json``; ``--json PATH`` writes the same figures there too.

It also scores the corner extractor on the same sequences (every 3rd frame,
views with all three corners visible): the pixel error of A1, A2, A3 found
inside the true marker box against the true projections, and how often no
triangle (or a mislabelled one, > 15 px off) came back.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import torch

from auv_envs.core.difficulty import LEVELS
from auv_envs.core.env import TaskEnv
from auv_envs.datasets.lars import export_sequence, load_sequence
from auv_envs.metrics import box_iou
from auv_envs.tasks.lars.env import LARSCaptureTask
from baselines.evaluation import EVAL_SEED_BASE, write_figures
from baselines.lars.perception.corners import MarkerCornerExtractor
from baselines.lars.perception.ltat import LTATParams, LTATracker
from baselines.lars.perception.siamese import (
    Pyramid,
    SiameseTracker,
    load_siamese,
    marker_box,
)
from baselines.lars.training.siamese import read_frame
from baselines.stats import bootstrap_interval

KINDS = ("siamese", "ltat-tracker-box", "ltat")
NAMES = {
    "siamese": "Siamese tracker alone",
    "ltat-tracker-box": "LTAT, tracker boxes (no corner snap)",
    "ltat": "LTAT",
}
IOU_THRESHOLDS = np.linspace(0.0, 1.0, 21)
PIXEL_THRESHOLDS = np.arange(0, 51)


def centre_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Centre distance (px) row by row; inf where an output box is NaN."""
    ca = 0.5 * (a[:, :2] + a[:, 2:])
    cb = 0.5 * (b[:, :2] + b[:, 2:])
    return np.nan_to_num(np.linalg.norm(ca - cb, axis=1), nan=np.inf)


def view_auc(ious: np.ndarray) -> np.ndarray:
    """Each view's share of the 21 thresholds it passes: the success AUC is their mean,
    so a bootstrap over views gives the AUC's interval."""
    return (ious[:, None] > IOU_THRESHOLDS[None, :]).mean(axis=1)


def _ci(ci) -> str:
    return f" [{ci[0]:.3f}, {ci[1]:.3f}]" if np.all(np.isfinite(ci)) else ""


def success_curve(ious: np.ndarray) -> np.ndarray:
    return np.array([(ious > t).mean() for t in IOU_THRESHOLDS])


def precision_curve(errors: np.ndarray) -> np.ndarray:
    return np.array([(errors <= t).mean() for t in PIXEL_THRESHOLDS])


def truth_boxes(labels: dict, size) -> np.ndarray:
    """(T, 2, 4) marker boxes clipped to the image; NaN when out of view."""
    c = labels["corners_px"]
    return np.array([[marker_box(c[t, v], size) for v in range(2)] for t in range(len(c))])


def frames(path: Path, t: int) -> list[np.ndarray]:
    return [read_frame(path, v, t) for v in ("left", "right")]


def run_tracker(kind: str, path: Path, truth: np.ndarray, net, rig, sides):
    """Output boxes (T, 2, 4) of ``kind`` started on frame 0's truth.

    ``kind``: ``"siamese"`` (the tracker alone), ``"ltat"`` (as shipped), or
    ``"ltat-tracker-box"`` (LTAT whose boxes are never snapped to the
    verified corners: re-detection alone).

    Returns:
        The boxes and LTAT's event counters (empty for the tracker alone).
    """
    n = len(truth)
    out = np.full((n, 2, 4), np.nan)
    images = frames(path, 0)
    pyrs = [Pyramid(im) for im in images]
    out[0] = truth[0]
    if kind == "siamese":
        tracker = SiameseTracker(net)
        tracker.init(pyrs, truth[0])
    else:
        params = LTATParams(snap_to_corners=kind == "ltat")
        tracker = LTATracker(net, rig, sides, params=params)
        tracker.reset(np.random.default_rng(0))
        tracker.start(pyrs, truth[0])
    for t in range(1, n):
        images = frames(path, t)
        pyrs = [Pyramid(im) for im in images]
        if kind == "siamese":
            out[t] = tracker.track(pyrs)[0]
        else:
            out[t] = tracker.step(pyrs, images).boxes
    return out, (dict(tracker.counts) if kind != "siamese" else {})


def corner_errors(paths, size, step: int = 3) -> dict:
    """Corner extractor vs the true projections (fully visible views, every ``step`` frames)."""
    extractor = MarkerCornerExtractor()
    errors, views, missed = [], 0, 0
    for path in paths:
        _, labels = load_sequence(path)
        for t in range(0, len(labels["time"]), step):
            images = None
            for v in range(2):
                if not labels["corners_visible"][t, v].all():
                    continue
                images = images or frames(path, t)
                views += 1
                truth = labels["corners_px"][t, v]
                found = extractor.find(images[v], marker_box(truth, size))
                if found is None:
                    missed += 1
                    continue
                errors.append(np.linalg.norm(found - truth, axis=1))
    e = np.array(errors).reshape(-1, 3)
    return {
        "views": views,
        "missed": missed,
        "mislabelled_over_15px": int((e.max(axis=1) > 15).sum()),
        "mean_px": e.mean(axis=0).tolist(),
        "p95_px": np.percentile(e, 95, axis=0).tolist(),
        "max_px": e.max(axis=0).tolist(),
    }


def select_sequences(data: Path, sea: str, count: int, steps: int, difficulty: str,
                     first_seed: int) -> list[Path]:
    """Export evaluation sequences; severe ones must show a wash-over and an analog."""
    paths, seed = [], first_seed + (0 if sea == "calm" else 50000)
    while len(paths) < count:
        path = data / difficulty / f"{sea}_{seed}"
        try:
            meta, labels = load_sequence(path)
            ok = meta["frames"] == steps and meta.get("difficulty", "easy") == difficulty
        except (FileNotFoundError, OSError, KeyError):
            ok = False
        if not ok:
            export_sequence(path, seed, sea, steps, difficulty=difficulty)
            meta, labels = load_sequence(path)
        first = truth_boxes(labels, meta["image_size"])[0]
        usable = np.isfinite(first).all()
        if sea == "severe":
            usable &= bool(labels["occluded"].any()) and bool(labels["distractors"].any())
        if usable:
            paths.append(path)
        seed += 1
    return paths


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", type=int, default=4, help="per sea state")
    parser.add_argument("--steps", type=int, default=250, help="frames per sequence")
    parser.add_argument("--data", default="build/ope_ltat_data")
    parser.add_argument("--out", default="results/ope_ltat")
    parser.add_argument("--difficulty", choices=LEVELS, default="paper")
    parser.add_argument("--first-seed", type=int, default=EVAL_SEED_BASE,
                        help="calm sequences from seed N, severe from N + 50000 "
                             "(default %(default)s)")
    parser.add_argument("--json", metavar="PATH", help="also write the figures here")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    net, _ = load_siamese()
    env = TaskEnv(LARSCaptureTask)  # calibration only (no rendering)
    rig, sides = env.calibration.stereo, env.calibration.marker_sides
    env.close()

    results, corners = {}, {}
    for sea in ("calm", "severe"):
        paths = select_sequences(Path(args.data), sea, args.sequences, args.steps,
                                 args.difficulty, args.first_seed)
        corners[sea] = corner_errors(paths, load_sequence(paths[0])[0]["image_size"])
        for kind in KINDS:
            ious, errors, seconds, count = [], [], 0.0, 0
            events = collections.Counter()
            for path in paths:
                meta, labels = load_sequence(path)
                truth = truth_boxes(labels, meta["image_size"])
                start = time.perf_counter()
                boxes, counts = run_tracker(kind, path, truth, net, rig, sides)
                events.update(counts)
                seconds += time.perf_counter() - start
                count += len(truth)
                valid = np.isfinite(truth).all(axis=2)
                ious.append(box_iou(boxes[valid], truth[valid]))
                errors.append(centre_error(boxes[valid], truth[valid]))
            ious, errors = np.concatenate(ious), np.concatenate(errors)
            s, p = success_curve(ious), precision_curve(errors)
            results[(sea, kind)] = {
                "sequences": [pth.name for pth in paths],
                "frames": int(len(ious)),
                "success": s.tolist(),
                "precision": p.tolist(),
                "auc": float(s.mean()),
                "auc_ci95": list(bootstrap_interval(view_auc(ious))),
                "precision_20px": float(p[20]),
                "precision_20px_ci95": list(bootstrap_interval(errors <= 20.0)),
                "stereo_frames_per_s": count / seconds,
                "ltat_events": dict(events),
            }

    print(f"difficulty {args.difficulty!r}, first seed {args.first_seed}\n")
    print("| sea state | tracker | views scored | success AUC [95 %] | precision @ 20 px [95 %] |")
    print("|---|---|---|---|---|")
    for (sea, kind), r in results.items():
        print(f"| {sea} | {NAMES[kind]} | {r['frames']} | {r['auc']:.3f}{_ci(r['auc_ci95'])} | "
              f"{r['precision_20px']:.3f}{_ci(r['precision_20px_ci95'])} |")
    for (sea, kind), r in results.items():
        if r["ltat_events"]:
            print(f"{sea} {kind}: {r['ltat_events']}")
    print("\n| sea state | views | no triangle | > 15 px | corner error mean px (A1, A2, A3) "
          "| p95 | max |")
    print("|---|---|---|---|---|---|---|")
    for sea, c in corners.items():
        fmt = lambda v: ", ".join(f"{x:.2f}" for x in v)  # noqa: E731
        print(f"| {sea} | {c['views']} | {c['missed']} | {c['mislabelled_over_15px']} "
              f"| {fmt(c['mean_px'])} | {fmt(c['p95_px'])} | {fmt(c['max_px'])} |")
    print()
    for sea in ("calm", "severe"):
        a, b = results[(sea, "siamese")], results[(sea, "ltat")]
        met = b["auc"] > a["auc"] and b["precision_20px"] >= a["precision_20px"]
        print(f"{sea}: LTAT success AUC above the tracker alone's and precision@20 not below "
              f"it: {met} (AUC {b['auc']:.3f} vs {a['auc']:.3f}, precision@20 "
              f"{b['precision_20px']:.3f} vs {a['precision_20px']:.3f})")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    for row, sea in enumerate(("calm", "severe")):
        for kind in KINDS:
            r = results[(sea, kind)]
            axes[row, 0].plot(IOU_THRESHOLDS, r["success"],
                              label=f"{NAMES[kind]} [{r['auc']:.3f}]")
            axes[row, 1].plot(PIXEL_THRESHOLDS, r["precision"],
                              label=f"{NAMES[kind]} [{r['precision_20px']:.3f}]")
        axes[row, 0].set(title=f"Success plots of OPE ({sea})", xlabel="Overlap threshold",
                         ylabel="Success rate", xlim=(0, 1), ylim=(0, 1.02))
        axes[row, 1].set(title=f"Precision plots of OPE ({sea})",
                         xlabel="Location error threshold (px)", ylabel="Precision",
                         xlim=(0, 50), ylim=(0, 1.02))
        for ax in axes[row]:
            ax.grid(alpha=0.3)
            ax.legend(loc="lower right" if ax is axes[row, 1] else "lower left")
    fig.tight_layout()
    fig.savefig(out / "ope_ltat.png", dpi=120)
    figures = {"difficulty": args.difficulty, "first_seed": args.first_seed,
               **{f"{sea}/{kind}": r for (sea, kind), r in results.items()},
               **{f"{sea}/corners": c for sea, c in corners.items()}}
    (out / "ope_ltat.json").write_text(json.dumps(figures, indent=2))
    if args.json:
        write_figures(args.json, figures)
    print(f"wrote {out / 'ope_ltat.png'} and {out / 'ope_ltat.json'}")


if __name__ == "__main__":
    main()
