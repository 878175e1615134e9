"""Tracking metrics for the acoustic end-effector tracking task (SPEC §3, [GMPHD] §3.3-3.4).

Single-target trajectory metrics:

* :func:`position_errors`, :func:`rmse`, :func:`max_error`, :func:`count_missing`: per-step
  Euclidean error and its summaries ([GMPHD] §3.3, "Average / Maximum RMSE").
* :func:`assign_track_labels` and :func:`track_fragmentation_count`: the track
  fragmentation count (TFC, [GMPHD] §3.3).
* :func:`tcfe`: tracking-curve fluctuation entropy (TCFE, [GMPHD] §3.4).

Set metrics (any number of targets and estimates per step):

* :func:`ospa` and :func:`ospa_sequence`: OSPA (Schuhmacher, Vo & Vo, "A consistent metric for
  performance evaluation of multi-object filters", IEEE TSP 56(8), 2008, eq. 3).
* :func:`gospa`: GOSPA with its localisation / missed / false decomposition (Rahmathullah,
  García-Fernández & Svensson, "Generalized optimal sub-pattern assignment metric",
  FUSION 2017, arXiv:1601.05585, Definition 1 and Proposition 1).

Multi-object tracking ([LAMP] §3.2):

* :func:`clear_mot` and :func:`clear_mot_labelled`: CLEAR MOT (Bernardin & Stiefelhagen,
  EURASIP JIVP 2008): PRCN, RCLL, FP, FN, IDs, FM, MOTA, MOTP; py-motmetrics is its test oracle.

Everything is plain numpy/scipy; the Stone Soup implementations serve as the test oracle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

__all__ = [
    "NO_TRACK",
    "ClearMOT",
    "GOSPAResult",
    "assign_track_labels",
    "clear_mot",
    "clear_mot_labelled",
    "count_missing",
    "gospa",
    "max_error",
    "ospa",
    "ospa_sequence",
    "position_errors",
    "rmse",
    "tcfe",
    "track_fragmentation_count",
]

NO_TRACK = -1
"""Label meaning "no track assigned to the target at this step"."""


# --------------------------------------------------------------------------- validation


def _trajectory(x, name: str, *, allow_missing_rows: bool) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name} must be a non-empty (T, d) array, got shape {arr.shape}")
    if np.isinf(arr).any():
        raise ValueError(f"{name} contains infinite values")
    nan = np.isnan(arr)
    if nan.any():
        if not allow_missing_rows:
            raise ValueError(f"{name} contains NaN")
        partial = nan.any(axis=1) & ~nan.all(axis=1)
        if partial.any():
            raise ValueError(
                f"{name} has partially-NaN rows (first at step {int(np.argmax(partial))}); a "
                "missing estimate must be an all-NaN row"
            )
    return arr


def _pair(estimates, truth) -> tuple[np.ndarray, np.ndarray]:
    est = _trajectory(estimates, "estimates", allow_missing_rows=True)
    tru = _trajectory(truth, "truth", allow_missing_rows=False)
    if est.shape != tru.shape:
        raise ValueError(f"estimates shape {est.shape} != truth shape {tru.shape}")
    return est, tru


def _point_set(x, name: str) -> np.ndarray:
    """A finite point set as an (m, d) array; any empty input (size 0) is the empty set."""
    arr = np.asarray(x, dtype=np.float64)
    if arr.size == 0:
        if arr.ndim > 2:
            raise ValueError(f"{name} must be an (m, d) array, got shape {arr.shape}")
        return arr.reshape(0, arr.shape[1] if arr.ndim == 2 else 0)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be an (m, d) array, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _point_ids(ids, n_points: int, name: str, per: str, *,
               non_negative: bool = False) -> np.ndarray:
    """The integer ids of a point set: one per point, distinct (and >= 0 if asked).

    ``per`` names id and point in the error message (``"label per estimate"``).
    """
    lab = np.asarray(ids)
    if lab.size == 0:
        lab = lab.reshape(0).astype(np.int64)
    if lab.ndim != 1 or lab.shape[0] != n_points:
        raise ValueError(f"{name} must hold one {per} ({n_points})")
    if not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"{name} must be integers, got dtype {lab.dtype}")
    if (non_negative and (lab < 0).any()) or np.unique(lab).size != lab.size:
        kind = " non-negative integers" if non_negative else ""
        raise ValueError(f"{name} must be distinct{kind}")
    return lab


def _check_c_p(c: float, p: float) -> tuple[float, float]:
    c, p = float(c), float(p)
    if not (math.isfinite(c) and c > 0.0):
        raise ValueError(f"cutoff c must be finite and > 0, got {c}")
    if not (math.isfinite(p) and p >= 1.0):
        raise ValueError(f"order p must be finite and >= 1, got {p}")
    return c, p


def _cutoff_cost(X: np.ndarray, Y: np.ndarray, c: float, p: float) -> np.ndarray:
    """Matrix of d^(c)(x_i, y_j)^p = min(||x_i - y_j||, c)^p."""
    if X.shape[1] != Y.shape[1]:
        raise ValueError(f"point dimensions differ: {X.shape[1]} vs {Y.shape[1]}")
    return np.minimum(cdist(X, Y), c) ** p


# --------------------------------------------------------------------------- RMSE, max error


def position_errors(estimates, truth) -> np.ndarray:
    """Per-step Euclidean position error e_t = ||x̂_t - x_t||_2.

    Args:
        estimates: (T, d) estimated positions. A step without an estimate is an all-NaN row;
            partially-NaN rows are rejected.
        truth: (T, d) true positions, finite.

    Returns:
        (T,) errors in the units of the input, NaN exactly at the missing steps.

    Raises:
        ValueError: shapes differ, empty input, infinite values, NaN in ``truth`` or a
            partially-NaN estimate row.
    """
    est, tru = _pair(estimates, truth)
    return np.linalg.norm(est - tru, axis=1)


def count_missing(estimates) -> int:
    """Number of steps without an estimate (all-NaN rows of a (T, d) array)."""
    est = _trajectory(estimates, "estimates", allow_missing_rows=True)
    return int(np.isnan(est[:, 0]).sum())


def _present_errors(estimates, truth, allow_missing: bool) -> np.ndarray:
    err = position_errors(estimates, truth)
    missing = np.isnan(err)
    if missing.any():
        if not allow_missing:
            raise ValueError(
                f"{int(missing.sum())} of {err.size} steps have no estimate (first at step "
                f"{int(np.argmax(missing))}); pass allow_missing=True to score the remaining "
                "steps and report count_missing() alongside"
            )
        err = err[~missing]
        if err.size == 0:
            raise ValueError("every step is missing an estimate; nothing to score")
    return err


def rmse(estimates, truth, *, allow_missing: bool = False) -> float:
    """Root-mean-square position error over a trajectory ([GMPHD] §3.3).

    RMSE = sqrt( (1/|S|) Σ_{t∈S} ||x̂_t - x_t||² ), with S the scored steps.

    Missing estimates (all-NaN rows) are an error by default, so a tracker can never improve
    its score by withholding estimates unnoticed. With ``allow_missing=True`` S is the set of
    steps that have an estimate; report :func:`count_missing` next to the value.

    Args:
        estimates: (T, d) estimated positions; all-NaN row = no estimate at that step.
        truth: (T, d) true positions.
        allow_missing: score only the steps with an estimate instead of raising.

    Returns:
        The RMSE in the units of the input.

    Raises:
        ValueError: bad shapes or values (see :func:`position_errors`), missing estimates
            without ``allow_missing``, or no estimate at all.
    """
    err = _present_errors(estimates, truth, allow_missing)
    return float(np.sqrt(np.mean(err**2)))


def max_error(estimates, truth, *, allow_missing: bool = False) -> float:
    """Maximum per-step position error max_{t∈S} ||x̂_t - x_t||_2 ([GMPHD] §3.3, "Maximum").

    Missing estimates are handled exactly as in :func:`rmse`.
    """
    err = _present_errors(estimates, truth, allow_missing)
    return float(np.max(err))


# --------------------------------------------------------------------------- TFC


def _previous_index(last_ids: np.ndarray, ids: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Per object, the index in this frame's ``ids`` of the id it was last matched to, or -1.

    ``known`` marks the objects that have a last id (any integer, -1 included: CLEAR-MOT
    hypothesis ids may be negative, so ``NO_TRACK`` cannot mean "none" there).
    """
    out = np.full(last_ids.shape[0], -1, dtype=np.int64)
    for j in np.flatnonzero(known):
        k = np.flatnonzero(ids == last_ids[j])
        if k.size:
            out[j] = k[0]
    return out


