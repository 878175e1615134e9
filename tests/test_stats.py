"""The leaderboard's intervals and ranks against closed forms and known data."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from baselines.stats import (
    beaten_ranks,
    bootstrap_interval,
    differ,
    overlap,
    paired_p_value,
    wilson_interval,
)

Z95 = scipy_stats.norm.ppf(0.975)


def wilson_closed_form(k: int, n: int) -> tuple[float, float]:
    """Wilson (1927): (p + z^2/2n +- z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)."""
    p, z = k / n, Z95
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return centre - half, centre + half


@pytest.mark.parametrize("k, n", [(0, 3), (3, 3), (1, 3), (17, 20), (0, 30), (15, 30), (29, 30)])
def test_wilson_interval_is_the_closed_form(k, n):
    low, high = wilson_interval(k, n)
    expected = wilson_closed_form(k, n)
    # At k = 0 and k = n the closed form's end is 0 or 1 only up to round-off.
    assert (low, high) == pytest.approx(expected, abs=1e-12)
    assert 0.0 <= low <= k / n <= high <= 1.0


def test_wilson_interval_known_values():
    # Brown, Cai and DasGupta (2001) style check: 3/3 and 0/3 at 95 %.
    assert wilson_interval(3, 3) == pytest.approx((0.4385030, 1.0), abs=1e-6)
    assert wilson_interval(0, 3) == pytest.approx((0.0, 0.5614970), abs=1e-6)


@pytest.mark.parametrize("k, n", [(1, 0), (-1, 3), (4, 3)])
def test_wilson_interval_rejects_impossible_counts(k, n):
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(k, n)


def test_bootstrap_interval_of_two_values_is_their_range():
    # Resampled means of (1, 2) are 1, 1.5, 2 with probabilities 1/4, 1/2, 1/4.
    assert bootstrap_interval([1.0, 2.0]) == (1.0, 2.0)


def test_bootstrap_interval_degenerate_cases():
    low, high = bootstrap_interval([3.5])
    assert math.isnan(low) and math.isnan(high)
    assert bootstrap_interval([2.0, 2.0, 2.0]) == (2.0, 2.0)


def test_bootstrap_interval_matches_the_normal_interval_for_a_large_sample():
    data = np.random.default_rng(7).normal(10.0, 2.0, 400)
    low, high = bootstrap_interval(data)
    half = Z95 * data.std(ddof=1) / math.sqrt(data.size)
    assert low == pytest.approx(data.mean() - half, abs=0.1 * half)
    assert high == pytest.approx(data.mean() + half, abs=0.1 * half)


def test_bootstrap_interval_is_a_function_of_the_data():
    data = np.random.default_rng(3).exponential(1.0, 12)
    assert bootstrap_interval(data) == bootstrap_interval(data.copy())
    assert bootstrap_interval(data) != bootstrap_interval(data * 1.01)


def test_overlap():
    assert overlap((0.0, 0.5), (0.5, 1.0))
    assert overlap((0.2, 0.3), (0.0, 1.0))
    assert not overlap((0.0, 0.4), (0.5, 1.0))


def _interval_ranks(intervals, p_values=()):
    """beaten_ranks on marginal intervals, or on neighbours' paired p-values."""
    def beats(j, i):
        paired = p_values[i] if j == i - 1 and i < len(p_values) else None
        return differ(intervals[j], intervals[i], paired)
    return beaten_ranks(len(intervals), beats)


def test_beaten_ranks():
    # Sorted best first: the first two overlap (tie at 1), the third is beaten by both
    # (rank 3), the last two by the first three and not by each other (tie at 4).
    intervals = [(0.8, 1.0), (0.7, 0.9), (0.3, 0.5), (0.0, 0.2), (0.1, 0.25)]
    assert _interval_ranks(intervals) == [(1, True), (1, True), (3, False), (4, True),
                                          (4, True)]
    assert _interval_ranks([(0.5, 1.0)]) == [(1, False)]
    # 3 episodes cannot separate 3/3 from 0/3 at 95 %: Wilson intervals overlap.
    assert _interval_ranks([wilson_interval(3, 3), wilson_interval(0, 3)]) == [(1, True),
                                                                              (1, True)]
    # 30 episodes can.
    assert _interval_ranks([wilson_interval(30, 30), wilson_interval(0, 30)]) == [
        (1, False), (2, False)]


def test_ties_do_not_chain():
    """Each entry ties with its neighbour, but the first beats the last: the last is not
    first (a chain of neighbour ties would rank all three 1)."""
    intervals = [(0.6, 1.0), (0.35, 0.65), (0.0, 0.4)]
    assert _interval_ranks(intervals) == [(1, True), (1, True), (2, False)]


def test_an_entry_never_shares_the_rank_of_one_that_beats_it():
    # 0 beats 1; 1 beats 3; 0 does not beat 3 (significance is not transitive): counted
    # alone, 3 would have 1 beater and share 1's rank 2.
    wins = {(0, 1), (0, 2), (1, 3)}
    ranks = beaten_ranks(4, lambda j, i: (j, i) in wins)
    assert ranks == [(1, False), (2, True), (2, True), (3, False)]
    for j, i in wins:
        assert ranks[j][0] < ranks[i][0]


def _by_seed(values):
    return {str(1000 + i): float(v) for i, v in enumerate(values)}


@pytest.mark.parametrize("wins, losses, ties", [(5, 0, 25), (6, 0, 24), (9, 2, 19), (7, 7, 6)])
def test_paired_test_on_success_is_the_exact_mcnemar_test(wins, losses, ties):
    """Binary outcomes on shared seeds: the sign-flip test of the mean difference is
    the exact binomial test on the discordant seeds (McNemar's exact test)."""
    a = [1] * wins + [0] * losses + [1] * (ties // 2) + [0] * (ties - ties // 2)
    b = [0] * wins + [1] * losses + [1] * (ties // 2) + [0] * (ties - ties // 2)
    expected = scipy_stats.binomtest(wins, wins + losses).pvalue
    assert paired_p_value(_by_seed(a), _by_seed(b)) == pytest.approx(expected, rel=1e-9)


def test_paired_test_cancels_what_the_seeds_share():
    """Two trackers whose errors move together from seed to seed: their marginal
    intervals overlap, the paired test separates them."""
    rng = np.random.default_rng(3)
    shared = rng.lognormal(-2.0, 0.4, size=12)  # the seeds' own difficulty
    a, b = shared, shared * 1.15 + 0.002 * rng.standard_normal(12)
    assert overlap(bootstrap_interval(a), bootstrap_interval(b))
    assert paired_p_value(_by_seed(a), _by_seed(b)) < 0.01
    # The ranks follow the test: b is below a.
    ranks = _interval_ranks([bootstrap_interval(a), bootstrap_interval(b)],
                            [None, paired_p_value(_by_seed(a), _by_seed(b))])
    assert ranks == [(1, False), (2, False)]


def test_paired_test_needs_the_same_seeds():
    assert paired_p_value({"1": 1.0, "2": 0.0}, {"1": 0.0, "3": 1.0}) is None
    assert paired_p_value({"1": 1.0}, {"1": 0.0}) is None
    assert paired_p_value(_by_seed([1, 0, 1]), _by_seed([1, 0, 1])) == 1.0
    # Not paired: the marginal rule decides (overlapping intervals tie).
    assert _interval_ranks([(0.5, 0.9), (0.4, 0.6)], [None, None]) == [(1, True),
                                                                      (1, True)]
