"""Tests for :mod:`auv_envs.metrics`.

OSPA and GOSPA are checked against Stone Soup (an independent implementation, test-only
dependency) on random sets, and against hand-worked values and brute force; RMSE, TFC and
TCFE against hand-worked cases.
"""

from __future__ import annotations

import datetime
import itertools
import math

import numpy as np
import pytest

from auv_envs import metrics

stonesoup_ospa = pytest.importorskip("stonesoup.metricgenerator.ospametric")
stonesoup_state = pytest.importorskip("stonesoup.types.state")

_T0 = datetime.datetime(2024, 1, 1)


def _states(points: np.ndarray) -> list:
    return [stonesoup_state.State(pt.reshape(-1, 1), timestamp=_T0) for pt in points]


def _random_cases(seed: int, n_cases: int, dim: int = 3):
    """Random (X, Y, c, p): cardinalities 0..6 (never both empty), clustered or spread."""
    rng = np.random.default_rng(seed)
    cases = []
    while len(cases) < n_cases:
        m, n = (int(k) for k in rng.integers(0, 7, size=2))
        if m == n == 0:
            continue
        scale = rng.choice([1.0, 5.0, 20.0])
        X = rng.uniform(-scale, scale, (m, dim))
        Y = rng.uniform(-scale, scale, (n, dim))
        c = float(rng.choice([0.5, 2.0, 7.5, 100.0]))
        p = float(rng.choice([1.0, 1.5, 2.0, 3.0]))
        cases.append((X, Y, c, p))
    return cases


def _brute_force_ospa(X, Y, c, p):
    if len(X) > len(Y):
        X, Y = Y, X
    m, n = len(X), len(Y)
    if n == 0:
        return 0.0
    best = min(
        sum(min(np.linalg.norm(X[i] - Y[j]), c) ** p for i, j in enumerate(perm))
        for perm in itertools.permutations(range(n), m)
    )
    return ((best + c**p * (n - m)) / n) ** (1 / p)


# --------------------------------------------------------------------------- OSPA


@pytest.mark.parametrize("dim", [2, 3])
def test_ospa_equals_stonesoup_ospa_for_p1(dim):
    cases = [case for case in _random_cases(1 + dim, 300, dim) if case[3] == 1.0]
    assert len(cases) > 50
    for X, Y, c, p in cases:
        expected = (
            stonesoup_ospa.OSPAMetric(c=c, p=p).compute_OSPA_distance(_states(X), _states(Y)).value
        )
        assert metrics.ospa(X, Y, c, p) == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_ospa_equals_stonesoup_via_gospa_alpha1_for_all_p():
    # With alpha = 1, GOSPA^p = max(m, n) * OSPA^p (Rahmathullah et al. 2017, §II-B). Stone
    # Soup's GOSPA assigns on the p-th powers (unlike its OSPA, see the next test), so it is
    # an exact oracle for every p. Its alpha is fixed to 2 in __init__; set it after.
    for X, Y, c, p in _random_cases(7, 300):
        oracle = stonesoup_ospa.GOSPAMetric(c=c, p=p)
        oracle.alpha = 1
        g = oracle.compute_gospa_metric(_states(X), _states(Y))[0].value["distance"]
        expected = (g**p / max(len(X), len(Y))) ** (1 / p)
        assert metrics.ospa(X, Y, c, p) == pytest.approx(expected, rel=1e-10, abs=1e-12)


def test_ospa_is_at_most_stonesoup_ospa_and_equals_brute_force():
    n_lower = 0
    for X, Y, c, p in _random_cases(11, 250):
        ours = metrics.ospa(X, Y, c, p)
        theirs = (
            stonesoup_ospa.OSPAMetric(c=c, p=p).compute_OSPA_distance(_states(X), _states(Y)).value
        )
        assert ours <= theirs + 1e-12
        n_lower += ours < theirs - 1e-9
        if min(len(X), len(Y)) <= 5 and max(len(X), len(Y)) <= 6:
            assert ours == pytest.approx(_brute_force_ospa(X, Y, c, p), rel=1e-12, abs=1e-12)
    # Stone Soup's sub-optimal assignment for p > 1 is the exception, not the rule.
    assert 0 < n_lower < 25


