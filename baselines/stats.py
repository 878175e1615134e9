"""Confidence intervals and honest ranks for the leaderboard.

A handful of episodes per (environment, agent) cannot say whether one agent
beats another unless the spread is reported with it. Every leaderboard cell
therefore carries a 95 % interval:

* success rates: the Wilson score interval (Wilson 1927; Brown, Cai and
  DasGupta 2001 recommend it for small n), from SciPy's ``binomtest``;
* continuous metrics: a percentile bootstrap interval of the mean (Efron and
  Tibshirani 1993), from SciPy's ``bootstrap`` with a fixed generator, so the
  same episodes always give the same interval.

Agents are ranked by success rate; two agents whose success intervals overlap
share a rank (a tie).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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


def overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two closed intervals ``(low, high)`` share a point."""
    return a[0] <= b[1] and b[0] <= a[1]


def tied_ranks(intervals: Sequence[Sequence[float]]) -> list[tuple[int, bool]]:
    """Ranks of entries already sorted best first, with ties.

    An entry shares the rank of the one above it when their intervals
    overlap; otherwise its rank is its position (1-based), as in sports
    tables. Returns ``(rank, tied)`` per entry; ``tied`` is True when another
    entry has the same rank.
    """
    ranks = []
    for i, interval in enumerate(intervals):
        if i and overlap(interval, intervals[i - 1]):
            ranks.append(ranks[-1])
        else:
            ranks.append(i + 1)
    return [(rank, ranks.count(rank) > 1) for rank in ranks]
