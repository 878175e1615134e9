"""Per-detection least-squares positioning from TDOA and DOA ([GMPHD] §1.1-1.3).

Unknowns ``omega = (x, y, z, D_1)`` with ``D_1`` the range to node 1. All
coordinates are taken relative to the array centroid ``h_bar`` (conditioning
only: the equations are translation invariant).

* **TDOA** (§1.1): with ``d_i = c tau_1i`` the measured range difference,
  ``|p - h_i|^2 = (D_1 + d_i)^2``; subtracting node 1's equation
  ``|p - h_1|^2 = D_1^2`` gives, for i = 2..n, the linear row

      2 (h_i - h_1)^T p + 2 d_i D_1 = |h_i|^2 - |h_1|^2 - d_i^2      (R omega = E)

  which is exact (no linearisation error) for noise-free data.
* **DOA** (§1.2): ``tan alpha_i = (y - y_i)/(x - x_i)`` and
  ``tan theta_i = hypot(x - x_i, y - y_i)/(z - z_i)`` become, per node, the
  two unit-norm rows

      sin(a_i) (x - x_i) - cos(a_i) (y - y_i) = 0
      cos(t_i) [cos(a_i) (x - x_i) + sin(a_i) (y - y_i)] - sin(t_i) (z - z_i) = 0

  (``I p = N``); their residuals are lateral offsets in metres.
* **Fused** (§1.3): ``I~ = [I, 0]`` (a zero column for ``D_1``) and
  ``N~ = N`` put the DOA rows on the TDOA unknowns; the stacked system is
  solved by one normal-equation solve
  ``omega = (R^T R + I~^T I~)^{-1} (R^T E + I~^T N~)``.

**Weighting** (our choice, documented): the paper solves the stacked system
unweighted (``weighting="none"`` reproduces that), but its TDOA rows are in
m^2 and its DOA rows in m, so unweighted the TDOA rows swamp the angles. With
``weighting="noise"`` (the default) a first unweighted solve gives the node
ranges ``D_i``, and every row is divided by its first-order residual standard
deviation under the documented noise model of the calibration
(``array.model`` at the work-area centre, per band): ``2 D_i sigma_d`` for a
TDOA row (``sigma_d = c hypot(std(tau_1i), clock_offset_std)``),
``rho_i sigma_alpha`` for an azimuth row (``rho_i`` the horizontal range) and
``D_i sigma_theta`` for an elevation row; then the same normal equations are
solved again with the weighted rows: with ``A``, ``b`` the method's stacked
rows (``[R; I~]``, ``[E; N~]`` when fused) and ``W = diag(1 / sigma_r^2)``,

    omega = (A^T W A)^{-1} A^T W b,    Cov(x, y, z) = [(A^T W A)^{-1}]_{1:3, 1:3},
    chi2  = (A omega - b)^T W (A omega - b)

(``W = I`` with ``weighting="none"``; every solve adds a relative ridge of
1e-12 to ``A^T W A``, below round-off for a well-posed system). The weighted
chi-square of the residuals gates each fix, and fixes outside the tank
(multipath mirror images lie above the surface or below the bottom) are
marked invalid.

**Variance factor** (our addition, the global model test of least-squares
adjustment; e.g. Koch, *Parameter Estimation and Hypothesis Testing in Linear
Models*, 2nd ed., 1999, §4.2 and §4.3): the calibration's noise model is the
calm-water one, but a detection can be noisier (flow noise raises the noise
floor with the current, :mod:`auv_envs.core.acoustics`). When a fix's
``chi2 / dof`` exceeds the ``variance_test`` quantile of ``chi2(dof) / dof``
(1.90 for the fused system's 19 dof at the default 0.99), the model is
rejected for that detection and its covariance is scaled by the a-posteriori
variance factor ``chi2 / dof``; otherwise it is kept. The residual gate is
correspondingly loose (``chi2 / dof <= 1000``, noise up to about 30 times the
model's): false alarms, random measurement vectors, score 10^4 and more.

**Clock offsets** (our addition; [GMPHD] only notes TDOA's "sensitivity to
synchronization errors", §1.3): each node's clock offset against node 1 is
constant over an episode, so it biases every TDOA fix alike and no fusion of
bands removes it. :class:`ClockOffsetEstimator` estimates the offsets online
from the DOA rows, which do not depend on the clocks: for each valid fix it
solves the DOA-only position, predicts the TDOAs there and averages the
residuals per node, weighted by their first-order variance (DOA position
covariance plus TDOA noise) and gated. ``solve(..., clock=estimator.clock)``
then subtracts the estimated offsets and weights the TDOA rows with what is
left of their uncertainty.

**Node dropouts**: while a node is out (the observation's ``node_mask``,
:mod:`auv_envs.core.acoustics`) its rows carry no measurement. ``solve(...,
nodes=...)`` gives them zero weight: its azimuth and elevation rows and the
TDOA row of its pair with node 1 drop out, and all TDOA rows while node 1 is
out (the fused system then fixes ``p`` from the angles alone, ``D_1`` no
longer an unknown). The residual degrees of freedom, and with them the gate
and the model test's threshold, are those of the rows left; a system with
fewer rows than unknowns gives no valid fix.

Everything is vectorised over arbitrary leading axes (bands x detections).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import numpy as np
from scipy.stats import chi2 as chi2_distribution

METHODS = ("fused", "tdoa", "doa")
WEIGHTINGS = ("noise", "none")


@dataclasses.dataclass(frozen=True)
class PositionFixes:
    """Position fixes of a batch of detections (leading axes ``...``).

    Entries that are not real detections (``mask`` False) are NaN in
    ``position``, ``covariance`` and ``chi2`` and never valid.

    Attributes:
      position: (..., 3) estimated positions in the tank frame (m).
      covariance: (..., 3, 3) position covariance of the weighted solve
        (``(A^T W A)^{-1}``, times the variance factor where the model test
        rejects it; meaningful only with ``weighting="noise"``).
      chi2: (...,) weighted residual sum of squares (``weighting="noise"``)
        or the plain residual sum of squares.
      dof: residual degrees of freedom (rows - unknowns).
      valid: (...,) real detection, finite, inside the tank and, when
        gating is on, ``chi2 / dof <= gate``.
    """

    position: np.ndarray
    covariance: np.ndarray
    chi2: np.ndarray
    dof: int
    valid: np.ndarray


def tdoa_rows(tdoa, nodes: np.ndarray, sound_speed: float, xp=np):
    """The linearised TDOA system ``R omega = E`` ([GMPHD] §1.1).

    Args:
      tdoa: (..., N-1) time differences ``t_i - t_1`` (s).
      nodes: (N, 3) node positions (any origin; the result uses the same).
      sound_speed: c in m/s.
      xp: the array namespace of ``tdoa`` (NumPy computes in float64, JAX in its own
        float type).

    Returns:
      ``R`` (..., N-1, 4) over ``(x, y, z, D_1)`` and ``E`` (..., N-1).
    """
    d = (np.asarray(tdoa, dtype=np.float64) if xp is np else tdoa) * sound_speed
    h = np.asarray(nodes, dtype=np.float64)
    geo = 2.0 * (h[1:] - h[0])  # (N-1, 3)
    R = xp.concatenate([xp.broadcast_to(geo, d.shape + (3,)), (2.0 * d)[..., None]], axis=-1)
    E = (np.sum(h[1:] ** 2, axis=1) - np.sum(h[0] ** 2)) - d * d
    return R, E


def doa_rows(azimuth, elevation, nodes: np.ndarray, xp=np):
    """The DOA system ``I p = N`` ([GMPHD] §1.2), two unit-norm rows per node.

    Args:
      azimuth, elevation: (..., N) angles (rad; elevation from the upward vertical).
      nodes: (N, 3) node positions.
      xp: the angles' array namespace.

    Returns:
      ``I`` (..., 2N, 3) and ``N`` (..., 2N): rows ``0..N-1`` azimuth, ``N..2N-1`` elevation.
    """
    if xp is np:
        azimuth = np.asarray(azimuth, dtype=np.float64)
        elevation = np.asarray(elevation, dtype=np.float64)
    h = np.asarray(nodes, dtype=np.float64)
    sa, ca = xp.sin(azimuth), xp.cos(azimuth)
    st, ct = xp.sin(elevation), xp.cos(elevation)
    I_ = xp.concatenate([xp.stack([sa, -ca, xp.zeros_like(sa)], axis=-1),
                         xp.stack([ct * ca, ct * sa, -st], axis=-1)], axis=-2)
    H = np.concatenate([h, h], axis=0)
    N_ = np.einsum("...rk,...rk->...r", I_, H) if xp is np else xp.sum(I_ * H, axis=-1)
    return I_, N_


def work_area_centre(calibration) -> np.ndarray:
    """(3,) centre of the calibration's ``work_area`` (where the noise model is read)."""
    lo, hi = (np.asarray(v, dtype=np.float64) for v in calibration.work_area)
    return 0.5 * (lo + hi)