def test_ospa_stonesoup_difference_hand_worked():
    # Distances: x1-y1 = sqrt(2), x2-y2 = 5 (sum 6.41, squares 27);
    #            x1-y2 = sqrt(5), x2-y1 = sqrt(20) (sum 6.71, squares 25).
    # OSPA (p = 2) minimises the squares: sqrt(25 / 2). Stone Soup minimises the plain sum
    # and reports sqrt(27 / 2).
    X = np.array([[2.0, 3.0], [3.0, 0.0]])
    Y = np.array([[1.0, 4.0], [0.0, 4.0]])
    assert metrics.ospa(X, Y, c=10.0, p=2.0) == pytest.approx(math.sqrt(12.5), rel=1e-12)
    theirs = (
        stonesoup_ospa.OSPAMetric(c=10.0, p=2.0).compute_OSPA_distance(_states(X), _states(Y)).value
    )
    assert theirs == pytest.approx(math.sqrt(13.5), rel=1e-12), (
        "Stone Soup now assigns on d^p: drop the caveat in metrics.ospa's docstring"
    )


def test_ospa_hand_worked():
    empty = np.zeros((0, 3))
    one = np.array([[0.0, 0.0, 0.0]])
    assert metrics.ospa(empty, empty, c=2.0, p=2.0) == 0.0
    assert metrics.ospa([], one, c=2.0, p=2.0) == 2.0
    assert metrics.ospa(one, empty, c=2.0, p=1.0) == 2.0
    # One pair at distance 1 and one unmatched point: ((1^2 + 2^2) / 2)^(1/2).
    Y = np.array([[1.0, 0.0, 0.0], [50.0, 0.0, 0.0]])
    assert metrics.ospa(one, Y, c=2.0, p=2.0) == pytest.approx(math.sqrt(2.5), rel=1e-12)
    # Beyond the cutoff a pair costs c: p = 1, ((2 + 2) / 2).
    assert metrics.ospa(one, Y * 10, c=2.0, p=1.0) == pytest.approx(2.0, rel=1e-12)
    assert metrics.ospa(Y, one, c=2.0, p=2.0) == metrics.ospa(one, Y, c=2.0, p=2.0)


def test_ospa_sequence_is_per_step_ospa():
    cases = _random_cases(3, 20)
    Xs, Ys = [case[0] for case in cases], [case[1] for case in cases]
    got = metrics.ospa_sequence(Xs, Ys, c=3.0, p=2.0)
    assert got.shape == (20,)
    np.testing.assert_allclose(
        got, [metrics.ospa(X, Y, 3.0, 2.0) for X, Y in zip(Xs, Ys, strict=True)]
    )
    with pytest.raises(ValueError, match="same length"):
        metrics.ospa_sequence(Xs, Ys[:-1], c=3.0, p=2.0)


# --------------------------------------------------------------------------- GOSPA


@pytest.mark.parametrize("dim", [2, 3])
def test_gospa_equals_stonesoup_gospa_with_decomposition(dim):
    for X, Y, c, p in _random_cases(20 + dim, 300, dim):
        expected = (
            stonesoup_ospa.GOSPAMetric(c=c, p=p)
            .compute_gospa_metric(_states(X), _states(Y))[0]
            .value
        )
        got = metrics.gospa(X, Y, c, p)
        for key in ("distance", "localisation", "missed", "false"):
            assert getattr(got, key) == pytest.approx(expected[key], rel=1e-10, abs=1e-10), key
        unit = c**p / 2
        assert got.missed == pytest.approx(unit * got.num_missed)
        assert got.false == pytest.approx(unit * got.num_false)
        assert got.localisation + got.missed + got.false == pytest.approx(got.distance**p)


@pytest.mark.parametrize("alpha", [0.5, 1.0, 1.7])
def test_gospa_other_alpha_equals_stonesoup_total(alpha):
    # Stone Soup fixes alpha = 2 and only decomposes for it; its total is the general
    # formula for any alpha once the attribute is overridden.
    for X, Y, c, p in _random_cases(31, 150):
        oracle = stonesoup_ospa.GOSPAMetric(c=c, p=p)
        oracle.alpha = alpha
        expected = oracle.compute_gospa_metric(_states(X), _states(Y))[0].value["distance"]
        got = metrics.gospa(X, Y, c, p, alpha=alpha)
        assert got.distance == pytest.approx(expected, rel=1e-10, abs=1e-12)
        assert got.num_missed == max(len(Y) - len(X), 0)
        assert got.num_false == max(len(X) - len(Y), 0)


