"""Gaussian-mixture PHD filters, one per sub-band, with DBSCAN adaptive birth ([GMPHD] §2).

**Models** ([GMPHD] §2.1). The state is ``x = (x, y, z, vx, vy, vz)`` under the
constant-velocity model of [GMPHD] §2.1 applied per axis::

    x_t = F x_{t-1} + w_{t-1},   w ~ N(0, Q),
    F = [[1, T], [0, 1]] (x) I_3,   Q = sigma_q^2 [[T^4/4, T^3/2], [T^3/2, T^2]] (x) I_3

(:class:`ConstantVelocityModel`), and the measurement is a position fix
``z = H x + v``, ``v ~ N(0, R_z)``, with ``H = [I_3, 0]`` and the fix's own
covariance ``R_z`` (from :mod:`~baselines.acoustic.perception.positioning`).

The recursion is the GM-PHD filter of Vo & Ma (IEEE TSP 54(11), 2006), Table I
(prediction, update) and Table II (pruning and merging), with [GMPHD] §2.2's
adaptive birth. Each band ``q`` keeps its own intensity
``v_{t-1,q}(x) = sum_j w^(j) N(x; m^(j), P^(j))``; every component carries a label.

**Prediction with adaptive birth** (Table I, steps 1-2; [GMPHD] §2.2,
:meth:`GaussianMixturePHDBank.predict`)::

    v_{t|t-1}(x) = sum_j p_S w^(j) N(x; F m^(j), F P^(j) F^T + Q) + gamma_t(x)
    gamma_t(x)   = sum_k w_gamma^(k) N(x; m_gamma^(k), P_gamma)

The birth :class:`AdaptiveBirth` pools the valid fixes of all bands at time t,
drops those within ``exclusion_radius`` of a confirmed component
(``w >= confirmed_weight``: already explained), and clusters the rest with
DBSCAN; cluster ``C_k`` gives ``m_gamma^(k) = (mean of C_k, 0, 0, 0)``, the
predefined ``P_gamma = diag(sigma_p^2 I_3, sigma_v^2 I_3)`` and a weight
proportional to its size, ``w_gamma^(k) = w_b |C_k| / n_sources``. The birth is
the same in every band, with fresh labels per band; survivors keep theirs.

**Update** (Table I, steps 3-4; :func:`gmphd_update`), per band with its own
fixes ``Z_{t,q}``::

    v_{t,q}(x) = (1 - p_D) v_{t|t-1}(x) + sum_{z in Z_{t,q}} sum_j w^(j)(z) N(x; m^(j)(z), P^(j)(z))

    S^(j)(z) = H P^(j) H^T + R_z,      K^(j)(z) = P^(j) H^T S^(j)(z)^{-1}
    m^(j)(z) = m^(j) + K^(j)(z) (z - H m^(j))
    P^(j)(z) = (I - K H) P^(j) (I - K H)^T + K R_z K^T
    w^(j)(z) = p_D w^(j) N(z; H m^(j), S^(j)(z))
               / (kappa + p_D sum_l w^(l) N(z; H m^(l), S^(l)(z)))

with ``kappa`` the uniform clutter intensity. Because each fix has its own
``R_z``, the gain and covariance depend on ``z``; the covariance is in Joseph
form (equal to Vo & Ma's ``(I - K H) P`` in exact arithmetic). Each updated
component keeps the label of the predicted component it came from.

**Pruning and merging** (Table II; :class:`MixtureReducer`): components with
``w <= T`` are dropped; then, repeatedly, the heaviest remaining component
``j`` absorbs the set ``L`` of remaining components ``i`` with
``(m^(i) - m^(j))^T P^(i)^{-1} (m^(i) - m^(j)) <= U`` into::

    w~ = sum_{i in L} w^(i),   m~ = (1 / w~) sum_{i in L} w^(i) m^(i)
    P~ = (1 / w~) sum_{i in L} w^(i) (P^(i) + (m~ - m^(i)) (m~ - m^(i))^T)

taking ``j``'s label, until none remain or ``J_max`` components are formed
(the loop stops at ``J_max``: the components kept are the first ``J_max``
merged, in the order of their heaviest members).

The bank keeps the Q mixtures padded to a common number of slots (weight 0
marks an empty slot) so that prediction and update run once for all bands.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from sklearn.cluster import DBSCAN

from baselines.kalman import constant_velocity_blocks

STATE_DIM = 6
#: The measurement matrix of a position fix, ``H = [I_3, 0]``.
POSITION_H = np.hstack([np.eye(3), np.zeros((3, 3))])
TWO_PI_CUBED = (2.0 * math.pi) ** 3


@dataclasses.dataclass
class GaussianMixture:
    """A Gaussian mixture intensity with one label per component.

    Attributes: ``weights`` (J,), ``means`` (J, 6), ``covariances`` (J, 6, 6),
    ``labels`` (J,) int.
    """

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    labels: np.ndarray

    @classmethod
    def empty(cls, dim: int = STATE_DIM) -> GaussianMixture:
        return cls(np.zeros(0), np.zeros((0, dim)), np.zeros((0, dim, dim)),
                   np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return len(self.weights)

    def select(self, index) -> GaussianMixture:
        return GaussianMixture(self.weights[index], self.means[index],
                               self.covariances[index], self.labels[index])


class ConstantVelocityModel:
    """[GMPHD] §2.1's constant-velocity model on each of the three axes.

    Args:
      dt: sampling interval T (s).
      accel_std: sigma_q, the white-acceleration standard deviation (m/s^2).
    """

    def __init__(self, dt: float, accel_std: float):
        if not (dt > 0 and accel_std >= 0):
            raise ValueError(f"need dt > 0 and accel_std >= 0, got {dt}, {accel_std}")
        f, q = constant_velocity_blocks(dt, accel_std)
        eye = np.eye(3)
        # State order (x, y, z, vx, vy, vz): kron over (position/velocity, axis).
        self.F = np.kron(f, eye)
        self.Q = np.kron(q, eye)

    def predict(self, means: np.ndarray, covariances: np.ndarray):
        """``m' = F m``, ``P' = F P F^T + Q`` over any leading axes."""
        F = self.F
        return means @ F.T, F @ covariances @ F.T + self.Q


class AdaptiveBirth:
    """Measurement-driven birth from DBSCAN clusters ([GMPHD] §2.2).

    Args:
      eps: DBSCAN neighbourhood radius (m).
      min_samples: DBSCAN core-point size (fixes, pooled over bands).
      weight: birth weight of a cluster holding ``n_sources`` fixes; a
        cluster of size s gets ``weight * s / n_sources`` (proportional to size).
      n_sources: the normaliser (the number of bands).
      position_std: the predefined birth covariance P_gamma's position std (m).
      velocity_std: P_gamma's velocity std (m/s).
      exclusion_radius: fixes within this distance (m) of a component with
        weight >= ``confirmed_weight`` are explained and do not seed births.
      confirmed_weight: the weight from which a component is confirmed.
    """

    def __init__(self, eps: float = 1.0, min_samples: int = 3, weight: float = 0.1,
                 n_sources: int = 10, position_std: float = 0.5, velocity_std: float = 1.0,
                 exclusion_radius: float = 3.0, confirmed_weight: float = 0.5):
        if not (eps > 0 and min_samples >= 1 and weight > 0 and n_sources >= 1):
            raise ValueError("AdaptiveBirth needs eps > 0, min_samples >= 1, weight > 0, "
                             "n_sources >= 1")
        self.eps, self.min_samples = float(eps), int(min_samples)
        self.weight, self.n_sources = float(weight), int(n_sources)
        self.covariance = np.diag([position_std**2] * 3 + [velocity_std**2] * 3)
        self.exclusion_radius = float(exclusion_radius)
        self.confirmed_weight = float(confirmed_weight)
        self._dbscan = DBSCAN(eps=self.eps, min_samples=self.min_samples)

    def __call__(self, fixes: np.ndarray, confirmed: np.ndarray | None = None):
        """Birth components (weights (B,), means (B, 6), covariances (B, 6, 6)).

        Args:
          fixes: (M, 3) valid position fixes pooled over the bands.
          confirmed: (C, 3) positions of confirmed components (may be None).
        """
        z = np.asarray(fixes, dtype=np.float64).reshape(-1, 3)
        if confirmed is not None and len(confirmed) and len(z):
            d2 = np.sum((z[:, None] - confirmed[None]) ** 2, axis=-1)
            z = z[d2.min(axis=1) > self.exclusion_radius**2]
        if len(z) < self.min_samples:
            return np.zeros(0), np.zeros((0, STATE_DIM)), np.zeros((0, STATE_DIM, STATE_DIM))
        cluster = self._dbscan.fit_predict(z)
        ids = np.unique(cluster[cluster >= 0])
        sizes = np.array([(cluster == i).sum() for i in ids], dtype=np.float64)
        means = np.zeros((len(ids), STATE_DIM))
        for row, i in enumerate(ids):
            means[row, :3] = z[cluster == i].mean(axis=0)
        weights = self.weight * sizes / self.n_sources
        return weights, means, np.broadcast_to(self.covariance, (len(ids), 6, 6)).copy()


def gmphd_update(weights, means, covariances, z, R, valid, p_detect, clutter_density):
    """The GM-PHD corrector (Vo & Ma 2006, Table I, steps 3-4), batched over bands.

    Args:
      weights: (Q, J) predicted weights (0 for empty slots).
      means: (Q, J, 6); covariances: (Q, J, 6, 6).
      z: (Q, K, 3) position fixes; R: (Q, K, 3, 3) their covariances;
      valid: (Q, K) which fixes are real.
      p_detect: (Q,) or scalar detection probability; clutter_density: kappa(z),
        a scalar (uniform clutter intensity).

    Returns:
      (weights (Q, J (K+1)), means, covariances, source (J (K+1),)): the
      missed-detection terms first (J), then detection k of component j at
      ``J + j K + k``; ``source`` is the predicted component each came from.
    """
    w = np.asarray(weights, dtype=np.float64)
    q_, j_ = w.shape
    pd = np.asarray(p_detect, dtype=np.float64)
    if pd.ndim:
        pd = pd[:, None]
    P = covariances[:, :, None]  # (Q, J, 1, 6, 6)
    HPt = P[..., :3, :].swapaxes(-1, -2)  # P H^T: (Q, J, 1, 6, 3)
    S = P[..., :3, :3] + R[:, None]  # (Q, J, K, 3, 3)
    S_inv = np.linalg.inv(S)
    nu = z[:, None, :, :, None] - means[:, :, None, :3, None]  # (Q, J, K, 3, 1)
    S_inv_nu = S_inv @ nu
    maha = (nu.swapaxes(-1, -2) @ S_inv_nu)[..., 0, 0]
    # N(z; H m, S) = exp(-maha / 2) / sqrt((2 pi)^3 det S)
    likelihood = np.exp(-0.5 * maha) / np.sqrt(TWO_PI_CUBED * np.linalg.det(S))
    gain = HPt @ S_inv  # K = P H^T S^-1: (Q, J, K, 6, 3)
    upd_m = means[:, :, None] + (HPt @ S_inv_nu)[..., 0]
    # Joseph form (I - K H) P (I - K H)^T + K R K^T (as baselines.kalman.joseph_covariance),
    # regrouped for H = [I_3, 0] so that H P and A H^T are slices:
    # A = (I - K H) P = P - K (H P), then A (I - K H)^T + K R K^T = A - (A H^T - K R) K^T.
    A = P - gain @ P[..., :3, :]
    upd_P = A - (A[..., :3] - gain @ R[:, None]) @ gain.swapaxes(-1, -2)
    # np.where, not a product: padded fixes may hold anything (NaN too) and must weigh 0.
    num = (pd * w)[:, :, None] * np.where(valid[:, None, :], likelihood, 0.0)  # (Q, J, K)
    upd_w = num / (clutter_density + num.sum(axis=1, keepdims=True))
    out_w = np.concatenate([(1.0 - pd) * w, upd_w.reshape(q_, -1)], axis=1)
    out_m = np.concatenate([means, upd_m.reshape(q_, -1, STATE_DIM)], axis=1)
    out_P = np.concatenate([covariances, upd_P.reshape(q_, -1, STATE_DIM, STATE_DIM)], axis=1)
    return out_w, out_m, out_P, _update_sources(j_, upd_w.shape[2])


@functools.lru_cache(maxsize=256)
def _update_sources(j: int, k: int) -> np.ndarray:
    """The predicted component of each :func:`gmphd_update` output term (read-only)."""
    source = np.concatenate([np.arange(j), np.repeat(np.arange(j), k)])
    source.flags.writeable = False
    return source


def compact_fixes(z: np.ndarray, R: np.ndarray, valid: np.ndarray):
    """Each band's real fixes moved to the front, padded to the largest count over bands.

    Only the real fixes matter to :func:`gmphd_update`; this is what
    :meth:`GaussianMixturePHDBank.update` hands it.

    Args:
      z: (Q, K, 3) position fixes; R: (Q, K, 3, 3); valid: (Q, K).

    Returns:
      (z (Q, k, 3), R (Q, k, 3, 3), valid (Q, k)) with k the most valid fixes of a band.
    """
    k = int(valid.sum(axis=1).max(initial=0))
    first = np.argsort(~valid, axis=1, kind="stable")[:, :k]
    return (np.take_along_axis(z, first[..., None], 1),
            np.take_along_axis(R, first[..., None, None], 1),
            np.take_along_axis(valid, first, 1))


class MixtureReducer:
    """Pruning, merging and capping (Vo & Ma 2006, Table II), batched over bands.

    Args:
      prune_threshold: T ([GMPHD]: 1e-5); components at or below it are dropped.
      merge_threshold: U, squared Mahalanobis distance for merging.
      max_components: J_max, the cap (the heaviest are kept).
    """

    def __init__(self, prune_threshold: float = 1e-5, merge_threshold: float = 4.0,
                 max_components: int = 12):
        if not (prune_threshold >= 0 and merge_threshold >= 0 and max_components >= 1):
            raise ValueError("need prune_threshold >= 0, merge_threshold >= 0, "
                             "max_components >= 1")
        self.prune_threshold = float(prune_threshold)
        self.merge_threshold = float(merge_threshold)
        self.max_components = int(max_components)

    def __call__(self, mixture: GaussianMixture) -> GaussianMixture:
        """Reduce one mixture."""
        w, m, P, lab = self.reduce(mixture.weights[None], mixture.means[None],
                                   mixture.covariances[None], mixture.labels[None])
        n = int(np.count_nonzero(w[0]))
        return GaussianMixture(w[0, :n], m[0, :n], P[0, :n], lab[0, :n])

    def reduce(self, weights, means, covariances, labels):
        """Reduce Q padded mixtures at once.

        The greedy loop of Table II (take the heaviest remaining component,
        merge every remaining one within U of it under that one's own
        covariance, repeat) runs once per *output* component, each pass
        vectorised over the bands.

        Args:
          weights: (Q, M) (0 marks an empty slot); means (Q, M, d);
            covariances (Q, M, d, d); labels (Q, M).

        Returns:
          (weights (Q, J), means, covariances, labels), J <= max_components,
          each band's components in the order of their heaviest members (the
          seeds of the merges); a band's empty slots (weight 0, identity
          covariance, label -1) come after its components.
        """
        q_, d = weights.shape[0], means.shape[-1]
        keep = weights > self.prune_threshold
        n = int(keep.sum(axis=1).max(initial=0))
        eye = np.eye(d)
        if n == 0:
            return (np.zeros((q_, 0)), np.zeros((q_, 0, d)), np.zeros((q_, 0, d, d)),
                    np.zeros((q_, 0), dtype=np.int64))
        order = np.argsort(np.where(keep, -weights, np.inf), axis=1, kind="stable")[:, :n]
        w = np.take_along_axis(weights, order, axis=1)
        m = np.take_along_axis(means, order[..., None], axis=1)
        P = np.take_along_axis(covariances, order[..., None, None], axis=1)
        lab = np.take_along_axis(labels, order, axis=1)
        left = np.take_along_axis(keep, order, axis=1)
        P_inv = np.linalg.inv(np.where(left[..., None, None], P, eye))
        cap = min(self.max_components, n)
        out_w = np.zeros((q_, cap))
        out_m = np.zeros((q_, cap, d))
        out_P = np.broadcast_to(eye, (q_, cap, d, d)).copy()
        out_l = np.full((q_, cap), -1, dtype=np.int64)
        rows = np.arange(q_)
        used = 0
        for it in range(cap):
            active = left.any(axis=1)
            if not active.any():
                break
            j = np.argmax(left, axis=1)  # heaviest remaining (sorted order)
            diff = m - m[rows, j][:, None]
            maha = np.einsum("qni,qnij,qnj->qn", diff, P_inv, diff)
            close = left & (maha <= self.merge_threshold)
            wl = np.where(close, w, 0.0)
            total = wl.sum(axis=1)
            safe = np.where(active, total, 1.0)
            mean = np.einsum("qn,qni->qi", wl, m) / safe[:, None]
            dm = m - mean[:, None]
            cov = np.einsum("qn,qnij->qij", wl, P + dm[..., :, None] * dm[..., None, :])
            a = np.flatnonzero(active)
            out_w[a, it] = total[a]
            out_m[a, it] = mean[a]
            out_P[a, it] = cov[a] / safe[a, None, None]
            out_l[a, it] = lab[a, j[a]]
            left &= ~close
            used = it + 1
        return out_w[:, :used], out_m[:, :used], out_P[:, :used], out_l[:, :used]


class GaussianMixturePHDBank:
    """Q independent GM-PHD filters (one per sub-band) sharing the adaptive birth.

    The Q mixtures are kept padded to a common number of slots (``weights``
    (Q, J) with 0 marking an empty slot, ``means`` (Q, J, 6), ``covariances``
    (Q, J, 6, 6), ``labels`` (Q, J)) so that prediction, update and reduction
    each run once for all bands.

    Args:
      n_bands: Q.
      motion: the :class:`ConstantVelocityModel`.
      birth: the :class:`AdaptiveBirth`.
      reducer: the :class:`MixtureReducer`.
      p_survival: p_S ([GMPHD]: 0.99).
      p_detect: (Q,) or scalar detection probability of a valid fix.
      clutter_density: kappa, the uniform clutter intensity of fixes (per m^3).
    """

    def __init__(self, n_bands: int, motion: ConstantVelocityModel, birth: AdaptiveBirth,
                 reducer: MixtureReducer, p_survival: float = 0.99, p_detect=0.9,
                 clutter_density: float = 1e-6):
        if not (0 < p_survival <= 1):
            raise ValueError(f"p_survival must be in (0, 1], got {p_survival}")
        pd = np.broadcast_to(np.asarray(p_detect, dtype=np.float64), (n_bands,)).copy()
        if not np.all((pd > 0) & (pd < 1)):
            raise ValueError("p_detect must lie in (0, 1)")
        self.n_bands = int(n_bands)
        self.motion, self.birth, self.reducer = motion, birth, reducer
        self.p_survival, self.p_detect = float(p_survival), pd
        self.clutter_density = float(clutter_density)
        self.reset()

    def reset(self) -> None:
        q = self.n_bands
        self.weights = np.zeros((q, 0))
        self.means = np.zeros((q, 0, STATE_DIM))
        self.covariances = np.zeros((q, 0, STATE_DIM, STATE_DIM))
        self.labels = np.zeros((q, 0), dtype=np.int64)
        self._next_label = 0

    @property
    def mixtures(self) -> list[GaussianMixture]:
        """The Q mixtures without their empty slots (views of the padded arrays)."""
        counts = np.count_nonzero(self.weights, axis=1)
        return [GaussianMixture(self.weights[i, :n], self.means[i, :n],
                                self.covariances[i, :n], self.labels[i, :n])
                for i, n in enumerate(counts)]

    def predict(self, z: np.ndarray, valid: np.ndarray):
        """Predicted intensity plus this step's adaptive birth (Vo & Ma Table I, steps 1-2).

        Args:
          z: (Q, K, 3) position fixes; valid: (Q, K) which are real.

        Returns:
          Padded (weights (Q, J), means, covariances, labels): the survivors of
          each band, then the birth components (the same in every band, with
          fresh labels per band).
        """
        # Last step's positions: the motion over one 10 ms period is far below
        # the exclusion radius.
        confirmed = self.means[self.weights >= self.birth.confirmed_weight][:, :3]
        bw, bm, bP = self.birth(z[valid], confirmed)
        q, b = self.n_bands, len(bw)
        pm, pP = self.motion.predict(self.means, self.covariances)
        w = np.concatenate([self.p_survival * self.weights, np.broadcast_to(bw, (q, b))], 1)
        m = np.concatenate([pm, np.broadcast_to(bm, (q, b, STATE_DIM))], 1)
        P = np.concatenate([pP, np.broadcast_to(bP, (q, b, STATE_DIM, STATE_DIM))], 1)
        births = np.arange(self._next_label, self._next_label + q * b).reshape(q, b)
        self._next_label += q * b
        return w, m, P, np.concatenate([self.labels, births], 1)

    def update(self, predicted, z: np.ndarray, R: np.ndarray, valid: np.ndarray) -> None:
        """PHD update of each band with its own fixes, then reduction (Table I 3-4, II)."""
        w, m, P, labels = predicted
        if w.shape[1] == 0:
            return
        uw, um, uP, source = gmphd_update(w, m, P, *compact_fixes(z, R, valid),
                                          self.p_detect, self.clutter_density)
        self.weights, self.means, self.covariances, self.labels = self.reducer.reduce(
            uw, um, uP, labels[:, source])

    def step(self, z: np.ndarray, R: np.ndarray, valid: np.ndarray) -> list[GaussianMixture]:
        """Predict, add the adaptive birth, update with each band's fixes, reduce.

        Args:
          z: (Q, K, 3) position fixes, R: (Q, K, 3, 3), valid: (Q, K).

        Returns:
          The Q updated mixtures (also in ``self.mixtures``).
        """
        self.update(self.predict(z, valid), z, R, valid)
        return self.mixtures