def _match_frame(dist: np.ndarray, previous: np.ndarray, gate: float) -> np.ndarray:
    """CLEAR-MOT correspondence of one frame (Bernardin & Stiefelhagen 2008, §3.1).

    1. An object keeps its earlier hypothesis (index ``previous[i]`` in this frame, -1 for
       none) if that hypothesis is still free and within ``gate`` (distance <= gate).
    2. The remaining objects and hypotheses are matched by ``linear_sum_assignment`` on the
       distance; pairs farther than ``gate`` carry a large finite cost (so the solver first
       maximises the number of gated pairs) and are discarded afterwards.

    Args:
        dist: (n_objects, n_hypotheses) distances.
        previous: (n_objects,) index of each object's earlier hypothesis in this frame, or -1.
        gate: gating distance.

    Returns:
        (n_objects,) index of the matched hypothesis, or -1.
    """
    n_obj, n_hyp = dist.shape
    matched = np.full(n_obj, -1, dtype=np.int64)
    free_obj = np.ones(n_obj, dtype=bool)
    free_hyp = np.ones(n_hyp, dtype=bool)
    for i in np.flatnonzero(previous >= 0):
        k = previous[i]
        if free_hyp[k] and dist[i, k] <= gate:
            matched[i] = k
            free_obj[i] = free_hyp[k] = False
    oi, hk = np.flatnonzero(free_obj), np.flatnonzero(free_hyp)
    if oi.size and hk.size:
        sub = dist[np.ix_(oi, hk)]
        valid = sub <= gate
        big = gate * (min(sub.shape) + 1) + 1.0  # exceeds any sum of gated distances
        rows, cols = linear_sum_assignment(np.where(valid, sub, big))
        keep = valid[rows, cols]
        matched[oi[rows[keep]]] = hk[cols[keep]]
    return matched