@functools.lru_cache(maxsize=64)
def _model_test_threshold(level: float, dof: int) -> float:
    """The model test's threshold on ``chi2 / dof``: the ``level`` quantile of chi2(dof) / dof."""
    return float(chi2_distribution.ppf(level, dof) / dof)


def _spd_inverse(S, xp):
    """The inverse of symmetric positive definite matrices S (..., n, n) through their
    Cholesky factor, unrolled over the (few) rows in elementwise arithmetic; NaN where S
    is not positive definite in the arithmetic's precision (such a fix is not finite,
    hence never valid)."""
    n = S.shape[-1]
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        L[j][j] = xp.sqrt(S[..., j, j] - sum(L[j][m] ** 2 for m in range(j)))
        for i in range(j + 1, n):
            L[i][j] = (S[..., i, j] - sum(L[i][m] * L[j][m] for m in range(j))) / L[j][j]
    inv_L = [[None] * n for _ in range(n)]  # L^-1, lower triangular
    for i in range(n):
        inv_L[i][i] = 1.0 / L[i][i]
        for j in range(i):
            inv_L[i][j] = -sum(L[i][m] * inv_L[m][j] for m in range(j, i)) / L[i][i]
    return xp.stack([xp.stack([sum(inv_L[m][i] * inv_L[m][j] for m in range(max(i, j), n))
                               for j in range(n)], axis=-1) for i in range(n)], axis=-2)


