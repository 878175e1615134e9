"""Generalized covariance intersection of the band mixtures, and labelled extraction.

**Fusion** (seed 004 §2.3): ``v_fused(x) = prod_q v_q(x)^{omega_q}`` with
``sum_q omega_q = 1``. For Poisson multi-object densities the GCI
(Chernoff / exponential-mixture) fusion is again Poisson with exactly this
un-normalised geometric mean as its intensity (Clark, Julier, Mahler and
Ristic, "Robust multi-object sensor fusion with unknown correlations",
SSPD 2010; Uney, Clark and Julier, "Distributed fusion of PHD filters via
exponential mixture densities", IEEE JSTSP 7(3), 2013), so the PHDs are fused
as they are, without renormalising.

**Mixture approximation.** A power of a Gaussian mixture is not a mixture;
we use the approximation of Battistelli, Chisci, Fantacci, Farina and
Graziano ("Consensus CPHD filter for distributed multitarget tracking",
IEEE JSTSP 7(3), 2013, section V):

    (sum_i w_i N(x; m_i, P_i))^omega ~= sum_i w_i^omega N(x; m_i, P_i)^omega,

accurate when the components are well separated (which pruning and merging
in each band keep true), with the exact power of a Gaussian

    N(x; m, P)^omega = kappa(omega, P) N(x; m, P / omega),
    kappa = det(2 pi P / omega)^{1/2} / det(2 pi P)^{omega/2}.

The product of the powered mixtures is expanded pairwise, band by band, with
the exact product of two Gaussians
``N(x; a, A) N(x; b, B) = N(a; b, A + B) N(x; c, C)``,
``C^{-1} = A^{-1} + B^{-1}``, ``C^{-1} c = A^{-1} a + B^{-1} b``. For single
Gaussians this is covariance intersection: ``C^{-1} = sum_q omega_q P_q^{-1}``.
After each band the expansion keeps the ``max_components`` heaviest terms
above ``min_weight``. A band with ``omega_q = 0`` contributes ``v^0 = 1``
exactly and is skipped; so is a band whose mixture is empty (documented
choice: an empty band carries no information here rather than vetoing every
target).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from baselines.acoustic.gmphd import GaussianMixture

LOG_2PI = math.log(2.0 * math.pi)


def _power(mix: GaussianMixture, omega: float):
    """log weights, means, covariances of the powered mixture (see the module docstring)."""
    d = mix.means.shape[-1]
    _, logdet = np.linalg.slogdet(mix.covariances)
    # log kappa = 0.5 [d log(2 pi / omega) + logdet] - 0.5 omega [d log 2 pi + logdet]
    log_kappa = 0.5 * (d * (LOG_2PI - math.log(omega)) + logdet) \
        - 0.5 * omega * (d * LOG_2PI + logdet)
    return omega * np.log(mix.weights) + log_kappa, mix.means, mix.covariances / omega


def _product(a, b):
    """All pairwise products of two (log-weight, mean, covariance) mixtures."""
    la, ma, Pa = a
    lb, mb, Pb = b
    d = ma.shape[-1]
    S = Pa[:, None] + Pb[None]  # (A, B, d, d)
    diff = ma[:, None] - mb[None]
    S_inv = np.linalg.inv(S)
    _, logdet = np.linalg.slogdet(S)
    log_c = -0.5 * (np.einsum("abi,abij,abj->ab", diff, S_inv, diff) + logdet + d * LOG_2PI)
    Ia, Ib = np.linalg.inv(Pa), np.linalg.inv(Pb)
    C = np.linalg.inv(Ia[:, None] + Ib[None])
    info = np.einsum("aij,aj->ai", Ia, ma)[:, None] + np.einsum("bij,bj->bi", Ib, mb)[None]
    c = np.einsum("abij,abj->abi", C, info)
    return ((la[:, None] + lb[None] + log_c).reshape(-1), c.reshape(-1, d),
            C.reshape(-1, d, d))


class GeneralizedCovarianceIntersection:
    """GCI fusion of Q Gaussian-mixture PHDs (seed 004 §2.3).

    Args:
      weights: omega_q, non-negative, summing to 1 (seed 004: 1/Q each).
      max_components: cap on the fused expansion after each band.
      min_weight: fused terms at or below this weight are dropped.
    """

    def __init__(self, weights, max_components: int = 12, min_weight: float = 1e-12):
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim != 1 or len(w) < 1 or np.any(w < 0) or not math.isclose(w.sum(), 1.0,
                                                                            abs_tol=1e-9):
            raise ValueError(f"GCI weights must be non-negative and sum to 1, got {weights}")
        if max_components < 1:
            raise ValueError("max_components must be >= 1")
        self.weights = w
        self.max_components = int(max_components)
        self.min_weight = float(min_weight)

    def __call__(self, mixtures: list[GaussianMixture]) -> GaussianMixture:
        if len(mixtures) != len(self.weights):
            raise ValueError(f"expected {len(self.weights)} mixtures, got {len(mixtures)}")
        used = [(mix, om) for mix, om in zip(mixtures, self.weights, strict=True)
                if om > 0 and len(mix)]
        if not used:
            return GaussianMixture.empty(mixtures[0].means.shape[-1])
        if len(used) == 1 and used[0][1] == 1.0:
            mix = used[0][0]
            return GaussianMixture(mix.weights.copy(), mix.means.copy(),
                                   mix.covariances.copy(), mix.labels.copy())
        first, om = used[0]
        acc = _power(first, om)
        labels = first.labels
        for mix, om in used[1:]:
            lw, m, P = _product(acc, _power(mix, om))
            labels = np.repeat(labels, len(mix))  # the first band's label travels along
            keep = np.argsort(-lw, kind="stable")[: self.max_components]
            keep = keep[lw[keep] > math.log(self.min_weight)]
            if not len(keep):
                return GaussianMixture.empty(m.shape[-1])
            acc, labels = (lw[keep], m[keep], P[keep]), labels[keep]
        lw, m, P = acc
        return GaussianMixture(np.exp(lw), m, P, labels.astype(np.int64))


class LabelledExtractor:
    """State extraction with persistent labels (seed 004 §2.3's X_t = {(m, l) | w > T}).

    Components above ``threshold`` are extracted. Labels are kept across
    time by matching the extracted positions to the previous step's labelled
    estimates (Hungarian assignment on Euclidean distance, gated at
    ``gate`` metres; an unmatched estimate starts a new label).

    Args:
      threshold: extraction weight threshold (seed 004: T_prune = 1e-5).
      gate: association gate (m).
    """

    def __init__(self, threshold: float = 1e-5, gate: float = 2.0):
        self.threshold = float(threshold)
        self.gate = float(gate)
        self.reset()

    def reset(self) -> None:
        self._positions = np.zeros((0, 3))
        self._labels = np.zeros(0, dtype=np.int64)
        self._next = 0

    def __call__(self, mixture: GaussianMixture):
        """Return (weights (E,), states (E, 6), labels (E,)) sorted by weight, heaviest first."""
        keep = np.flatnonzero(mixture.weights > self.threshold)
        keep = keep[np.argsort(-mixture.weights[keep], kind="stable")]
        states = mixture.means[keep]
        labels = np.full(len(keep), -1, dtype=np.int64)
        if len(keep) and len(self._positions):
            cost = np.linalg.norm(states[:, None, :3] - self._positions[None], axis=-1)
            rows, cols = linear_sum_assignment(np.minimum(cost, 1e6))
            ok = cost[rows, cols] <= self.gate
            labels[rows[ok]] = self._labels[cols[ok]]
        fresh = labels < 0
        labels[fresh] = np.arange(self._next, self._next + fresh.sum())
        self._next += int(fresh.sum())
        self._positions, self._labels = states[:, :3].copy(), labels.copy()
        return mixture.weights[keep], states, labels