def assign_track_labels(estimates: Sequence, labels: Sequence, truth, gate: float) -> np.ndarray:
    """Per-step label of the track assigned to each target, with a gating distance.

    The correspondence rule is CLEAR-MOT's (Bernardin & Stiefelhagen, EURASIP JIVP 2008,
    §3.1; also py-motmetrics' ``MOTAccumulator.update``), applied step by step:

    1. A target keeps the label it was last assigned (even across a gap) if a track with
       that label is present and within ``gate`` of the target (distance <= gate).
    2. The remaining targets and tracks are matched by ``linear_sum_assignment`` on the
       Euclidean distance; pairs farther than ``gate`` carry a large finite cost (so the
       solver first maximises the number of gated pairs) and are discarded afterwards.

    Args:
        estimates: length-T sequence; element t is a (k_t, d) array of estimated positions
            (k_t may be 0).
        labels: length-T sequence; element t holds the k_t non-negative integer track
            labels of those estimates (distinct within a step).
        truth: (T, d) positions of one target, or (T, N, d) for N targets.
        gate: gating distance, > 0.

    Returns:
        int array of shape (T,) (one target) or (T, N): the assigned label, or -1 when no
        track is within the gate.

    Raises:
        ValueError: mismatched lengths or shapes, non-finite values, negative or repeated
            labels, non-positive gate.
    """
    tru = np.asarray(truth, dtype=np.float64)
    single = tru.ndim == 2
    if single:
        tru = tru[:, None, :]
    if tru.ndim != 3 or tru.shape[0] == 0 or tru.shape[2] == 0:
        raise ValueError(f"truth must be (T, d) or (T, N, d), got shape {np.shape(truth)}")
    if not np.isfinite(tru).all():
        raise ValueError("truth contains NaN or infinite values")
    n_steps, n_targets, dim = tru.shape
    gate = float(gate)
    if not (math.isfinite(gate) and gate > 0.0):
        raise ValueError(f"gate must be finite and > 0, got {gate}")
    if len(estimates) != n_steps or len(labels) != n_steps:
        raise ValueError(
            f"estimates ({len(estimates)}) and labels ({len(labels)}) must have one entry "
            f"per truth step ({n_steps})"
        )

    out = np.full((n_steps, n_targets), NO_TRACK, dtype=np.int64)
    last = np.full(n_targets, NO_TRACK, dtype=np.int64)
    for t in range(n_steps):
        pts = _point_set(estimates[t], f"estimates[{t}]")
        lab = _point_ids(labels[t], pts.shape[0], f"labels[{t}]", "label per estimate",
                         non_negative=True)
        if pts.shape[0] == 0:
            continue
        if pts.shape[1] != dim:
            raise ValueError(f"estimates[{t}] has dimension {pts.shape[1]}, truth has {dim}")

        matched = _match_frame(cdist(tru[t], pts),
                               _previous_index(last, lab, last != NO_TRACK), gate)
        out[t, matched >= 0] = lab[matched[matched >= 0]]
        assigned = out[t] != NO_TRACK
        last[assigned] = out[t, assigned]
    return out[:, 0] if single else out