def _solve_normal(A, b, xp=np):
    """Batched normal-equation least squares; returns (x, (A^T A)^{-1}, rss).

    On NumPy with its matrix products and ``inv``; on another namespace (JAX) in
    elementwise products and sums and an unrolled Cholesky inverse: XLA on the CPU
    multiplies and inverts thousands of 4 x 4 systems ten to twenty times slower as
    batched matrix operations (measured, 20,480 systems)."""
    if xp is np:
        At = np.swapaxes(A, -1, -2)
        AtA = At @ A
        Atb = (At @ b[..., None])[..., 0]
    else:
        AtA = xp.sum(A[..., :, :, None] * A[..., :, None, :], axis=-3)
        Atb = xp.sum(A * b[..., None], axis=-2)
    # A relative ridge of 1e-12 keeps degenerate (clutter) systems solvable
    # without moving well-posed solutions beyond round-off.
    scale = xp.trace(AtA, axis1=-2, axis2=-1)[..., None, None]
    AtA = AtA + (1e-12 * scale + 1e-300) * np.eye(A.shape[-1])
    if xp is np:
        inv = np.linalg.inv(AtA)
        x = (inv @ Atb[..., None])[..., 0]
        r = (A @ x[..., None])[..., 0] - b
        return x, inv, np.einsum("...r,...r->...", r, r)
    inv = _spd_inverse(AtA, xp)
    x = xp.sum(inv * Atb[..., None, :], axis=-1)
    r = xp.sum(A * x[..., None, :], axis=-1) - b
    return x, inv, xp.sum(r * r, axis=-1)


