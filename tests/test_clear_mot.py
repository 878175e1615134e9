"""CLEAR MOT (:func:`auv_envs.metrics.clear_mot`) against py-motmetrics and hand-worked cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from auv_envs.metrics import clear_mot, clear_mot_labelled

mm = pytest.importorskip("motmetrics")

MM_NAMES = ("precision", "recall", "num_false_positives", "num_misses", "num_switches",
            "num_fragmentations", "mota", "motp", "num_objects", "num_detections")


def _motmetrics(gt_ids, gt_pts, hyp_ids, hyp_pts, threshold):
    acc = mm.MOTAccumulator(auto_id=True)
    for oi, op, hi, hp in zip(gt_ids, gt_pts, hyp_ids, hyp_pts, strict=True):
        # motmetrics' norm2squared_matrix returns squared distances; MOTP is a mean distance.
        d2 = mm.distances.norm2squared_matrix(op, hp, max_d2=threshold**2)
        acc.update(oi, hi, np.sqrt(d2))
    summary = mm.metrics.create().compute(acc, metrics=list(MM_NAMES), name="x")
    return {k: float(summary[k].iloc[0]) for k in MM_NAMES}


def _random_sequence(seed: int):
    """Objects that wander, appear and vanish; a tracker that drifts, misses, swaps ids,
    starts new ids and reports clutter."""
    rng = np.random.default_rng(seed)
    n_obj, n_frames = int(rng.integers(1, 7)), int(rng.integers(20, 60))
    threshold = float(rng.choice([1.0, 3.0, 8.0]))
    pos = rng.uniform(0, 30, (n_obj, 2))
    present = rng.random(n_obj) < 0.8
    hyp_of = np.arange(n_obj) + 100
    next_id = 200
    gt_ids, gt_pts, hyp_ids, hyp_pts = [], [], [], []
    for _ in range(n_frames):
        pos += rng.normal(0, 1.0, pos.shape)
        flip = rng.random(n_obj) < 0.08
        present = np.where(flip, ~present, present)
        if n_obj > 1 and rng.random() < 0.08:  # two tracks swap objects
            a, b = rng.choice(n_obj, 2, replace=False)
            hyp_of[[a, b]] = hyp_of[[b, a]]
        if rng.random() < 0.05:  # a track is replaced by a new id
            hyp_of[rng.integers(n_obj)] = next_id
            next_id += 1
        ids = np.flatnonzero(present)
        gt_ids.append(ids)
        gt_pts.append(pos[ids].copy())
        seen = ids[rng.random(ids.size) < 0.85]
        h_pts = pos[seen] + rng.normal(0, threshold / 2, (seen.size, 2))
        h_ids = hyp_of[seen]
        n_clutter = int(rng.poisson(0.4))
        h_pts = np.vstack([h_pts, rng.uniform(0, 30, (n_clutter, 2))])
        h_ids = np.concatenate([h_ids, np.arange(n_clutter) + 10_000 + 10 * len(hyp_ids)])
        hyp_ids.append(h_ids)
        hyp_pts.append(h_pts)
    return gt_ids, gt_pts, hyp_ids, hyp_pts, threshold


@pytest.mark.parametrize("seed", range(40))
def test_clear_mot_agrees_with_motmetrics(seed):
    gt_ids, gt_pts, hyp_ids, hyp_pts, threshold = _random_sequence(seed)
    ours = clear_mot(gt_ids, gt_pts, hyp_ids, hyp_pts, threshold)
    ref = _motmetrics(gt_ids, gt_pts, hyp_ids, hyp_pts, threshold)
    assert ours.fp == ref["num_false_positives"]
    assert ours.fn == ref["num_misses"]
    assert ours.ids == ref["num_switches"]
    assert ours.fm == ref["num_fragmentations"]
    assert ours.num_objects == ref["num_objects"]
    assert ours.num_matches == ref["num_detections"]
    for ours_value, key in ((ours.prcn, "precision"), (ours.rcll, "recall"),
                            (ours.mota, "mota"), (ours.motp, "motp")):
        if math.isnan(ref[key]):
            assert math.isnan(ours_value), key
        else:
            assert ours_value == pytest.approx(ref[key], rel=1e-12, abs=1e-12), key


def test_the_random_sequences_exercise_every_event():
    totals = np.zeros(4)
    for seed in range(40):
        r = clear_mot(*_random_sequence(seed))
        totals += (r.fp, r.fn, r.ids, r.fm)
    assert (totals > 5).all(), totals


def test_hand_worked_sequence():
    # Frame 0: object 1 matched to hyp 7 at distance 1; object 2 missed; hyp 9 is clutter.
    # Frame 1: object 1 lost (its hyp too far), object 2 matched to 8 at distance 0.5.
    # Frame 2: object 1 matched to hyp 8 (a switch from 7), object 2 matched to new hyp 7
    #          (a switch from 8); both at distance 0.
    # Frame 3: object 1 back on hyp 8 (kept), object 2 absent.
    gt_ids = [[1, 2], [1, 2], [1, 2], [1]]
    gt_pts = [[[0, 0], [10, 0]], [[0, 0], [10, 0]], [[0, 0], [10, 0]], [[0, 0]]]
    hyp_ids = [[7, 9], [7, 8], [8, 7], [8]]
    hyp_pts = [[[1, 0], [50, 50]], [[5, 0], [10, 0.5]], [[0, 0], [10, 0]], [[0, 0]]]
    r = clear_mot(gt_ids, gt_pts, hyp_ids, hyp_pts, threshold=2.0)
    assert (r.num_objects, r.num_matches, r.fp, r.fn, r.ids) == (7, 5, 2, 2, 2)
    # Object 1: tracked, missed, tracked, tracked -> one fragment; object 2: missed, then
    # tracked -> a late start is not a fragment.
    assert r.fm == 1
    assert r.motp == pytest.approx((1.0 + 0.5) / 5)
    assert r.mota == pytest.approx(1 - (2 + 2 + 2) / 7)
    assert r.prcn == pytest.approx(5 / 7)
    assert r.rcll == pytest.approx(5 / 7)


def test_distance_exactly_at_threshold_matches():
    r = clear_mot([[0]], [[[0.0, 0.0]]], [[0]], [[[3.0, 4.0]]], threshold=5.0)
    assert (r.num_matches, r.motp) == (1, 5.0)
    r = clear_mot([[0]], [[[0.0, 0.0]]], [[0]], [[[3.0, 4.0]]], threshold=4.999)
    assert (r.num_matches, r.fp, r.fn) == (0, 1, 1)


def test_empty_sequence_gives_nan_ratios():
    r = clear_mot([[]], [np.zeros((0, 2))], [[]], [np.zeros((0, 2))], threshold=1.0)
    assert r.num_objects == 0 and math.isnan(r.mota) and math.isnan(r.motp)


def test_labelled_form_counts_a_label_swap_as_switches():
    true = np.array([[[0, 0], [10, 0]]] * 3, float)
    est = true.copy()
    est[2] = est[2][::-1]  # the tracker swaps the two labels in the last frame
    r = clear_mot_labelled(true, np.ones((3, 2), bool), est, np.ones((3, 2), bool), 1.0)
    assert (r.ids, r.fp, r.fn, r.mota) == (2, 0, 0, pytest.approx(1 - 2 / 6))


def test_labelled_form_ignores_points_where_invisible():
    true = np.array([[[0, 0], [np.nan, np.nan]]], float)
    est = np.array([[[0.5, 0], [np.nan, np.nan]]], float)
    vis = np.array([[True, False]])
    r = clear_mot_labelled(true, vis, est, vis, 1.0)
    assert (r.num_objects, r.num_matches, r.motp) == (1, 1, 0.5)


@pytest.mark.parametrize(
    "args, match",
    [
        (([[0]], [[[0, 0]]], [[0]], [[[0, 0]]], 0.0), "threshold"),
        (([[0]], [[[0, 0]]], [[0]], [[[0, 0]]], math.nan), "threshold"),
        (([[0]], [[[0, 0]]], [], [], 1.0), "one entry per frame"),
        (([[0, 1]], [[[0, 0]]], [[0]], [[[0, 0]]], 1.0), "one id per point"),
        (([[0, 0]], [[[0, 0], [1, 1]]], [[0]], [[[0, 0]]], 1.0), "distinct"),
        (([[0.5]], [[[0, 0]]], [[0]], [[[0, 0]]], 1.0), "integers"),
        (([[0]], [[[np.nan, 0]]], [[0]], [[[0, 0]]], 1.0), "NaN"),
        (([[0]], [[[0, 0]]], [[0]], [[[0, 0, 0]]], 1.0), "dimension"),
    ],
)
def test_bad_input_raises(args, match):
    with pytest.raises(ValueError, match=match):
        clear_mot(*args)


def test_labelled_form_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="equal shapes"):
        clear_mot_labelled(np.zeros((3, 2, 2)), np.ones((3, 2)), np.zeros((3, 3, 2)),
                           np.ones((3, 3)), 1.0)