def test_gospa_hand_worked():
    empty = np.zeros((0, 2))
    assert metrics.gospa(empty, empty, c=1.0, p=2.0) == (0.0, 0.0, 0.0, 0.0, 0, 0)
    # X = estimates, Y = truth. One estimate 0.5 from a truth point, one truth point far
    # away (missed), one estimate far away (false); p = 2, c = 2:
    # localisation 0.25, missed 4/2, false 4/2, distance sqrt(4.25).
    X = np.array([[0.0, 0.0], [-30.0, 0.0]])
    Y = np.array([[0.5, 0.0], [30.0, 0.0]])
    got = metrics.gospa(X, Y, c=2.0, p=2.0)
    assert got.localisation == pytest.approx(0.25)
    assert (got.missed, got.false, got.num_missed, got.num_false) == (2.0, 2.0, 1, 1)
    assert got.distance == pytest.approx(math.sqrt(4.25))
    # alpha = 1 keeps the far pair at the cutoff: 0.25 + 4, nothing missed or false.
    got1 = metrics.gospa(X, Y, c=2.0, p=2.0, alpha=1.0)
    assert (got1.num_missed, got1.num_false) == (0, 0)
    assert got1.localisation == pytest.approx(4.25)
    assert got1.distance == pytest.approx(math.sqrt(4.25))
    # Three estimates, no truth: 3 false, alpha = 2, p = 1: 3 * 2 / 2.
    got = metrics.gospa(np.ones((3, 2)), empty, c=2.0, p=1.0)
    assert (got.distance, got.false, got.num_false, got.missed) == (3.0, 3.0, 3, 0.0)


# --------------------------------------------------------------------------- set-metric input


@pytest.mark.parametrize("fn", [metrics.ospa, metrics.gospa])
@pytest.mark.parametrize(
    ("X", "Y", "c", "p", "match"),
    [
        (np.zeros((2, 3)), np.zeros((2, 3)), 0.0, 2.0, "cutoff c"),
        (np.zeros((2, 3)), np.zeros((2, 3)), -1.0, 2.0, "cutoff c"),
        (np.zeros((2, 3)), np.zeros((2, 3)), math.inf, 2.0, "cutoff c"),
        (np.zeros((2, 3)), np.zeros((2, 3)), 1.0, 0.5, "order p"),
        (np.zeros((2, 3)), np.zeros((2, 3)), 1.0, math.inf, "order p"),
        (np.zeros((2, 3)), np.zeros((2, 2)), 1.0, 2.0, "dimensions differ"),
        (np.full((2, 3), np.nan), np.zeros((2, 3)), 1.0, 2.0, "NaN"),
        (np.zeros((2, 3)), np.array([[0.0, np.inf, 0.0]]), 1.0, 2.0, "NaN or infinite"),
        (np.zeros(3), np.zeros((2, 3)), 1.0, 2.0, r"\(m, d\)"),
        (np.zeros((1, 2, 3)), np.zeros((2, 3)), 1.0, 2.0, r"\(m, d\)"),
    ],
)
def test_set_metrics_reject_bad_input(fn, X, Y, c, p, match):
    with pytest.raises(ValueError, match=match):
        fn(X, Y, c, p)


@pytest.mark.parametrize("alpha", [0.0, -1.0, 2.5, math.nan])
def test_gospa_rejects_alpha_outside_0_2(alpha):
    with pytest.raises(ValueError, match="alpha"):
        metrics.gospa(np.zeros((1, 2)), np.zeros((1, 2)), c=1.0, p=2.0, alpha=alpha)


# --------------------------------------------------------------------------- RMSE


def test_rmse_and_max_error_hand_worked():
    truth = np.zeros((3, 3))
    est = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(metrics.position_errors(est, truth), [0.0, 5.0, 1.0])
    assert metrics.rmse(est, truth) == pytest.approx(math.sqrt(26 / 3), rel=1e-12)
    assert metrics.max_error(est, truth) == 5.0
    assert metrics.count_missing(est) == 0