class LeastSquaresPositioner:
    """Fused TDOA-DOA (or TDOA-only / DOA-only) least-squares fixes per detection.

    Args:
      calibration: the environment's ``AcousticCalibration`` (node positions,
        sound speed, noise model, tank extent).
      method: ``"fused"`` (§1.3), ``"tdoa"`` (§1.1) or ``"doa"`` (§1.2).
      weighting: ``"noise"`` (rows scaled by the documented noise model, see
        the module docstring) or ``"none"`` (the paper's plain stacking).
      gate: maximum ``chi2 / dof`` of a valid fix (``None``: no residual gate).
        Only meaningful with ``weighting="noise"``.
      variance_test: level of the model test above which a fix's covariance
        is scaled by its variance factor ``chi2 / dof`` (``None``: never;
        only with ``weighting="noise"``); see the module docstring.
      margin: metres by which a fix may lie outside the tank and stay valid.
    """

    def __init__(self, calibration, method: str = "fused", weighting: str = "noise",
                 gate: float | None = 1000.0, variance_test: float | None = 0.99,
                 margin: float = 1.0):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        if weighting not in WEIGHTINGS:
            raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
        if gate is not None and not gate > 0:
            raise ValueError(f"gate must be positive or None, got {gate}")
        if variance_test is not None and not 0 < variance_test < 1:
            raise ValueError(f"variance_test must be in (0, 1) or None, got {variance_test}")
        self.method = method
        self.weighting = weighting
        self.gate = gate
        self.variance_test = variance_test
        h = np.asarray(calibration.hydrophone_positions, dtype=np.float64)
        self._centre = h.mean(axis=0)
        self._nodes = h - self._centre
        self._c = float(calibration.sound_speed)
        self._n = len(h)
        sx, sy = calibration.tank_size
        self._low = np.array([-margin, -margin, -calibration.tank_depth - margin])
        self._high = np.array([sx + margin, sy + margin, margin])
        # Per-band noise stds at the work-area centre (calibration, not state).
        model = calibration.array.model(work_area_centre(calibration))
        self.tdoa_std = model["tdoa_std"]  # (Q, N-1) s, without the clock offsets
        self.clock_offset_std = float(calibration.config.clock_offset_std)
        self.azimuth_std = model["azimuth_std"]  # (Q, N)
        self.elevation_std = model["elevation_std"]  # (Q, N)
        self._row_scale = self._row_scales(self.clock_offset_std)  # (Q, rows)
        self.n_unknowns = 3 if method == "doa" else 4
        rows = {"fused": 3 * self._n - 1, "tdoa": self._n - 1, "doa": 2 * self._n}[method]
        self.dof = rows - self.n_unknowns
        # The model test's threshold on chi2 / dof (inf: the covariance is never scaled).
        self.variance_threshold = self._variance_threshold(self.dof)
        # ... and for every dof that node dropouts leave (solve_fixed looks it up).
        self._thresholds = np.array([self._variance_threshold(d) for d in range(rows + 1)])

    def _variance_threshold(self, dof: int) -> float:
        if self.variance_test is None or self.weighting != "noise" or dof <= 0:
            return math.inf
        return _model_test_threshold(self.variance_test, dof)

    def _rows_of(self, nodes, xp=np):
        """Which rows (rows,) the working ``nodes`` (N,) measure, and the unknowns left."""
        tdoa = nodes[1:] & nodes[0]
        blocks = {"fused": (tdoa, nodes, nodes), "tdoa": (tdoa,), "doa": (nodes, nodes)}
        unknowns = self.n_unknowns
        if self.method == "fused":  # no TDOA row: D_1 is not in the system
            unknowns = xp.where(xp.any(tdoa), unknowns, 3)
        return xp.concatenate(blocks[self.method]), unknowns

    def range_diff_std(self, clock_std) -> np.ndarray:
        """(Q, N-1) std of the measured range differences (m) with clock errors of ``clock_std``.

        ``clock_std`` (s) is a scalar or one value per TDOA (N-1,): the spread of
        the clock offsets left in the TDOAs (the calibration's
        ``clock_offset_std`` when nothing corrects them).
        """
        return self._c * np.hypot(self.tdoa_std, clock_std)

    def _row_scales(self, clock_std, xp=np) -> np.ndarray:
        """Per band, the factor multiplying each row's range (see :meth:`_row_std`)."""
        tdoa = 2.0 * self._c * xp.hypot(xp.asarray(self.tdoa_std), clock_std)
        angles = (xp.asarray(self.azimuth_std), xp.asarray(self.elevation_std))
        blocks = {"fused": (tdoa, *angles), "tdoa": (tdoa,), "doa": angles}[self.method]
        return xp.concatenate(blocks, axis=-1)

    # ------------------------------------------------------------------ systems
    def _system(self, tdoa, azimuth, elevation, xp=np):
        parts_A, parts_b = [], []
        if self.method in ("fused", "tdoa"):
            R, E = tdoa_rows(tdoa, self._nodes, self._c, xp)
            parts_A.append(R)
            parts_b.append(E)
        if self.method in ("fused", "doa"):
            I_, N_ = doa_rows(azimuth, elevation, self._nodes, xp)
            if self.method == "fused":  # I~ = [I, 0]: D_1 does not enter the DOA rows
                I_ = xp.concatenate([I_, xp.zeros(I_.shape[:-1] + (1,), I_.dtype)], axis=-1)
            parts_A.append(I_)
            parts_b.append(N_)
        return xp.concatenate(parts_A, axis=-2), xp.concatenate(parts_b, axis=-1)

    def _row_std(self, p, band, row_scale, xp=np):
        """First-order residual stds (..., rows) of each row at positions p (..., 3) in
        bands (...)."""
        diff = p[..., None, :] - self._nodes  # (..., N, 3)
        horizontal = xp.maximum(xp.hypot(diff[..., 0], diff[..., 1]), 1.0)
        ranges = xp.maximum(xp.hypot(horizontal, diff[..., 2]), 1.0)
        parts = []
        if self.method in ("fused", "tdoa"):
            parts.append(ranges[..., 1:])
        if self.method in ("fused", "doa"):
            parts += [horizontal, ranges]
        return xp.concatenate(parts, axis=-1) * xp.asarray(row_scale)[band]

    def _fix(self, tdoa, azimuth, elevation, band, rows, row_scale, dof, threshold, xp):
        """The fixes of detections (leading axes ``...``): the method's rows (an out node's
        weighing nothing when ``rows`` is given), the unweighted solve, the noise weights at
        its solution and the weighted solve; then the validity (finite, inside the tank,
        residual gate) and the model test. Returns (position, covariance, chi2, ok)."""
        A, b = self._system(tdoa, azimuth, elevation, xp)
        if rows is not None:  # an out node's rows weigh nothing
            A, b = A * rows[..., :, None], b * rows
        x, inv, rss = _solve_normal(A, b, xp)
        if self.weighting == "noise":
            w = 1.0 / self._row_std(x[..., :3], band, row_scale, xp)  # x centred
            if rows is not None:
                w = w * rows
            x, inv, rss = _solve_normal(A * w[..., None], b * w, xp)
        position = x[..., :3] + self._centre
        ok = xp.all(xp.isfinite(position), axis=-1) & (dof >= 0)
        ok &= xp.all((position >= self._low) & (position <= self._high), axis=-1)
        if self.gate is not None:
            ok &= xp.logical_or(dof <= 0, rss <= self.gate * dof)
        covariance = inv[..., :3, :3]
        if self.variance_test is not None and self.weighting == "noise":
            factor = rss / xp.maximum(dof, 1)  # the threshold is infinite without a dof
            covariance = covariance * xp.where(factor > threshold, factor, 1.0)[..., None, None]
        return position, covariance, rss, ok

    def solve_fixed(self, tdoa, azimuth, elevation, mask, nodes=None, xp=np,
                    clock=None) -> PositionFixes:
        """:meth:`solve`'s fixes of one measurement set at fixed shapes, on any array
        namespace (``jax.numpy`` under ``jit`` and ``vmap``; float32 there): every entry
        is solved, real or not, and the entries that are not real detections are never
        valid (their numbers, finite or not, mean nothing).

        Args:
          tdoa: (Q, K, N-1); azimuth, elevation: (Q, K, N); mask: (Q, K); nodes: (N,) or
            None; clock: ``(offset, std)`` or None, as for :meth:`solve`. Shapes are not
            checked beyond broadcasting.

        Returns:
          :class:`PositionFixes` whose ``dof`` is an array (it depends on ``nodes``).
        """
        q, k = mask.shape
        band = xp.broadcast_to(xp.arange(q)[:, None], (q, k))
        rows, dof, threshold = None, xp.asarray(self.dof), xp.asarray(self.variance_threshold)
        if nodes is not None:
            used, unknowns = self._rows_of(xp.asarray(nodes).astype(bool), xp)
            rows = used.astype(tdoa.dtype)
            dof = xp.sum(used) - unknowns
            threshold = xp.asarray(self._thresholds)[xp.clip(dof, 0, len(self._thresholds) - 1)]
        row_scale = self._row_scale
        if clock is not None:
            tdoa = tdoa - clock[0]
            row_scale = self._row_scales(clock[1], xp)
        position, covariance, chi2, ok = self._fix(
            tdoa, azimuth, elevation, band, rows, row_scale, dof, threshold, xp)
        return PositionFixes(position, covariance, chi2, dof, ok & xp.asarray(mask).astype(bool))

    def solve(self, tdoa, azimuth, elevation, mask=None, clock=None,
              nodes=None) -> PositionFixes:
        """Fix every detection of a measurement set.

        Only the real detections (``mask``) are solved, in one batch; the
        entries of the others are NaN (position, covariance, chi2) and invalid.
        The rows of nodes that are out (``nodes``) are left out.

        Args:
          tdoa: (Q, K, N-1) s; azimuth, elevation: (Q, K, N) rad. The leading
            axis must be the band axis (its noise model is per band); any
            number of leading axes ``(Q, ...)`` works.
          mask: (Q, K) real-detection flags (default: all real).
          clock: ``(offset, std)`` of the clock offsets, each (N-1,) s, e.g.
            from a :class:`ClockOffsetEstimator`: ``offset`` is subtracted from
            every TDOA and ``std`` replaces the calibration's
            ``clock_offset_std`` in the row weights. Default: no correction.
          nodes: (N,) which nodes work (the observation's ``node_mask``); their
            measurements are the only ones used (see the module docstring).
            Default: all.

        Returns:
          :class:`PositionFixes` over the leading axes; ``dof`` is that of the
          rows used.
        """
        tdoa = np.asarray(tdoa, dtype=np.float64)
        azimuth = np.asarray(azimuth, dtype=np.float64)
        elevation = np.asarray(elevation, dtype=np.float64)
        lead = azimuth.shape[:-1]
        if (tdoa.shape != lead + (self._n - 1,) or azimuth.shape[-1] != self._n
                or elevation.shape != azimuth.shape):
            raise ValueError(
                f"expected tdoa (..., {self._n - 1}) and azimuth/elevation (..., {self._n}) "
                f"with equal leading axes, got {tdoa.shape}, {azimuth.shape}, {elevation.shape}"
            )
        n_bands = len(self._row_scale)
        if lead[:1] != (n_bands,):
            raise ValueError(f"the leading axis must be the {n_bands} bands, got shape {lead}")
        mask = np.ones(lead, bool) if mask is None else np.asarray(mask).astype(bool)
        if mask.shape != lead:
            raise ValueError(f"mask must have shape {lead}, got {mask.shape}")
        rows, dof, threshold = None, self.dof, self.variance_threshold
        if nodes is not None:
            nodes = np.asarray(nodes).astype(bool)
            if nodes.shape != (self._n,):
                raise ValueError(f"nodes must have shape ({self._n},), got {nodes.shape}")
            if not nodes.all():
                used, unknowns = self._rows_of(nodes)
                rows = used.astype(np.float64)
                dof = int(used.sum()) - int(unknowns)
                threshold = self._variance_threshold(dof)
        sel = np.nonzero(mask)
        tdoa_sel, row_scale = tdoa[sel], self._row_scale
        if clock is not None:
            offset, std = (np.asarray(v, dtype=np.float64) for v in clock)
            if offset.shape != (self._n - 1,) or std.shape != (self._n - 1,):
                raise ValueError(f"clock offset and std must each have shape ({self._n - 1},), "
                                 f"got {offset.shape} and {std.shape}")
            tdoa_sel = tdoa_sel - offset
            row_scale = self._row_scales(std)
        position, covariance, rss, ok = self._fix(  # sel[0]: the bands
            tdoa_sel, azimuth[sel], elevation[sel], sel[0], rows, row_scale, dof, threshold, np)
        out_position = np.full(lead + (3,), np.nan)
        out_covariance = np.full(lead + (3, 3), np.nan)
        chi2 = np.full(lead, np.nan)
        valid = np.zeros(lead, bool)
        out_position[sel], out_covariance[sel] = position, covariance
        chi2[sel], valid[sel] = rss, ok
        return PositionFixes(out_position, out_covariance, chi2, dof, valid)


