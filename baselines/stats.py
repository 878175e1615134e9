"""Confidence intervals and honest ranks for the leaderboard.

A handful of episodes per (environment, agent) cannot say whether one agent
beats another unless the spread is reported with it. Every leaderboard cell
therefore carries a 95 % interval:

* success rates: the Wilson score interval (Wilson 1927; Brown, Cai and
  DasGupta 2001 recommend it for small n), from SciPy's ``binomtest``;
* continuous metrics: a percentile bootstrap interval of the mean (Efron and
  Tibshirani 1993), from SciPy's ``bootstrap`` with a fixed generator, so the
  same episodes always give the same interval.

Agents are ranked by success rate (tracking: the mean OSPA with its cut-off), best
first; a row's rank is one more than the number of rows that beat it: two rows differ,
when both were played on the same seeds, by a paired permutation test of the mean
per-seed difference at the 5 % level (what the seeds share cancels; on success rates
it is the exact McNemar test), otherwise by disjoint 95 % intervals.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
#: Bootstrap resamples; the interval's end points move by well under 1 % of
#: the spread between seeds of the generator at this size.
RESAMPLES = 4000
#: The bootstrap generator's seed: intervals are a function of the episodes alone.
BOOTSTRAP_SEED = 20261124


def wilson_interval(successes: int, n: int,
                    confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval of a success rate ``successes / n``.

    Raises:
        ValueError: ``n < 1`` or ``successes`` outside ``[0, n]``.
    """
    if n < 1 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n and n >= 1, got {successes}/{n}")
    interval = stats.binomtest(int(successes), int(n)).proportion_ci(
        confidence_level=confidence, method="wilson"
    )
    return float(interval.low), float(interval.high)


def bootstrap_interval(values: Sequence[float],
                       confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values``.

    One value has no interval: ``(nan, nan)``. Equal values give the point
    ``(v, v)`` (every resample has the same mean).
    """
    data = np.asarray(values, dtype=float)
    if data.size < 2:
        return math.nan, math.nan
    if np.ptp(data) == 0.0:
        return float(data[0]), float(data[0])
    result = stats.bootstrap(
        (data,), np.mean, confidence_level=confidence, n_resamples=RESAMPLES,
        method="percentile", rng=np.random.default_rng(BOOTSTRAP_SEED),
    )
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


#: What ranks an environment's agents: the first of these its rows report, with
#: the direction that is better. Tracking ranks by the mean OSPA with its cut-off (the
#: acoustic env's ``error_clip``, 5 m: a step's error counts at most that), so that one
#: divergent episode cannot make the order alone (``scripts/acoustic_rank_stability.py``,
#: ``docs/evaluation.md``); RMSE stays a column. The others rank by success rate.
RANK_METRICS = (("mean_ospa", "lower"), ("rmse", "lower"), ("success", "higher"))
#: The paired test's significance level (two-sided).
ALPHA = 1 - CONFIDENCE
#: Random sign flips of the paired test when there are more distinct ones (2**n).
PERMUTATIONS = 9999


def paired_p_value(a: Mapping, b: Mapping) -> float | None:
    """Two-sided p-value that ``a`` and ``b`` (seed -> value) have the same mean, by the
    paired permutation test: under the null each seed's two values are exchangeable, so
    the mean difference is referred to its distribution over sign flips of the per-seed
    differences (SciPy's ``permutation_test``, ``permutation_type="samples"``: exact up
    to 13 seeds whose values differ, else 9999 random flips from a fixed generator). On success
    rates it is the exact McNemar test. None unless both have the same seeds, at least
    two (rows played on different seeds are not paired)."""
    if set(a) != set(b) or len(a) < 2:
        return None
    seeds = sorted(a)
    x = np.array([a[s] for s in seeds], dtype=float)
    y = np.array([b[s] for s in seeds], dtype=float)
    # A seed whose two values are equal flips to itself: leaving it out changes no
    # permutation's standing, and makes the test exact up to 13 differing seeds.
    differ = x != y
    if np.count_nonzero(differ) < 2:
        return 1.0
    x, y = x[differ], y[differ]
    result = stats.permutation_test(
        (x, y), lambda u, v, axis: np.mean(u - v, axis=axis), permutation_type="samples",
        vectorized=True, n_resamples=PERMUTATIONS, alternative="two-sided",
        rng=np.random.default_rng(BOOTSTRAP_SEED),
    )
    return float(result.pvalue)


def overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two closed intervals ``(low, high)`` share a point."""
    return a[0] <= b[1] and b[0] <= a[1]


def differ(interval_a: Sequence[float], interval_b: Sequence[float],
           p_value: float | None = None) -> bool:
    """Whether two entries differ at 95 %: by the paired test's ``p_value`` (below
    :data:`ALPHA`) where they share seeds (:func:`paired_p_value`), otherwise by disjoint
    ``intervals``."""
    if p_value is not None:
        return p_value < ALPHA
    return not overlap(interval_a, interval_b)


def beaten_ranks(count: int, beats) -> list[tuple[int, bool]]:
    """Ranks of ``count`` entries already sorted best first.

    ``beats(j, i)`` (``j < i``) says whether entry ``j`` beats entry ``i`` significantly
    (:func:`differ`); an entry below never beats one above. An entry's rank is one more
    than the number of entries that beat it, and never less than one more than the rank
    of any of them: an entry never shares a rank with one that beats it, and ties do not
    chain (with 6/6, 4/6, 0/6 where only the first and last differ, the ranks are 1, 1,
    2). Returns ``(rank, tied)`` per entry; ``tied`` is True when another entry has the
    same rank.
    """
    ranks: list[int] = []
    for i in range(count):
        above = [j for j in range(i) if beats(j, i)]
        ranks.append(max([len(above) + 1, *(ranks[j] + 1 for j in above)]))
    return [(rank, ranks.count(rank) > 1) for rank in ranks]