def track_fragmentation_count(assigned_labels) -> int:
    """Track fragmentation count (TFC): how often the track on a target is lost and re-initiated.

    [GMPHD] §3.3 defines TFC only in words. Here, per target, let ℓ_t be the label of the
    track assigned to it at step t (``None`` or -1: no track within the gate; see
    :func:`assign_track_labels`). An *event* is a step t with ℓ_t assigned such that the
    target was tracked before and either

    * ℓ_{t-1} is unassigned (the target is re-acquired after a gap, whatever the label), or
    * ℓ_{t-1} is assigned and ℓ_t ≠ ℓ_{t-1} (the track was replaced without a gap).

    TFC is the number of events, summed over targets. The first acquisition is not counted,
    nor is a loss that is never followed by re-acquisition. A gap followed by a different
    label counts once, not twice.

    Relation to py-motmetrics: its ``num_fragmentations`` counts, per ground-truth object,
    tracked -> missed transitions between the first and last tracked step, which equals the
    first bullet; the second bullet is the subset of its ``num_switches`` that happen without
    a gap. So TFC = num_fragmentations + (ID switches between consecutive tracked steps).

    Args:
        assigned_labels: length-T sequence of int labels with ``None`` or -1 for "no
            track", or a (T, N) integer array (-1 = no track) for N targets.

    Returns:
        The fragmentation count (int >= 0).

    Raises:
        ValueError: empty input, non-integer labels, labels < -1, or more than 2 dimensions.
    """
    seq = assigned_labels
    if not isinstance(seq, np.ndarray):
        seq = [NO_TRACK if v is None else v for v in seq]
    arr = np.asarray(seq)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise ValueError(f"assigned_labels must be (T,) or (T, N), got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"assigned_labels must be integers or None, got dtype {arr.dtype}")
    if (arr < NO_TRACK).any():
        raise ValueError("labels must be >= 0, or -1 / None for 'no track'")
    prev, cur = arr[:-1], arr[1:]
    tracked_before = np.maximum.accumulate(prev != NO_TRACK, axis=0)
    # cur != prev covers both bullets: a resumption (prev = -1) and a replacement.
    event = (cur != NO_TRACK) & tracked_before & (cur != prev)
    return int(event.sum())


# --------------------------------------------------------------------------- TCFE


def tcfe(estimates, *, bin_width: float = 0.01, num_bins: int | None = None,
         order: int = 1) -> float:
    """Tracking-curve fluctuation entropy (TCFE, [GMPHD] §3.4), in nats.

    [GMPHD] defines TCFE as "the information entropy of the sequence of differences between
    consecutive estimated positions" without a binning; this is the precise version used here.

    1. Step lengths s_t = ||Δ^order x̂_t||_2: with ``order=1`` (the default, the paper's
       literal reading) the differences of consecutive estimates, x̂_{t+1} - x̂_t (metres per
       sample step); with ``order=2`` the differences of those differences,
       x̂_{t+2} - 2 x̂_{t+1} + x̂_t, i.e. how far each step departs from repeating the
       previous one (the one-step error of a constant-velocity continuation of the curve).
       There are T - order of them.
    2. Histogram of bins of width w = ``bin_width``: bin k = floor(s_t / w), i.e.
       [k·w, (k+1)·w), k = 0, 1, 2, ... without an upper limit (the default,
       ``num_bins=None``), so an erratic track whose steps scatter over many bins scores
       high however large its jumps. With ``num_bins`` = K the last bin [(K-1)·w, ∞)
       collects every larger step instead (then jumps beyond it all look alike). A step
       within round-off of a bin edge may fall on either side of it.
    3. Normalisation: probabilities q_k = n_k / (T - order), the fraction of steps in bin k
       (they sum to 1). No normalisation by the number of bins is applied.
    4. TCFE = -Σ_{k: q_k>0} q_k ln q_k (natural log), in [0, ln(T - order)].

    Interpretation: with the defaults (1 cm bins, unbounded, order 1) and the 100 Hz
    measurement rate of SPEC §3, noise-free motion below 1 m/s keeps every step in bin 0
    (TCFE = 0). A track in which 1 % (2 %) of the steps jump into one other bin scores
    0.056 (0.098), the magnitude of [GMPHD]'s 0.05-0.09 for its own method; white jitter of
    1 cm per axis spreads the steps over several bins and scores about 1.4. TCFE depends on
    the sampling step and on the bin width: only compare values computed with the same ones,
    and at another rate choose ``bin_width`` at least twice the largest true displacement per
    step (v_max · Δt) so that the nominal motion stays in bin 0.
    Only step lengths enter, so a turn at constant speed does not raise it. With
    ``order=1`` a noise-free curve whose speed varies across a bin edge scores above 0 (its
    speed profile, not the tracker, is measured); ``order=2`` removes that: noise-free
    motion scores 0 while its acceleration stays below w / (2 Δt^2) (500 m/s^2 for 1 cm
    bins at 100 Hz), and only the fluctuation of the estimate is measured.

    Args:
        estimates: (T, d) estimated positions, T >= order + 1, finite (a trajectory with
            missing steps has no defined successive differences: score its contiguous
            segments).
        bin_width: bin width w in metres, > 0.
        num_bins: None (bins without limit, the default) or a number of bins K >= 2, the
            last one open-ended.
        order: 1 (differences of consecutive estimates) or 2 (differences of those).

    Returns:
        The entropy in nats.

    Raises:
        ValueError: T < order + 1, non-finite values, bin_width <= 0, num_bins < 2,
            order not 1 or 2.
    """
    if isinstance(order, bool) or order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    est = _trajectory(estimates, "estimates", allow_missing_rows=False)
    if est.shape[0] < order + 1:
        count = ("two", "three")[order - 1]
        raise ValueError(f"tcfe of order {order} needs at least {count} estimates")
    bin_width = float(bin_width)
    if not (math.isfinite(bin_width) and bin_width > 0.0):
        raise ValueError(f"bin_width must be finite and > 0, got {bin_width}")
    if num_bins is not None and (
        isinstance(num_bins, bool) or int(num_bins) != num_bins or num_bins < 2
    ):
        raise ValueError(f"num_bins must be None or an integer >= 2, got {num_bins}")
    steps = np.linalg.norm(np.diff(est, n=order, axis=0), axis=1)
    idx = np.floor(steps / bin_width)
    if num_bins is not None:
        idx = np.minimum(idx, num_bins - 1)
    _, counts = np.unique(idx, return_counts=True)
    q = counts / steps.size
    return float(-(q * np.log(q)).sum()) + 0.0  # + 0.0 turns -0.0 into 0.0


# --------------------------------------------------------------------------- OSPA, GOSPA


def ospa(X, Y, c: float, p: float) -> float:
    """OSPA distance of order p with cutoff c (Schuhmacher, Vo & Vo 2008, eq. 3).

    For X = {x_1..x_m}, Y = {y_1..y_n} with m <= n (swap otherwise), n > 0 and
    d^(c)(x, y) = min(||x - y||_2, c):

        OSPA = ( (1/n) [ min_π Σ_{i=1}^{m} d^(c)(x_i, y_π(i))^p + c^p (n - m) ] )^(1/p)

    where π ranges over injections of {1..m} into {1..n}; OSPA = 0 when m = n = 0 and c
    when exactly one set is empty. The minimum is found with ``linear_sum_assignment`` on
    the matrix of d^(c)(x_i, y_j)^p. The metric is symmetric in X and Y.

    Stone Soup (``OSPAMetric.compute_OSPA_distance``, 1.9.1) solves the assignment on
    d^(c) rather than on (d^(c))^p; for p > 1 that assignment can be sub-optimal, so its
    value is then >= this one (equal for p = 1 and whenever both assignments coincide).

    Args:
        X: (m, d) points (e.g. estimates); any size-0 array is the empty set.
        Y: (n, d) points (e.g. truth).
        c: cutoff, > 0.
        p: order, finite and >= 1.

    Returns:
        The OSPA distance, in [0, c].

    Raises:
        ValueError: non-finite points, shapes other than (m, d), different dimensions,
            c <= 0, p < 1 or p = inf.
    """
    c, p = _check_c_p(c, p)
    X, Y = _point_set(X, "X"), _point_set(Y, "Y")
    m, n = X.shape[0], Y.shape[0]
    if m and n:
        cost = _cutoff_cost(X, Y, c, p)
        rows, cols = linear_sum_assignment(cost)
        assigned = cost[rows, cols].sum()
    elif m == n == 0:
        return 0.0
    else:
        assigned = 0.0
    total = assigned + c**p * abs(m - n)
    return float((total / max(m, n)) ** (1.0 / p))


def ospa_sequence(Xs: Sequence, Ys: Sequence, c: float, p: float) -> np.ndarray:
    """OSPA at each time step: ``[ospa(Xs[t], Ys[t], c, p) for t]`` as a (T,) array."""
    if len(Xs) != len(Ys):
        raise ValueError(f"Xs ({len(Xs)}) and Ys ({len(Ys)}) must have the same length")
    return np.array([ospa(X, Y, c, p) for X, Y in zip(Xs, Ys, strict=True)], dtype=np.float64)


class GOSPAResult(NamedTuple):
    """GOSPA value and its decomposition (same keys and units as Stone Soup's GOSPA dict).

    ``localisation + missed + false == distance ** p``: the three terms are in units of
    distance^p and are not p-th rooted; only ``distance`` is.
    """

    distance: float
    """The GOSPA distance d_p^(c,α)(X, Y)."""
    localisation: float
    """Σ over assigned pairs of d(x, y)^p (cutoff distances for α < 2)."""
    missed: float
    """(c^p / α) · num_missed."""
    false: float
    """(c^p / α) · num_false."""
    num_missed: int
    """True points (Y) left unassigned."""
    num_false: int
    """Estimated points (X) left unassigned."""


def gospa(X, Y, c: float, p: float, alpha: float = 2.0) -> GOSPAResult:
    """GOSPA distance with its localisation / missed / false decomposition.

    Rahmathullah, García-Fernández & Svensson (2017), Definition 1: for |X| = m <= n = |Y|
    (swap otherwise) and d^(c)(x, y) = min(||x - y||_2, c),

        GOSPA = ( min_π Σ_{i=1}^{m} d^(c)(x_i, y_π(i))^p + (c^p / α)(n - m) )^(1/p).

    Unlike OSPA it is not normalised by max(m, n); GOSPA = 0 when both sets are empty.

    Decomposition (X = estimates, Y = truth). For α = 2 (Proposition 1) the minimiser is
    read as an assignment in which only pairs with d(x, y) < c count as assigned (a pair at
    or beyond the cutoff costs c^p = c^p/2 + c^p/2, a missed plus a false point):

        GOSPA^p = Σ_assigned d(x, y)^p + (c^p/2)(num_missed + num_false).

    This is Stone Soup's convention (``GOSPAMetric.compute_gospa_metric``): each missed and
    each false point costs c^p/2, the components are reported un-rooted, and
    distance = (localisation + missed + false)^(1/p). For α < 2 keeping a pair at the
    cutoff is cheaper than splitting it, so all min(m, n) pairs of the optimal injection are
    assigned, localisation sums their cutoff distances d^(c)^p, and the unmatched points
    cost c^p/α each. (Stone Soup fixes α = 2.)

    Args:
        X: (m, d) estimated points; any size-0 array is the empty set.
        Y: (n, d) true points.
        c: cutoff, > 0.
        p: order, finite and >= 1.
        alpha: α in (0, 2].

    Returns:
        :class:`GOSPAResult`.

    Raises:
        ValueError: non-finite points, shapes other than (m, d), different dimensions,
            c <= 0, p < 1 or p = inf, alpha outside (0, 2].
    """
    c, p = _check_c_p(c, p)
    alpha = float(alpha)
    if not (0.0 < alpha <= 2.0):
        raise ValueError(f"alpha must be in (0, 2], got {alpha}")
    X, Y = _point_set(X, "X"), _point_set(Y, "Y")
    m, n = X.shape[0], Y.shape[0]
    localisation, n_pairs = 0.0, 0
    if m and n:
        if X.shape[1] != Y.shape[1]:
            raise ValueError(f"point dimensions differ: {X.shape[1]} vs {Y.shape[1]}")
        dist = cdist(X, Y)
        cost = np.minimum(dist, c) ** p
        rows, cols = linear_sum_assignment(cost)
        keep = dist[rows, cols] < c if alpha == 2.0 else np.ones(rows.size, dtype=bool)
        localisation = float(cost[rows[keep], cols[keep]].sum())
        n_pairs = int(keep.sum())
    num_false, num_missed = m - n_pairs, n - n_pairs
    unit = c**p / alpha
    missed, false = unit * num_missed, unit * num_false
    distance = (localisation + missed + false) ** (1.0 / p)
    return GOSPAResult(float(distance), localisation, missed, false, num_missed, num_false)


# --------------------------------------------------------------------------- CLEAR MOT


class ClearMOT(NamedTuple):
    """CLEAR MOT summary (Bernardin & Stiefelhagen, EURASIP JIVP 2008, §2.1-2.2; [LAMP] §3.2).

    Ratios are fractions (multiply by 100 for percent); a ratio whose denominator is 0 is NaN.
    """

    prcn: float
    """Precision: matches / (matches + false positives)."""
    rcll: float
    """Recall: matches / ground-truth objects."""
    fp: int
    """False positives: hypotheses not matched to any object."""
    fn: int
    """False negatives (misses): objects not matched to any hypothesis."""
    ids: int
    """Identity switches: an object matched to a hypothesis other than its previous one."""
    fm: int
    """Fragmentations: an object's tracked -> missed transitions followed by tracking again."""
    mota: float
    """1 - (FN + FP + IDs) / ground-truth objects."""
    motp: float
    """Mean distance of the matched pairs (in the units of the points, e.g. pixels)."""
    num_objects: int
    """Ground-truth object occurrences summed over frames."""
    num_matches: int
    """Matched pairs summed over frames (switches included)."""


def _frame_set(ids, points, name: str, t: int) -> tuple[np.ndarray, np.ndarray]:
    pts = _point_set(points, f"{name}_points[{t}]")
    return _point_ids(ids, pts.shape[0], f"{name}_ids[{t}]", "id per point"), pts


def clear_mot(gt_ids: Sequence, gt_points: Sequence, hyp_ids: Sequence, hyp_points: Sequence,
              threshold: float) -> ClearMOT:
    """CLEAR MOT metrics of a multi-object tracker over a sequence of frames.

    The correspondence rule of Bernardin & Stiefelhagen (2008) §2.1, frame by frame:

    1. An object keeps the hypothesis it was last matched to (in any earlier frame) if that
       hypothesis is present, not yet taken, and within ``threshold`` (distance <= threshold).
       Objects are visited in the order given.
    2. The remaining objects and hypotheses are matched by ``linear_sum_assignment`` on the
       Euclidean distance; a pair beyond the threshold costs more than any set of valid pairs
       (so the number of matches is maximised first) and is dropped afterwards. A match in
       this step whose object was last matched to a different hypothesis is an ID switch.
    3. Unmatched objects are misses (FN), unmatched hypotheses false positives (FP).

    FM counts, per object and over the frames in which it is present, the runs of misses that
    lie between two tracked frames. These are the rules of py-motmetrics 1.4's
    ``MOTAccumulator`` (its default ``max_switch_time``), against which this is tested; give it
    Euclidean distances (``norm2squared_matrix`` returns squared ones), and its MOTP is then the
    mean distance reported here.

    Args:
        gt_ids: length-T sequence; element t holds the integer ids of the objects present in
            frame t (distinct within a frame; may be empty).
        gt_points: length-T sequence of (k_t, d) object positions.
        hyp_ids: length-T sequence of the tracker's hypothesis ids per frame.
        hyp_points: length-T sequence of (h_t, d) hypothesis positions.
        threshold: largest distance of a match, > 0 (e.g. pixels).

    Returns:
        :class:`ClearMOT`.

    Raises:
        ValueError: sequences of different lengths, ids that do not match the points, repeated
            or non-integer ids, non-finite points, different dimensions, bad threshold.
    """
    threshold = float(threshold)
    if not (math.isfinite(threshold) and threshold > 0.0):
        raise ValueError(f"threshold must be finite and > 0, got {threshold}")
    n_frames = len(gt_ids)
    if not (len(gt_points) == len(hyp_ids) == len(hyp_points) == n_frames):
        raise ValueError(
            f"gt_ids ({n_frames}), gt_points ({len(gt_points)}), hyp_ids ({len(hyp_ids)}) and "
            f"hyp_points ({len(hyp_points)}) must have one entry per frame"
        )
    last: dict[int, int] = {}  # object -> hypothesis it was last matched to
    tracked_runs: dict[int, list[bool]] = {}  # object -> tracked flag per frame present
    n_objects = n_matches = n_fp = n_fn = n_switches = 0
    total_distance = 0.0
    dim = None
    for t in range(n_frames):
        oids, opts = _frame_set(gt_ids[t], gt_points[t], "gt", t)
        hids, hpts = _frame_set(hyp_ids[t], hyp_points[t], "hyp", t)
        for pts in (opts, hpts):
            if pts.shape[0]:
                dim = pts.shape[1] if dim is None else dim
                if pts.shape[1] != dim:
                    raise ValueError(f"frame {t}: points of dimension {pts.shape[1]}, not {dim}")
        n_objects += oids.size
        matched_hyp = np.full(oids.size, -1)
        if oids.size and hids.size:
            known = np.array([o in last for o in oids.tolist()], dtype=bool)
            previous = np.array([last.get(o, 0) for o in oids.tolist()], dtype=np.int64)
            matched_hyp = _match_frame(cdist(opts, hpts), _previous_index(previous, hids, known),
                                       threshold)
            # A match to another hypothesis than the object's last one is a switch (a kept
            # correspondence never is).
            for i in np.flatnonzero(matched_hyp >= 0):
                n_switches += int(known[i] and previous[i] != hids[matched_hyp[i]])
        for i, o in enumerate(oids.tolist()):
            k = matched_hyp[i]
            tracked_runs.setdefault(o, []).append(k >= 0)
            if k >= 0:
                last[o] = int(hids[k])
                total_distance += float(np.linalg.norm(opts[i] - hpts[k]))
        n_match_frame = int((matched_hyp >= 0).sum())
        n_matches += n_match_frame
        n_fn += oids.size - n_match_frame
        n_fp += hids.size - n_match_frame
    n_fragments = 0
    for flags in tracked_runs.values():
        f = np.asarray(flags)
        # A tracked -> missed step before the last tracked frame starts a fragment.
        if f.any():
            span = f[: int(np.flatnonzero(f)[-1]) + 1]
            n_fragments += int(np.sum(span[:-1] & ~span[1:]))

    def ratio(num: float, den: float) -> float:
        return num / den if den else math.nan

    return ClearMOT(
        prcn=ratio(n_matches, n_matches + n_fp),
        rcll=ratio(n_matches, n_objects),
        fp=n_fp,
        fn=n_fn,
        ids=n_switches,
        fm=n_fragments,
        mota=1.0 - ratio(n_fn + n_fp + n_switches, n_objects) if n_objects else math.nan,
        motp=ratio(total_distance, n_matches),
        num_objects=n_objects,
        num_matches=n_matches,
    )


def clear_mot_labelled(true_points, true_visible, est_points, est_visible,
                       threshold: float) -> ClearMOT:
    """:func:`clear_mot` for a fixed set of labelled objects, each with one labelled track.

    The shape of the docking envs' ``info["true_pixels"]`` / ``info["true_visible"]`` and of a
    ``features`` observation's ``pixels`` / ``visible``: object k and hypothesis k both carry id
    k, so a hypothesis that lands on another object is an ID switch.

    Args:
        true_points: (T, n, d) object positions (ignored where not visible).
        true_visible: (T, n) bool, whether object k is present in frame t.
        est_points: (T, n, d) tracked positions (ignored where not reported).
        est_visible: (T, n) bool, whether the tracker reports object k in frame t.
        threshold: largest distance of a match, > 0.

    Raises:
        ValueError: shapes that differ or are not (T, n, d) / (T, n); non-finite values where
            visible; see :func:`clear_mot`.
    """
    tp, ep = np.asarray(true_points, float), np.asarray(est_points, float)
    tv, ev = np.asarray(true_visible), np.asarray(est_visible)
    if tp.ndim != 3 or tp.shape != ep.shape or tv.shape != tp.shape[:2] or ev.shape != tv.shape:
        raise ValueError(
            f"need true/est points (T, n, d) and visibility (T, n) of equal shapes, got "
            f"{tp.shape}, {ep.shape}, {tv.shape}, {ev.shape}"
        )
    tv, ev = tv.astype(bool), ev.astype(bool)
    ids = np.arange(tp.shape[1])
    return clear_mot(
        [ids[m] for m in tv], [p[m] for p, m in zip(tp, tv, strict=True)],
        [ids[m] for m in ev], [p[m] for p, m in zip(ep, ev, strict=True)],
        threshold,
    )


def box_iou(a, b) -> np.ndarray | float:
    """Intersection over union of axis-aligned boxes ``(x0, y0, x1, y1)``, row by row.

    The overlap measure of OTB's one-pass evaluation (Wu, Lim & Yang, CVPR 2013).
    ``a`` and ``b`` are (N, 4) arrays (or single (4,) boxes, giving a float); a
    row where either box is NaN (a tracker that reports no box) scores 0.
    """
    a2 = np.atleast_2d(np.asarray(a, dtype=np.float64))
    b2 = np.atleast_2d(np.asarray(b, dtype=np.float64))
    if a2.shape[-1] != 4 or b2.shape[-1] != 4:
        raise ValueError(f"boxes must be (N, 4) or (4,), got {np.shape(a)} and {np.shape(b)}")
    x0 = np.maximum(a2[:, 0], b2[:, 0])
    y0 = np.maximum(a2[:, 1], b2[:, 1])
    x1 = np.minimum(a2[:, 2], b2[:, 2])
    y1 = np.minimum(a2[:, 3], b2[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area_a = (a2[:, 2] - a2[:, 0]) * (a2[:, 3] - a2[:, 1])
    area_b = (b2[:, 2] - b2[:, 0]) * (b2[:, 3] - b2[:, 1])
    out = np.nan_to_num(inter / (area_a + area_b - inter), nan=0.0)
    return float(out[0]) if np.ndim(a) == 1 and np.ndim(b) == 1 else out