class ClockState(NamedTuple):
    """A clock-offset estimate: the offsets (N-1,) s and their precisions (N-1,) 1/s^2."""

    offset: np.ndarray
    precision: np.ndarray


class ClockOffsetEstimator:
    """Online estimate of the nodes' clock offsets against node 1 (see the module docstring).

    The offsets ``b`` (N-1,) enter the TDOAs as ``tau_1i + b_i``. Each update
    takes the detections whose fused fix was valid, fixes them again from
    their DOA rows only (``p``, covariance ``P``), and forms the residuals
    ``r_i = tau_1i - (|p - h_i| - |p - h_1|) / c`` with first-order variance
    ``g_i^T P g_i / c^2 + std(tau_1i)^2`` (``g_i`` the difference of the unit
    vectors from nodes 1 and i to ``p``). Residuals within ``gate`` standard
    deviations of the current estimate update a per-node information-weighted
    mean that starts from the prior ``N(0, clock_offset_std^2)``. The nodes
    are treated independently (their residuals share the DOA error of ``p``;
    ignoring that loses some efficiency, not consistency).

    Args:
      calibration: the environment's ``AcousticCalibration``.
      gate: residual gate in standard deviations.
    """

    def __init__(self, calibration, gate: float = 4.0):
        if not gate > 0:
            raise ValueError(f"gate must be positive, got {gate}")
        self.gate = float(gate)
        self._doa = LeastSquaresPositioner(calibration, "doa")
        self._nodes = np.asarray(calibration.hydrophone_positions, dtype=np.float64)
        self._c = float(calibration.sound_speed)
        self._tdoa_var = self._doa.tdoa_std ** 2  # (Q, N-1)
        self._prior_precision = 1.0 / max(self._doa.clock_offset_std, 1e-9) ** 2
        self.reset()

    def reset(self) -> None:
        n = len(self._nodes) - 1
        self.offset = np.zeros(n)
        self._precision = np.full(n, self._prior_precision)
        self.samples = 0

    @property
    def std(self) -> np.ndarray:
        """(N-1,) standard deviation of the offset estimates (s)."""
        return 1.0 / np.sqrt(self._precision)

    @property
    def clock(self) -> tuple[np.ndarray, np.ndarray]:
        """``(offset, std)`` for :meth:`LeastSquaresPositioner.solve`'s ``clock``."""
        return self.offset, self.std

    def update(self, tdoa, azimuth, elevation, valid, nodes=None) -> None:
        """Fold in the detections flagged ``valid`` (Q, K) of one measurement set.

        ``nodes`` (N,): which nodes work (default all); an out node's offset
        learns nothing, and no offset does while node 1 is out.
        """
        measured = True
        if nodes is not None:
            nodes = np.asarray(nodes).astype(bool)
            measured = nodes[1:] & nodes[0]
            if not measured.any():
                return
        fixes = self._doa.solve(tdoa, azimuth, elevation, valid, nodes=nodes)
        sel = np.nonzero(fixes.valid)
        if not len(sel[0]):
            return
        state, kept = self._fold(ClockState(self.offset, self._precision),
                                 np.asarray(tdoa, dtype=np.float64)[sel], fixes.position[sel],
                                 fixes.covariance[sel], sel[0], measured)
        self.offset, self._precision = state
        self.samples += int(kept)

    def _fold(self, state: ClockState, tdoa, position, covariance, band, keep, xp=np):
        """The estimate after the DOA fixes ``position`` (M, 3), ``covariance`` (M, 3, 3)
        of detections in bands ``band`` (M,) with TDOAs ``tdoa`` (M, N-1), the residuals
        that ``keep`` (broadcast to (M, N-1)) allows and the gate passes; and how many
        residuals it took."""
        diff = position[:, None, :] - xp.asarray(self._nodes, position.dtype)  # (M, N, 3)
        ranges = xp.linalg.norm(diff, axis=-1)
        units = diff / ranges[..., None]
        predicted = (ranges[:, 1:] - ranges[:, :1]) / self._c
        g = units[:, 1:] - units[:, :1]  # (M, N-1, 3)
        variance = (xp.einsum("mni,mij,mnj->mn", g, covariance, g) / self._c ** 2
                    + xp.asarray(self._tdoa_var)[band])
        innovation = tdoa - predicted - state.offset
        keep = keep & (innovation ** 2 <= self.gate ** 2 * (variance + 1.0 / state.precision))
        information = xp.where(keep, 1.0 / variance, 0.0)
        precision = state.precision + information.sum(axis=0)
        offset = state.offset + xp.sum(xp.where(keep, information * innovation, 0.0),
                                       axis=0) / precision
        return ClockState(offset, precision), xp.sum(keep)

    def start(self, xp=np) -> ClockState:
        """The estimate of a new episode for :meth:`step` (the prior)."""
        n, dtype = len(self._nodes) - 1, np.float64 if xp is np else xp.float32
        return ClockState(xp.zeros(n, dtype), xp.full(n, self._prior_precision, dtype))

    def step(self, state: ClockState, tdoa, azimuth, elevation, valid, nodes=None,
             xp=np) -> ClockState:
        """:meth:`update` as a pure function at fixed shapes on any array namespace (the
        DOA fixes by :meth:`LeastSquaresPositioner.solve_fixed`): the estimate after one
        measurement set's detections flagged ``valid`` (Q, K)."""
        q, k = valid.shape
        fixes = self._doa.solve_fixed(tdoa, azimuth, elevation, valid, nodes=nodes, xp=xp)
        measured = xp.ones(len(self._nodes) - 1, bool)
        if nodes is not None:
            nodes = xp.asarray(nodes).astype(bool)
            measured = nodes[1:] & nodes[0]
        ok = fixes.valid.reshape(-1)
        position = xp.where(ok[:, None], fixes.position.reshape(-1, 3), 0.0)
        covariance = xp.where(ok[:, None, None], fixes.covariance.reshape(-1, 3, 3),
                              xp.eye(3))
        band = xp.broadcast_to(xp.arange(q)[:, None], (q, k)).reshape(-1)
        state, _ = self._fold(state, xp.asarray(tdoa).reshape(q * k, -1), position,
                              covariance, band, ok[:, None] & measured, xp)
        return state