def test_missing_estimates_raise_unless_allowed_and_are_counted():
    truth = np.zeros((4, 3))
    est = np.array([[1.0, 0.0, 0.0], [np.nan] * 3, [0.0, 3.0, 0.0], [np.nan] * 3])
    with pytest.raises(ValueError, match="2 of 4 steps have no estimate"):
        metrics.rmse(est, truth)
    with pytest.raises(ValueError, match="no estimate"):
        metrics.max_error(est, truth)
    assert metrics.count_missing(est) == 2
    assert metrics.rmse(est, truth, allow_missing=True) == pytest.approx(math.sqrt(5.0))
    assert metrics.max_error(est, truth, allow_missing=True) == 3.0
    err = metrics.position_errors(est, truth)
    np.testing.assert_array_equal(np.isnan(err), [False, True, False, True])
    with pytest.raises(ValueError, match="every step"):
        metrics.rmse(np.full((2, 3), np.nan), np.zeros((2, 3)), allow_missing=True)


@pytest.mark.parametrize("fn", [metrics.rmse, metrics.max_error, metrics.position_errors])
@pytest.mark.parametrize(
    ("est", "truth", "match"),
    [
        (np.zeros((3, 3)), np.zeros((4, 3)), "shape"),
        (np.zeros((3, 3)), np.zeros((3, 2)), "shape"),
        (np.zeros(3), np.zeros(3), r"\(T, d\)"),
        (np.zeros((0, 3)), np.zeros((0, 3)), r"\(T, d\)"),
        (np.zeros((2, 3)), np.array([[0.0, 0.0, np.nan], [0.0, 0.0, 0.0]]), "truth contains NaN"),
        (np.array([[0.0, np.nan, 0.0], [0.0, 0.0, 0.0]]), np.zeros((2, 3)), "partially-NaN"),
        (np.array([[0.0, np.inf, 0.0]]), np.zeros((1, 3)), "infinite"),
    ],
)
def test_trajectory_errors_reject_bad_input(fn, est, truth, match):
    with pytest.raises(ValueError, match=match):
        fn(est, truth)


# --------------------------------------------------------------------------- TFC


@pytest.mark.parametrize(
    ("labels", "expected"),
    [
        ([None, None, 1, 1, 1], 0),  # first acquisition is not a fragment
        ([1, 1, None, None, 1, 1], 1),  # lost, re-acquired with the same label
        ([1, 1, 2, 2], 1),  # track replaced without a gap
        ([1, None, 2], 1),  # gap and new label: one event, not two
        ([1, 1, None, None], 0),  # a final loss is never re-initiated
        ([-1, 3, 3, -1, 3, 5, 5, -1, -1, 7, 7, -1], 3),
        ([None, None], 0),
        ([4], 0),
    ],
)
def test_track_fragmentation_count_hand_worked(labels, expected):
    assert metrics.track_fragmentation_count(labels) == expected
    as_array = np.array([-1 if v is None else v for v in labels])
    assert metrics.track_fragmentation_count(as_array) == expected


def test_track_fragmentation_count_sums_over_targets():
    labels = np.array([[1, -1], [1, 2], [-1, 3], [1, 3]])  # target 0: 1 gap; target 1: 1 switch
    assert metrics.track_fragmentation_count(labels) == 2


@pytest.mark.parametrize(
    ("labels", "match"),
    [
        ([], r"\(T,\)"),
        ([1.5, 2.0], "integers"),
        ([1, -2], ">= 0"),
        (np.zeros((2, 2, 2), int), "shape"),
    ],
)
def test_track_fragmentation_count_rejects_bad_input(labels, match):
    with pytest.raises(ValueError, match=match):
        metrics.track_fragmentation_count(labels)


