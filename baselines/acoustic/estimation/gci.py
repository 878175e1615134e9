"""Generalized covariance intersection of the band mixtures, and labelled extraction.

**Fusion** ([GMPHD] §2.3): ``v_fused(x) = prod_q v_q(x)^{omega_q}`` with
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

The product of the powered mixtures is a sum over one component per band;
each term is a product of Gaussians, computed exactly in information form:
with ``S_q = P_q / omega_q``, ``Lambda = sum_q S_q^{-1}``,
``eta = sum_q S_q^{-1} m_q``,

    prod_q N(x; m_q, S_q) = K N(x; Lambda^{-1} eta, Lambda^{-1}),
    log K = -1/2 [sum_q (d log 2 pi + log det S_q + m_q^T S_q^{-1} m_q)
                  - (d log 2 pi - log det Lambda + eta^T Lambda^{-1} eta)].

A fused term, one component ``i_q`` from each band, is then

    w = K prod_q w_{i_q}^{omega_q} kappa(omega_q, P_{i_q}),
    m = Lambda^{-1} eta,   P = Lambda^{-1},

and carries the label of its component in the first band used.
For single Gaussians this is covariance intersection:
``C^{-1} = sum_q omega_q P_q^{-1}``. The terms are expanded band by band,
summing the information (a matrix sum per term, no inversion); whenever the
expansion holds more than ``max_components`` terms, the heaviest
``max_components`` are kept (a beam). At the end the kept terms are formed,
sorted by weight, and those at or below ``min_weight`` are dropped. A band
with ``omega_q = 0`` contributes ``v^0 = 1`` exactly and is skipped; so is a
band whose mixture is empty (documented choice: an empty band carries no
information here rather than vetoing every target).

**Extraction** ([GMPHD] §2.3, :class:`LabelledExtractor`): the output is
``X_t = {(m^(j), l^(j)) | w^(j) > T_prune}``, with the labels kept from one step
to the next by matching positions (Hungarian assignment, gated).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from baselines.acoustic.estimation.gmphd import GaussianMixture

LOG_2PI = math.log(2.0 * math.pi)


def _terms(L: np.ndarray, h: np.ndarray, s: np.ndarray, base: np.ndarray):
    """Log weights, means and covariances of product terms in information form.

    Args:
      L: (T, d, d) summed information ``Lambda``; h: (T, d) summed ``eta``;
      s: (T,) summed ``d log 2 pi + log det S_q + m_q^T S_q^{-1} m_q``;
      base: (T,) summed log weights of the powered components.
    """
    d = L.shape[-1]
    C = np.linalg.inv(L)
    c = (C @ h[..., None])[..., 0]
    _, logdet_L = np.linalg.slogdet(L)
    log_k = -0.5 * (s - (d * LOG_2PI - logdet_L + np.einsum("ti,ti->t", h, c)))
    return base + log_k, c, C


class GeneralizedCovarianceIntersection:
    """GCI fusion of Q Gaussian-mixture PHDs ([GMPHD] §2.3).

    Args:
      weights: omega_q, non-negative, summing to 1 ([GMPHD]: 1/Q each).
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
        sizes = [len(mix) for mix, _ in used]
        om = np.repeat([o for _, o in used], sizes)
        w = np.concatenate([mix.weights for mix, _ in used])
        m = np.concatenate([mix.means for mix, _ in used])
        P = np.concatenate([mix.covariances for mix, _ in used])
        d = m.shape[-1]
        # The powered components N(x; m, P)^om = kappa N(x; m, P / om), all bands at once.
        info = np.linalg.inv(P) * om[:, None, None]
        eta = (info @ m[..., None])[..., 0]
        _, logdet_P = np.linalg.slogdet(P)
        log_kappa = 0.5 * (d * (LOG_2PI - np.log(om)) + logdet_P) \
            - 0.5 * om * (d * LOG_2PI + logdet_P)
        base_all = om * np.log(w) + log_kappa
        s_all = d * LOG_2PI + logdet_P - d * np.log(om) + np.einsum("ni,ni->n", m, eta)
        ends = np.cumsum(sizes)
        L, h, s, base = info[: ends[0]], eta[: ends[0]], s_all[: ends[0]], base_all[: ends[0]]
        labels = used[0][0].labels
        for start, end in zip(ends[:-1], ends[1:], strict=True):
            n = end - start
            L = (L[:, None] + info[None, start:end]).reshape(-1, d, d)
            h = (h[:, None] + eta[None, start:end]).reshape(-1, d)
            s = (s[:, None] + s_all[None, start:end]).reshape(-1)
            base = (base[:, None] + base_all[None, start:end]).reshape(-1)
            labels = np.repeat(labels, n)  # the first band's label travels along
            if len(base) > self.max_components:
                lw = _terms(L, h, s, base)[0]
                keep = np.argsort(-lw, kind="stable")[: self.max_components]
                L, h, s, base, labels = L[keep], h[keep], s[keep], base[keep], labels[keep]
        lw, c, C = _terms(L, h, s, base)
        keep = np.argsort(-lw, kind="stable")
        keep = keep[lw[keep] > math.log(self.min_weight)]
        return GaussianMixture(np.exp(lw[keep]), c[keep], C[keep],
                               labels[keep].astype(np.int64))


class LabelledExtractor:
    """State extraction with persistent labels ([GMPHD] §2.3's X_t = {(m, l) | w > T}).

    Components above ``threshold`` are extracted. Labels are kept across
    time by matching the extracted positions to the previous step's labelled
    estimates (Hungarian assignment on Euclidean distance, gated at
    ``gate`` metres; an unmatched estimate starts a new label).

    Args:
      threshold: extraction weight threshold ([GMPHD]: T_prune = 1e-5).
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
