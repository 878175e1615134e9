"""Cubature Kalman filter and the AUV motion model it runs on ([LTAT], §2.3, eqs. 7-28).

Components, each with one role:

* :class:`CubatureKalmanFilter`: the third-degree spherical-radial CKF
  (Arasaratnam and Haykin 2009), generic over a process function ``f`` and a
  measurement function ``h`` with additive Gaussian noise.
* :class:`HeaveSurgeModel`: eq. 8's motion, the process model ``f``.
* :func:`white_acceleration_noise`: the process noise ``Q``.
* :func:`position_measurement`: eq. 9, the measurement model ``h``.
* :func:`fit_heave`: least-squares sinusoid fit of measured heights, which
  gives eq. 8's ``C`` ("determined by the sine wave period") and the mean
  level when the agent does not know them.

**State** (eq. 7): ``X = (x, y, z, vx, vy, vz)``, the AUV's centre of gravity
and its velocity (m, m/s), ``n = 6``.

**Cubature points** (eqs. 13-16). For ``N(x, P)`` in ``n`` dimensions, with
``S`` a square root ``P = S S^T`` (Cholesky; a clipped eigen-decomposition
when round-off leaves ``P`` indefinite, :func:`covariance_root`) and ``e_i``
the unit vectors::

    xi_i     =  sqrt(n) e_i,   xi_(n+i) = -sqrt(n) e_i,   i = 1..n   (eq. 13, m = 2n)
    w_i      =  1 / (2n)                                             (eq. 14)
    chi_i    =  x + S xi_i,    i = 1..2n                             (eqs. 15-16)

**Time update** (eqs. 17-19), :meth:`CubatureKalmanFilter.predict`::

    chi*_i   =  f(chi_i)                                             (eq. 17)
    x-       =  sum_i w_i chi*_i                                     (eq. 18)
    P-       =  sum_i w_i (chi*_i - x-)(chi*_i - x-)^T + Q           (eq. 19)

(eq. 19 is printed as ``sum w chi* chi*^T - x- x-^T + Q``; the form about
the mean is the same sum without the cancellation of two large terms).

**Measurement update** (eqs. 20-28), :meth:`CubatureKalmanFilter.update`,
with the points ``chi_i`` redrawn from ``N(x-, P-)`` (eqs. 20-21)::

    Z_i      =  h(chi_i)                                             (eq. 22)
    z^       =  sum_i w_i Z_i                                        (eq. 23)
    Pz       =  sum_i w_i (Z_i - z^)(Z_i - z^)^T + R                 (eq. 24)
    Pxz      =  sum_i w_i (chi_i - x-)(Z_i - z^)^T                   (eq. 25)
    K        =  Pxz Pz^-1                                            (eq. 26)
    x+       =  x- + K (z - z^)                                      (eq. 27)
    P+       =  P- - K Pz K^T  =  P- - K Pxz^T                       (eq. 28)

``P+`` is then symmetrised. Not in the paper: an optional chi-square gate
rejects ``z`` (the estimate unchanged) when the normalised innovation
squared ``(z - z^)^T Pz^-1 (z - z^)`` exceeds it.

**Process model** (eq. 8), :class:`HeaveSurgeModel`: with sampling interval
``T``, heave angular frequency ``C`` and mean level ``z_mean``,
``X_k = F X_(k-1) + (I - F) z_mean e_z + n_k`` where ``F`` moves
``x += T vx`` (uniform surge), ``y += T vy`` (``vy`` a slow drift the
process noise keeps near zero), holds ``vx, vy``, and advances the heave
pair by the exact solution of ``z'' = -C^2 (z - z_mean)`` over one step::

    z_k  - z_mean  =  cos(C T) (z_(k-1) - z_mean) + sin(C T) / C  vz_(k-1)
    vz_k           = -C sin(C T) (z_(k-1) - z_mean) + cos(C T) vz_(k-1)

or, with ``discretisation="euler"``, its first-order form
``z_k = z_(k-1) + T vz_(k-1)``, ``vz_k = vz_(k-1) - C^2 T (z_(k-1) - z_mean)``
(eq. 8 as printed, ``z + C T vz`` and ``vz - C T z``, with its velocity read
as the scaled rate ``z'/C``). The process noise ``n_k ~ N(0, Q)`` is white
acceleration of spectral density ``q = sigma^2`` per axis,
``Q_axis = q [[T^3/3, T^2/2], [T^2/2, T]]`` on each (position, velocity)
pair.

**Measurement model** (eq. 9), :func:`position_measurement`:
``Z_k = H X_k + m_k``, ``H = [I_3 0]``, ``m_k ~ N(0, R_k)``, where the
``ckf-pd`` agent passes each fix's own ``R_k`` (the marker corners' pixel
noise carried through the triangulation of eq. 2, see
:class:`~baselines.lars.perception.marker.MarkerLocaliser`).

Every function takes and returns plain numpy arrays; the filter vectorises
the ``2n`` points as the rows of one ``(2n, n)`` array.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize_scalar

#: ``f(points (k, n)) -> (k, n)``, ``h(points (k, n)) -> (k, m)``.
PointFunction = Callable[[np.ndarray], np.ndarray]


def covariance_root(covariance: np.ndarray) -> np.ndarray:
    """A square root ``S`` with ``S S^T = P`` (eq. 15).

    Cholesky when ``P`` is positive definite. Round-off can leave a
    covariance with a tiny negative eigenvalue (a state the measurements
    pinned down exactly); then the symmetric part's eigen-decomposition with
    negative eigenvalues clipped to zero is used, which is the nearest
    positive semi-definite root.

    Raises:
        ValueError: if ``P`` is not finite.
    """
    p = np.asarray(covariance, dtype=float)
    if not np.all(np.isfinite(p)):
        raise ValueError("covariance has non-finite entries")
    return _root(p)


def _root(p: np.ndarray) -> np.ndarray:
    # LAPACK's potrf directly: numpy's cholesky wrapper costs 4x more on 6 x 6
    root, info = lapack.dpotrf(p, lower=1, clean=1)
    if info == 0:
        return root
    w, v = np.linalg.eigh(0.5 * (p + p.T))
    return v * np.sqrt(np.clip(w, 0.0, None))


def _solve_spd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 b`` for a symmetric positive definite ``a`` (LAPACK posv; LU if not PD)."""
    _, x, info = lapack.dposv(a, b, lower=1)
    if info == 0:
        return x
    try:
        return np.linalg.solve(a, b)
    except np.linalg.LinAlgError as exc:
        raise FloatingPointError("innovation covariance is singular") from exc