def test_assign_track_labels_single_target_gate_and_continuation():
    truth = np.array([[float(t), 0.0, 0.0] for t in range(6)])
    estimates = [
        [[0.1, 0.0, 0.0], [5.0, 5.0, 5.0]],
        [[1.2, 0.0, 0.0]],
        [[2.9, 0.0, 0.0]],  # 0.9 from the target: outside the 0.5 gate
        # Track 4 still within the gate keeps the target although track 6 is closer.
        [[3.1, 0.0, 0.0], [3.0, 0.0, 0.05]],
        np.zeros((0, 3)),
        [[5.0, 0.0, 0.0]],
    ]
    labels = [[4, 9], [4], [4], [4, 6], [], [6]]
    got = metrics.assign_track_labels(estimates, labels, truth, gate=0.5)
    np.testing.assert_array_equal(got, [4, 4, -1, 4, -1, 6])
    assert metrics.track_fragmentation_count(got) == 2
    # Without a previous correspondence the nearest track wins.
    got = metrics.assign_track_labels(estimates[3:4], labels[3:4], truth[3:4], gate=0.5)
    np.testing.assert_array_equal(got, [6])


def test_assign_track_labels_maximises_gated_matches():
    # Raw-distance assignment would pair A-1 (0.05) with B-2 (0.71 > gate) and leave B
    # untracked; gating with a large finite cost pairs A-2 (0.5) and B-1 (0.45).
    truth = np.array([[[0.0, 0.0], [0.5, 0.0]]])
    estimates = [np.array([[0.05, 0.0], [0.0, 0.5]])]
    got = metrics.assign_track_labels(estimates, [np.array([1, 2])], truth, gate=0.6)
    assert got.shape == (1, 2)
    np.testing.assert_array_equal(got, [[2, 1]])


@pytest.mark.parametrize(
    ("estimates", "labels", "gate", "match"),
    [
        ([[[0.0, 0.0]]], [[1]], 0.0, "gate"),
        ([[[0.0, 0.0]]], [[1]], math.nan, "gate"),
        ([[[0.0, 0.0]], [[0.0, 0.0]]], [[1], [1]], 1.0, "one entry per truth step"),
        ([[[0.0, 0.0]]], [[1, 2]], 1.0, "one label per estimate"),
        ([[[0.0, 0.0], [1.0, 0.0]]], [[1, 1]], 1.0, "distinct"),
        ([[[0.0, 0.0]]], [[-1]], 1.0, "non-negative"),
        ([[[0.0, 0.0]]], [[1.0]], 1.0, "integers"),
        ([[[0.0, 0.0, 0.0]]], [[1]], 1.0, "dimension"),
        ([[[np.nan, 0.0]]], [[1]], 1.0, "NaN"),
    ],
)
def test_assign_track_labels_rejects_bad_input(estimates, labels, gate, match):
    with pytest.raises(ValueError, match=match):
        metrics.assign_track_labels(estimates, labels, np.zeros((1, 2)), gate=gate)


# --------------------------------------------------------------------------- TCFE


def test_tcfe_hand_worked_bins():
    # Bins of width 1 m, 4 bins: [0,1) [1,2) [2,3) [3,inf).
    # Steps 0.5, 0.5, 1.5, 0.25, 5.0 -> bins 0, 0, 1, 0, 3 -> q = (3/5, 1/5, 0, 1/5).
    x = np.array([0.0, 0.5, 1.0, 2.5, 2.75, 7.75])[:, None]
    expected = -(0.6 * math.log(0.6) + 2 * 0.2 * math.log(0.2))
    assert metrics.tcfe(x, bin_width=1.0, num_bins=4) == pytest.approx(expected, rel=1e-12)
    # Step lengths are Euclidean in 3-D: 0.5 and 1.3 -> two bins, equally likely: ln 2.
    x3 = np.array([[0.0, 0.0, 0.0], [0.3, 0.4, 0.0], [0.3, 0.4, 1.3]])
    assert metrics.tcfe(x3, bin_width=1.0, num_bins=4) == pytest.approx(math.log(2))
    # The last bin is open-ended: steps of 10 and 100 share it.
    assert metrics.tcfe(np.array([[0.0], [10.0], [110.0]]), bin_width=1.0, num_bins=2) == 0.0
    assert metrics.tcfe(np.array([[0.0], [10.0], [10.5]]), bin_width=1.0, num_bins=2) == (
        pytest.approx(math.log(2))
    )