def cubature_points(mean: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """The ``2n`` cubature points (rows) of ``N(mean, covariance)`` (eqs. 13, 15-16)."""
    mean = np.asarray(mean, dtype=float)
    return _points(mean, covariance_root(covariance))


def _points(mean: np.ndarray, root: np.ndarray) -> np.ndarray:
    spread = math.sqrt(mean.shape[0]) * root.T  # row i: sqrt(n) S e_i
    return np.concatenate((mean + spread, mean - spread))


class CubatureKalmanFilter:
    """Third-degree spherical-radial cubature Kalman filter ([LTAT], eqs. 13-28).

    Args:
        transition: ``f``, maps an ``(k, n)`` array of states to the next states.
        measurement: ``h``, maps an ``(k, n)`` array of states to ``(k, m)``
            predicted measurements.
        process_noise: ``Q`` (n, n), additive.
        measurement_noise: default ``R`` (m, m), additive; :meth:`update` may
            pass its own per measurement.

    Attributes:
        mean, covariance: the current estimate (``None`` before
            :meth:`initialise`).
        last_nis: normalised innovation squared of the last :meth:`update`.
    """

    def __init__(
        self,
        transition: PointFunction,
        measurement: PointFunction,
        process_noise: np.ndarray,
        measurement_noise: np.ndarray,
    ):
        self.transition = transition
        self.measurement = measurement
        self.process_noise = _square("process_noise", process_noise)
        self.measurement_noise = _square("measurement_noise", measurement_noise)
        self.mean: np.ndarray | None = None
        self.covariance: np.ndarray | None = None
        self.last_nis = math.nan

    @property
    def initialised(self) -> bool:
        return self.mean is not None

    def initialise(self, mean, covariance) -> None:
        """Start from ``N(mean, covariance)``.

        Raises:
            ValueError: on shapes that do not match ``Q`` or non-finite values.
        """
        n = self.process_noise.shape[0]
        mean = np.array(mean, dtype=float)
        covariance = _square("covariance", covariance)
        if mean.shape != (n,) or covariance.shape != (n, n):
            raise ValueError(f"expected a ({n},) mean and ({n}, {n}) covariance, "
                             f"got {mean.shape} and {covariance.shape}")
        if not np.all(np.isfinite(mean)):
            raise ValueError("initial mean has non-finite entries")
        self.mean, self.covariance = mean, covariance
        self.last_nis = math.nan

    def predict(self) -> None:
        """Time update, eqs. 15-19.

        Eq. 19's ``sum w X X^T - x x^T`` is evaluated about the mean
        (``sum w (X - x)(X - x)^T``): algebraically identical, without the
        cancellation of two large terms.
        """
        self._require_state()
        # the filter keeps its covariance finite (_set), so no re-check here
        points = self.transition(_points(self.mean, _root(self.covariance)))  # eq. 17
        weight = 1.0 / points.shape[0]  # eq. 14
        mean = np.add.reduce(points) * weight  # eq. 18
        dev = points - mean
        cov = (dev.T @ dev) * weight + self.process_noise  # eq. 19 (symmetric: syrk)
        self._set(mean, cov, symmetrise=False)

    def update(self, z, noise: np.ndarray | None = None, gate: float | None = None) -> bool:
        """Measurement update with ``z``, eqs. 20-28.

        Args:
            z: the measurement (m,).
            noise: ``R`` for this measurement (default: the constructor's).
            gate: if given, reject the measurement when its normalised
                innovation squared ``nu^T Pz^-1 nu`` exceeds it (a chi-square
                gate against outliers); the estimate is then unchanged.

        Returns:
            Whether the measurement was used.

        Raises:
            ValueError: on a non-finite measurement or noise of the wrong shape.
        """
        self._require_state()
        z = np.asarray(z, dtype=float)
        r = self.measurement_noise if noise is None else np.asarray(noise, dtype=float)
        if not math.isfinite(np.add.reduce(z) + np.add.reduce(r, None)):
            raise ValueError("measurement or its noise has non-finite entries")
        if r.shape != (z.shape[0], z.shape[0]):
            raise ValueError(f"measurement noise must be ({z.shape[0]}, {z.shape[0]}), "
                             f"got {r.shape}")
        points = _points(self.mean, _root(self.covariance))  # eqs. 20-21
        z_points = self.measurement(points)  # eq. 22
        weight = 1.0 / points.shape[0]
        z_hat = np.add.reduce(z_points) * weight  # eq. 23
        dz = z_points - z_hat
        pz = (dz.T @ dz) * weight + r  # eq. 24
        pxz = ((points - self.mean).T @ dz) * weight  # eq. 25
        innovation = z - z_hat
        solved = _solve_spd(pz, np.concatenate((innovation[:, None], pxz.T), axis=1))
        self.last_nis = float(innovation @ solved[:, 0])
        if gate is not None and not self.last_nis <= gate:
            return False
        gain = solved[:, 1:].T  # eq. 26: Pxz Pz^-1 (Pz symmetric)
        mean = self.mean + gain @ innovation  # eq. 27
        cov = self.covariance - gain @ pxz.T  # eq. 28: K Pz K^T = K Pxz^T
        self._set(mean, cov)
        return True

    def _set(self, mean: np.ndarray, cov: np.ndarray, symmetrise: bool = True) -> None:
        if symmetrise:
            cov = 0.5 * (cov + cov.T)
        if not math.isfinite(np.add.reduce(mean) + np.add.reduce(cov, None)):  # NaN/inf propagate
            raise FloatingPointError("the cubature Kalman filter diverged (non-finite estimate)")
        self.mean, self.covariance = mean, cov

    def _require_state(self) -> None:
        if self.mean is None:
            raise RuntimeError("call initialise() before predict() or update()")


def _square(name: str, matrix) -> np.ndarray:
    m = np.array(matrix, dtype=float)
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name} has non-finite entries")
    return m


# ---------------------------------------------------------------- motion model (eq. 8)
STATE_SIZE = 6
DISCRETISATIONS = ("exact", "euler")


@dataclasses.dataclass(frozen=True)
class HeaveSurgeModel:
    """[LTAT]'s AUV motion (eq. 8) on the state ``(x, y, z, vx, vy, vz)`` of eq. 7.

    Uniform surge along x (``x += T vx``), y held (``y += T vy`` with ``vy``
    a slow drift the process noise keeps near zero), and a sinusoidal heave:
    ``z`` oscillates about ``z_mean`` with angular frequency ``C = omega``.
    Velocities are in m/s as eq. 7 defines them.

    ``discretisation="exact"`` (default) advances the heave pair by the exact
    solution of ``z'' = -C^2 (z - z_mean)`` over one step, a rotation by
    ``C T``. ``"euler"`` is its first-order form ``z + T vz``,
    ``vz - C^2 T (z - z_mean)``: eq. 8 as printed (``z + C T vz``,
    ``vz - C T z``) with its velocity read as the scaled rate ``z'/C``. The
    first-order form inflates the amplitude by ``sqrt(1 + (C T)^2)`` per
    step, which a filter bridging a lost marker would carry along.

    Args:
        dt: sampling interval ``T``, s.
        omega: ``C``, rad/s (``2 pi / heave period``).
        z_mean: the level the heave oscillates about, m.
        discretisation: ``"exact"`` or ``"euler"``.
    """

    dt: float
    omega: float
    z_mean: float = 0.0
    discretisation: str = "exact"
    matrix: np.ndarray = dataclasses.field(init=False, repr=False, compare=False)
    _offset: np.ndarray = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self):
        for name in ("dt", "omega"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")
        if not math.isfinite(self.z_mean):
            raise ValueError(f"z_mean must be finite, got {self.z_mean}")
        if self.discretisation not in DISCRETISATIONS:
            raise ValueError(f"discretisation must be one of {DISCRETISATIONS}, "
                             f"got {self.discretisation!r}")
        t, c = self.dt, self.omega
        f = np.eye(STATE_SIZE)
        f[0, 3] = f[1, 4] = t
        if self.discretisation == "exact":
            co, si = math.cos(c * t), math.sin(c * t)
            f[2, 2], f[2, 5], f[5, 2], f[5, 5] = co, si / c, -c * si, co
        else:
            f[2, 5], f[5, 2] = t, -c * c * t
        f.setflags(write=False)
        level = np.zeros(STATE_SIZE)
        level[2] = self.z_mean
        offset = level - f @ level  # the oscillation is about z_mean, not 0
        offset.setflags(write=False)
        object.__setattr__(self, "matrix", f)
        object.__setattr__(self, "_offset", offset)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """Next states of the rows of ``states`` (k, 6) (or of one state (6,))."""
        return states @ self.matrix.T + self._offset

    def kinematics(self, state, horizon: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration (3 each) ``horizon`` s after ``state``.

        The continuous-time solution of the model (no process noise), used to
        plan the arm's trajectory towards where the AUV will be.
        """
        s = np.asarray(state, dtype=float)
        c, h = self.omega, float(horizon)
        co, si = math.cos(c * h), math.sin(c * h)
        dz, vz = s[2] - self.z_mean, s[5]
        z_dev = co * dz + si / c * vz
        pos = np.array([s[0] + h * s[3], s[1] + h * s[4], self.z_mean + z_dev])
        vel = np.array([s[3], s[4], -c * si * dz + co * vz])
        acc = np.array([0.0, 0.0, -c * c * z_dev])
        return pos, vel, acc

    def with_heave(self, omega: float, z_mean: float) -> HeaveSurgeModel:
        """The same model with a new heave frequency and mean level."""
        return dataclasses.replace(self, omega=omega, z_mean=z_mean)


def position_measurement(states: np.ndarray) -> np.ndarray:
    """Eq. 9: the measured position ``H X`` of each state row (``H = [I 0]``)."""
    return states[..., :3]


def white_acceleration_noise(dt: float, accel_std) -> np.ndarray:
    """``Q`` (6, 6) for white acceleration noise of std ``accel_std`` (3,) m/s^2 per axis.

    The discrete white-noise-acceleration covariance of each position/velocity
    pair, ``q [[T^3/3, T^2/2], [T^2/2, T]]`` with ``q = std^2`` read as a
    spectral density (m^2/s^3) over one step; for the heave pair it is the
    same to first order in ``C T``.
    """
    std = np.broadcast_to(np.asarray(accel_std, dtype=float), (3,))
    if not (dt > 0 and np.all(np.isfinite(std)) and np.all(std >= 0)):
        raise ValueError(f"dt must be positive and accel_std finite and >= 0, got {dt}, {std}")
    q = np.zeros((STATE_SIZE, STATE_SIZE))
    for axis, s2 in enumerate(std**2):
        q[axis, axis] = s2 * dt**3 / 3.0
        q[axis, axis + 3] = q[axis + 3, axis] = s2 * dt**2 / 2.0
        q[axis + 3, axis + 3] = s2 * dt
    return q


# ---------------------------------------------------------------- heave frequency (eq. 8's C)
@dataclasses.dataclass(frozen=True)
class HeaveFit:
    """``z(t) ~ mean + amplitude sin(omega t + phase)`` fitted by least squares.

    Attributes:
        omega: rad/s. mean, amplitude: m. phase: rad, at the first sample's time.
        rms: root-mean-square residual, m.
        samples: number of heights used; span: time they cover, s.
    """

    omega: float
    mean: float
    amplitude: float
    phase: float
    rms: float
    samples: int
    span: float


def _sinusoid_residuals(times: np.ndarray, z: np.ndarray, omegas: np.ndarray):
    """Least-squares ``(sin, cos, 1)`` coefficients (G, 3) and residual RMS (G,) per omega."""
    wt = omegas[:, None] * times[None, :]
    basis = np.stack((np.sin(wt), np.cos(wt), np.ones_like(wt)), axis=-1)  # (G, N, 3)
    normal = np.einsum("gni,gnj->gij", basis, basis)
    rhs = np.einsum("gni,n->gi", basis, z)
    coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
    resid = z[None, :] - np.einsum("gni,gi->gn", basis, coef)
    return coef, np.sqrt(np.mean(resid**2, axis=1))


def fit_heave(times, z, omega_bounds=(0.5, 1.6), grid: int = 48) -> HeaveFit:
    """Fit a sinusoid of unknown frequency to heights ``z`` at ``times``.

    For a fixed ``omega`` the model is linear in ``(a, b, mean)`` of
    ``a sin(omega t) + b cos(omega t) + mean``; the frequency minimising the
    residual is found on a grid over ``omega_bounds`` and refined with a
    bounded scalar search (scipy) around the best grid point.

    Raises:
        ValueError: with fewer than 4 heights, mismatched or non-finite
            inputs, or bounds that are not ``0 < lo < hi``.
    """
    t = np.asarray(times, dtype=float)
    z = np.asarray(z, dtype=float)
    lo, hi = (float(b) for b in omega_bounds)
    if t.shape != z.shape or t.ndim != 1 or t.size < 4:
        raise ValueError(f"need matching 1-D times and heights (>= 4), got {t.shape}, {z.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(z))):
        raise ValueError("times and heights must be finite")
    if not 0.0 < lo < hi:
        raise ValueError(f"omega_bounds must satisfy 0 < lo < hi, got {omega_bounds}")
    t = t - t[0]  # conditioning: the basis stays O(1)
    omegas = np.linspace(lo, hi, grid)
    _, rms = _sinusoid_residuals(t, z, omegas)
    best = int(np.argmin(rms))
    step = omegas[1] - omegas[0]
    result = minimize_scalar(
        lambda w: float(_sinusoid_residuals(t, z, np.array([w]))[1][0]),
        bounds=(max(lo, omegas[best] - step), min(hi, omegas[best] + step)),
        method="bounded", options={"xatol": 1e-5},
    )
    omega = float(result.x)
    coef, rms_best = _sinusoid_residuals(t, z, np.array([omega]))
    a, b, mean = coef[0]
    return HeaveFit(
        omega=omega, mean=float(mean), amplitude=math.hypot(a, b),
        phase=math.atan2(b, a), rms=float(rms_best[0]), samples=int(t.size),
        span=float(t[-1]),
    )