def test_tcfe_default_bins_have_no_upper_limit():
    # Jumps of tens of metres scatter over many 1 cm bins: an erratic track
    # must not look smooth because its steps exceed a last, open-ended bin.
    rng = np.random.default_rng(3)
    jumps = rng.uniform(0.0, 300.0, (500, 3))
    assert metrics.tcfe(jumps) > math.log(400)
    assert metrics.tcfe(jumps, num_bins=50) == 0.0  # every step in the overflow bin


def test_tcfe_defaults_small_for_smooth_large_for_erratic():
    # 100 steps of 5 mm (0.5 m/s at 100 Hz) with 1 % of steps jumping 2.5 cm:
    # -(0.99 ln 0.99 + 0.01 ln 0.01) = 0.056, the size of [GMPHD]'s values.
    steps = np.full(100, 0.005)
    steps[40] = 0.025
    x = np.stack([np.concatenate([[0.0], np.cumsum(steps)]), np.zeros(101), np.zeros(101)], 1)
    assert metrics.tcfe(x) == pytest.approx(-(0.99 * math.log(0.99) + 0.01 * math.log(0.01)))
    assert metrics.tcfe(x[:41]) == 0.0  # constant speed

    rng = np.random.default_rng(0)
    t = np.arange(2000) * 0.01
    truth = np.stack([2 * np.sin(0.2 * t), 1.5 * np.cos(0.15 * t), 0.3 * t], axis=1)
    smooth = metrics.tcfe(truth + rng.normal(0.0, 0.001, truth.shape))
    erratic = metrics.tcfe(truth + rng.normal(0.0, 0.02, truth.shape))
    assert smooth < 0.1
    assert erratic > 1.0


@pytest.mark.parametrize(
    ("x", "kwargs", "match"),
    [
        (np.zeros((1, 3)), {}, "at least two"),
        (np.zeros(5), {}, r"\(T, d\)"),
        (np.array([[0.0, 0.0], [np.nan, np.nan]]), {}, "NaN"),
        (np.zeros((3, 2)), {"bin_width": 0.0}, "bin_width"),
        (np.zeros((3, 2)), {"bin_width": -0.1}, "bin_width"),
        (np.zeros((3, 2)), {"num_bins": 1}, "num_bins"),
        (np.zeros((3, 2)), {"num_bins": 2.5}, "num_bins"),
    ],
)
def test_tcfe_rejects_bad_input(x, kwargs, match):
    with pytest.raises(ValueError, match=match):
        metrics.tcfe(x, **kwargs)


def test_box_iou_hand_worked_and_nan_boxes_score_zero():
    a = np.array([[0.0, 0.0, 2.0, 2.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0]])
    b = np.array([[1.0, 1.0, 3.0, 3.0], [0.0, 0.0, 1.0, 1.0], [np.nan] * 4])
    np.testing.assert_allclose(metrics.box_iou(a, b), [1.0 / 7.0, 1.0, 0.0])
    assert metrics.box_iou([0, 0, 1, 1], [2, 2, 3, 3]) == 0.0
    with pytest.raises(ValueError, match="boxes"):
        metrics.box_iou([0, 0, 1], [0, 0, 1, 1])


def test_clear_mot_hypothesis_id_minus_one_is_an_ordinary_id():
    """Hypothesis ids may be any integers: -1 (``NO_TRACK`` elsewhere) is kept by rule 1
    like any other id, and leaving it for another hypothesis is a switch (py-motmetrics 1.4
    gives the same: ids 0, MOTP 0.2333 for the first case)."""
    gt_ids = [[0], [0], [0]]
    gt = [[[0.0, 0.0]]] * 3
    kept = metrics.clear_mot(gt_ids, gt, [[-1], [5, -1], [5, -1]],
                             [[[0.1, 0.0]], [[0.0, 0.0], [0.3, 0.0]], [[0.0, 0.0], [0.3, 0.0]]],
                             1.0)
    assert (kept.ids, kept.fp, kept.num_matches) == (0, 2, 3)
    assert kept.motp == pytest.approx((0.1 + 0.3 + 0.3) / 3)
    switched = metrics.clear_mot(gt_ids, gt, [[-1], [5], [5]],
                                 [[[0.1, 0.0]], [[0.2, 0.0]], [[0.2, 0.0]]], 1.0)
    assert switched.ids == 1
