"""Irregular long-crested seas: wave spectra, a seeded realisation, and the linear
motions of floating bodies in it.

**Spectra.** Pierson–Moskowitz and JONSWAP by significant wave height ``Hs``
and peak period ``Tp`` (DNV-RP-C205, *Environmental Conditions and
Environmental Loads*, 2010, §3.5.5; Fossen, *Handbook of Marine Craft
Hydrodynamics and Motion Control*, 2nd ed., 2021, ch. 10)::

    S_PM(w) = 5/16 Hs^2 wp^4 w^-5 exp(-5/4 (w / wp)^-4),       wp = 2 pi / Tp
    S_J(w)  = A(gamma) S_PM(w) gamma^exp(-(w - wp)^2 / (2 sigma^2 wp^2)),
              sigma = 0.07 (w <= wp), 0.09 (w > wp)

``A(gamma)`` is computed here by quadrature so that ``4 sqrt(m0) = Hs``
exactly (DNV's ``1 - 0.287 ln gamma`` is its fit); ``gamma = 1`` is PM.

**Realisation.** The sum of ``N`` long-crested components (Fossen 2021,
ch. 10, the wave-elevation "sum of harmonics")::

    eta(x, y, t) = sum_i a_i cos(w_i t - k_i (x cos b + y sin b) + e_i)

with deep-water dispersion ``k = w^2 / g``, travel direction ``b`` (from
world +x, counter-clockwise), one frequency drawn uniformly inside each of
``N`` equal bands (equal spacing would repeat after ``2 pi / dw``), phases
uniform in ``[0, 2 pi)`` and ``a_i = sqrt(2 S(w_i) dw)``.

**Responses** (linear, as transfer functions of one component, used by the
caller as response amplitude operators): in waves long against a body, the
body follows the surface in heave and aligns with its slope in roll and pitch
(the long-wave, Froude–Krylov limit: Faltinsen, *Sea Loads on Ships and
Offshore Structures*, 1990, ch. 3). The surface seen by a waterplane of length
``L`` and beam ``B`` is averaged over it: the mean elevation of a plane wave
over a length is ``j0(k L / 2) = sin(x) / x`` of the wave, the least-squares
slope ``k j1'(x) = k 3 (sin x - x cos x) / x^3`` of its slope (exact averages,
worked out here; both tend to 1 for long waves). A small floater
(:class:`FloaterResponse`, the AUV) follows that averaged surface with a
first-order lag in roll and pitch; a ship (:class:`ShipResponse`) responds to
it as three uncoupled, linear mass-spring-damper modes with natural periods
and damping ratios of a ship (Faltinsen 1990, chs. 3-4; Fossen 2021, ch. 10).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.integrate import trapezoid

from auv_envs.core.frames import GRAVITY
from auv_envs.core.pytree import attribute_pytree

SPECTRUM_KINDS = ("jonswap", "pierson-moskowitz")

#: Douglas sea scale / WMO sea state code 3700: code -> (description, Hs range in m)
#: (WMO Manual on Codes, table 3700; reproduced in Fossen 2021, ch. 10).
SEA_STATE_CODES = {
    0: ("calm (glassy)", 0.0, 0.0),
    1: ("calm (rippled)", 0.0, 0.1),
    2: ("smooth (wavelets)", 0.1, 0.5),
    3: ("slight", 0.5, 1.25),
    4: ("moderate", 1.25, 2.5),
    5: ("rough", 2.5, 4.0),
    6: ("very rough", 4.0, 6.0),
    7: ("high", 6.0, 9.0),
    8: ("very high", 9.0, 14.0),
    9: ("phenomenal", 14.0, math.inf),
}

#: Pierson & Moskowitz (1964): ``alpha`` (Phillips' constant) and ``beta`` of
#: ``S(w) = alpha g^2 w^-5 exp(-beta (g / (U w))^4)`` for a fully developed sea.
PM_ALPHA = 8.1e-3
PM_BETA = 0.74
#: Realisation defaults: component count and the frequency band in units of
#: the peak frequency (PM energy outside [0.5, 4] wp: 0.5 %).
DEFAULT_COMPONENTS = 100
DEFAULT_BAND = (0.5, 4.0)
#: Breaking limit of the steepness ``Hs / lambda_p`` (Michell's ``H / lambda``
#: of the steepest regular wave, about 1/7).
MAX_STEEPNESS = 1.0 / 7.0


def _finite_positive(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
        math.isfinite(value) and value > 0
    ):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def _pm_shape(x: np.ndarray, xp) -> np.ndarray:
    """``S_PM(w) wp / Hs^2`` at ``x = w / wp`` (integrates to 1/16)."""
    with np.errstate(divide="ignore", over="ignore"):
        x = xp.maximum(x, 1e-3)
        return 0.3125 * x**-5 * xp.exp(-1.25 * x**-4)


def _peak_factor(x: np.ndarray, gamma: float, xp) -> np.ndarray:
    sigma = xp.where(x <= 1.0, 0.07, 0.09)
    return gamma ** xp.exp(-0.5 * ((x - 1.0) / sigma) ** 2)


@dataclasses.dataclass(frozen=True)
class SeaSpectrum:
    """A one-sided wave spectrum ``S(w)`` in m^2 s/rad, parameterised by ``Hs`` and ``Tp``.

    Attributes:
        hs: significant wave height ``4 sqrt(m0)``, m.
        tp: peak period, s.
        kind: ``"jonswap"`` (default) or ``"pierson-moskowitz"``.
        gamma: JONSWAP peak-enhancement factor (default 3.3, the JONSWAP
            mean; DNV-RP-C205 §3.5.5.5 recommends 1-5 by ``Tp / sqrt(Hs)``,
            see :meth:`dnv`); ignored by Pierson–Moskowitz.

    Raises:
        ValueError: non-positive or non-finite ``hs``/``tp``, an unknown
            ``kind``, ``gamma`` outside [1, 20], or a sea steeper than
            breaking (``Hs / lambda_p > 1/7``).
    """

    hs: float
    tp: float
    kind: str = "jonswap"
    gamma: float = 3.3

    def __post_init__(self):
        hs = _finite_positive("hs", self.hs)
        tp = _finite_positive("tp", self.tp)
        if self.kind not in SPECTRUM_KINDS:
            raise ValueError(f"kind must be one of {SPECTRUM_KINDS}, got {self.kind!r}")
        gamma = self.gamma
        if isinstance(gamma, bool) or not isinstance(gamma, int | float) or not (
            1.0 <= gamma <= 20.0
        ):
            raise ValueError(f"gamma must be a number in [1, 20], got {gamma!r}")
        steepness = hs / (GRAVITY * tp**2 / (2.0 * math.pi))
        if steepness > MAX_STEEPNESS:
            raise ValueError(
                f"Hs = {hs} m with Tp = {tp} s is steeper than breaking "
                f"(Hs / lambda_p = {steepness:.3f} > 1/7); lengthen tp"
            )

    @classmethod
    def dnv(cls, hs: float, tp: float) -> SeaSpectrum:
        """JONSWAP with DNV-RP-C205 §3.5.5.5's ``gamma``: 5 for ``Tp / sqrt(Hs) <= 3.6``,
        ``exp(5.75 - 1.15 Tp / sqrt(Hs))`` up to 5, then 1 (Pierson–Moskowitz)."""
        ratio = _finite_positive("tp", tp) / math.sqrt(_finite_positive("hs", hs))
        gamma = 5.0 if ratio <= 3.6 else (math.exp(5.75 - 1.15 * ratio) if ratio < 5.0 else 1.0)
        return cls(hs, tp, "jonswap", max(gamma, 1.0))

    @property
    def peak_frequency(self) -> float:
        """``wp = 2 pi / Tp``, rad/s."""
        return 2.0 * math.pi / self.tp

    @property
    def effective_gamma(self) -> float:
        return 1.0 if self.kind == "pierson-moskowitz" else float(self.gamma)

    @property
    def normalisation(self) -> float:
        """``A(gamma)``: the factor that keeps ``m0 = Hs^2 / 16`` (1 for PM)."""
        return _normalisation(self.effective_gamma)

    def density(self, omega, xp) -> np.ndarray:
        """``S(w)``, m^2 s/rad, at angular frequencies ``omega`` (0 where ``w <= 0``;
        ``xp``: NumPy, or ``jax.numpy`` for a JAX array)."""
        w = np.asarray(omega, dtype=float) if xp is np else omega
        x = w / self.peak_frequency
        shape = _pm_shape(x, xp)
        gamma = self.effective_gamma
        if gamma != 1.0:
            shape = self.normalisation * shape * _peak_factor(x, gamma, xp)
        return xp.where(w > 0.0, self.hs**2 / self.peak_frequency * shape, 0.0)

    def moment(self, n: int) -> float:
        """Spectral moment ``m_n = int w^n S(w) dw`` for ``n`` in 0..3 (quadrature)."""
        if n not in (0, 1, 2, 3):
            raise ValueError(f"moment order must be 0..3 (higher ones diverge), got {n}")
        x = np.linspace(0.3, 60.0, 200_001)
        wp = self.peak_frequency
        body = trapezoid(x**n * self.density(x * wp, np) / self.hs**2 * wp, x)
        # Beyond the grid the shape is A x^-5 (the exponential and the peak factor are 1).
        tail = self.normalisation * 0.3125 * 60.0 ** (n - 4) / (4 - n)
        return float(self.hs**2 * wp**n * (body + tail))

    @property
    def zero_crossing_period(self) -> float:
        """Mean zero up-crossing period ``Tz = 2 pi sqrt(m0 / m2)``, s."""
        return 2.0 * math.pi * math.sqrt(self.moment(0) / self.moment(2))


_NORMALISATION_CACHE: dict[float, float] = {}


def _normalisation(gamma: float) -> float:
    """``A(gamma)`` by quadrature of the peak's extra energy (negligible outside
    0.5-2 wp: the Gaussian exponent passes 25 there)."""
    if gamma == 1.0:
        return 1.0
    if gamma not in _NORMALISATION_CACHE:
        x = np.linspace(0.5, 2.0, 6001)
        extra = trapezoid(_pm_shape(x, np) * (_peak_factor(x, gamma, np) - 1.0), x)
        _NORMALISATION_CACHE[gamma] = (1.0 / 16.0) / (1.0 / 16.0 + float(extra))
    return _NORMALISATION_CACHE[gamma]


def sea_state_code(hs: float) -> int:
    """The Douglas / WMO sea state code (0-9) of a significant wave height ``hs`` (m)."""
    if not (math.isfinite(hs) and hs >= 0):
        raise ValueError(f"hs must be a finite number >= 0, got {hs!r}")
    if hs == 0.0:
        return 0
    return next(code for code, (_, _, high) in SEA_STATE_CODES.items() if code and hs <= high)


def fully_developed_peak_period(hs: float) -> float:
    """Peak period (s) of a fully developed Pierson–Moskowitz sea of height ``hs`` (m).

    From the PM wind-sea relations ``Hs = 2 sqrt(alpha / beta) U^2 / g`` and
    ``wp = (4 beta / 5)^(1/4) g / U``: ``Tp ~= 5.0 sqrt(Hs)``, the
    ``Tp / sqrt(Hs) = 5`` at which DNV-RP-C205's ``gamma`` reaches 1.
    """
    hs = _finite_positive("hs", hs)
    wind2 = hs * GRAVITY / (2.0 * math.sqrt(PM_ALPHA / PM_BETA))
    return 2.0 * math.pi * math.sqrt(wind2) / ((0.8 * PM_BETA) ** 0.25 * GRAVITY)


def typical_sea(code: int) -> SeaSpectrum:
    """A documentation example for sea state ``code`` 1-8: ``Hs`` mid-range, fully
    developed ``Tp`` (:func:`fully_developed_peak_period`), PM spectrum."""
    if code not in SEA_STATE_CODES or not 1 <= code <= 8:
        raise ValueError(f"code must be 1..8 (0 has no waves, 9 no upper bound), got {code!r}")
    _, low, high = SEA_STATE_CODES[code]
    hs = 0.5 * (low + high)
    return SeaSpectrum(hs, fully_developed_peak_period(hs), "pierson-moskowitz")


def _read_only(values) -> np.ndarray:
    out = np.array(values, dtype=float)
    out.setflags(write=False)
    return out


@attribute_pytree(("omega", "amplitude", "phase", "heading", "wavenumber"))
@dataclasses.dataclass(frozen=True, eq=False)
class WaveRealisation:
    """One seeded realisation of a long-crested sea (the module's sum of harmonics).

    Attributes:
        omega: (N,) component frequencies, rad/s.
        amplitude: (N,) component amplitudes, m.
        phase: (N,) phases, rad.
        heading: direction the waves travel towards, rad from world +x
            (counter-clockwise seen from above).
    """

    omega: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    heading: float = 0.0

    def __post_init__(self):
        if not isinstance(self.omega, np.ndarray):  # JAX arrays (the batched env): as given
            object.__setattr__(self, "wavenumber", self.omega ** 2 / GRAVITY)
            return
        arrays = [_read_only(getattr(self, n)) for n in ("omega", "amplitude", "phase")]
        if any(a.ndim != 1 or a.shape != arrays[0].shape for a in arrays) or not arrays[0].size:
            raise ValueError("omega, amplitude and phase must be non-empty (N,) arrays")
        if not all(np.all(np.isfinite(a)) for a in arrays) or not math.isfinite(self.heading):
            raise ValueError("a wave realisation must be finite")
        if np.any(arrays[0] <= 0) or np.any(arrays[1] < 0):
            raise ValueError("frequencies must be > 0 and amplitudes >= 0")
        for name, array in zip(("omega", "amplitude", "phase"), arrays, strict=True):
            object.__setattr__(self, name, array)
        object.__setattr__(self, "heading", float(self.heading))
        object.__setattr__(self, "wavenumber", _read_only(arrays[0] ** 2 / GRAVITY))

    @classmethod
    def sample(
        cls,
        spectrum: SeaSpectrum,
        rng: np.random.Generator,
        n_components: int = DEFAULT_COMPONENTS,
        heading: float = 0.0,
        band: tuple[float, float] = DEFAULT_BAND,
        *,
        xp,
    ) -> WaveRealisation:
        """Draw a realisation of ``spectrum`` from ``rng`` (``2 n_components`` uniforms).

        Args:
            spectrum: the target spectrum.
            rng: the episode's generator.
            n_components: number of harmonic components ``N``.
            heading: travel direction, rad.
            band: (low, high) frequency band in units of the peak frequency.
            xp: NumPy, or ``jax.numpy`` (``rng`` a JAX key's draws).
        """
        if isinstance(n_components, bool) or not isinstance(n_components, int) or n_components < 1:
            raise ValueError(f"n_components must be a positive int, got {n_components!r}")
        low, high = band
        if not (math.isfinite(low) and math.isfinite(high) and 0.0 < low < high):
            raise ValueError(f"band must be (low, high) with 0 < low < high, got {band!r}")
        wp = spectrum.peak_frequency
        width = (high - low) * wp / n_components
        u = rng.random((2, n_components))
        omega = low * wp + width * (xp.arange(n_components) + u[0])
        amplitude = xp.sqrt(2.0 * spectrum.density(omega, xp) * width)
        return cls(omega, amplitude, 2.0 * math.pi * u[1], heading)

    @property
    def significant_height(self) -> float:
        """``4 sqrt(m0)`` of this realisation (``m0 = sum a^2 / 2``), m."""
        return 4.0 * math.sqrt(0.5 * float(self.amplitude @ self.amplitude))

    def _argument(self, t, x, y) -> np.ndarray:
        t, x, y = (np.asarray(v, dtype=float)[..., None] for v in (t, x, y))
        along = x * math.cos(self.heading) + y * math.sin(self.heading)
        return self.omega * t - self.wavenumber * along + self.phase

    def elevation(self, t, x=0.0, y=0.0) -> np.ndarray:
        """Surface elevation ``eta`` (m) at times and places broadcast together."""
        return np.cos(self._argument(t, x, y)) @ self.amplitude

    def elevation_rate(self, t, x=0.0, y=0.0) -> np.ndarray:
        """``d eta / dt`` (m/s) at fixed places."""
        return -np.sin(self._argument(t, x, y)) @ (self.amplitude * self.omega)

    def slope(self, t, x=0.0, y=0.0) -> tuple[np.ndarray, np.ndarray]:
        """Surface slope ``(d eta / dx, d eta / dy)`` (dimensionless)."""
        s = np.sin(self._argument(t, x, y)) @ (self.amplitude * self.wavenumber)
        return s * math.cos(self.heading), s * math.sin(self.heading)

    def at(self, t: float, x: float = 0.0, y: float = 0.0) -> tuple[float, float]:
        """``(eta, d eta / dt)`` at one time and place, as Python floats."""
        along = x * math.cos(self.heading) + y * math.sin(self.heading)
        arg = self.omega * t - self.wavenumber * along + self.phase
        a = self.amplitude
        return float(np.cos(arg) @ a), float(-(np.sin(arg) @ (a * self.omega)))

    def along_track(self, x0: float, y0: float, vx: float = 0.0, vy: float = 0.0, *, ops):
        """The elevation seen from a point moving as ``(x0 + vx t, y0 + vy t)`` (``ops``:
        a backend of :mod:`auv_envs.core.ops`).

        Returns:
            ``(omega_e, c)``: encounter frequencies (N,) and complex amplitudes
            (N,) with ``eta = Re sum c exp(i omega_e t)`` along the track.
        """
        cb, sb = ops.cos(self.heading), ops.sin(self.heading)
        k = self.wavenumber
        encounter = self.omega - k * (vx * cb + vy * sb)
        c = self.amplitude * ops.xp.exp(1j * (self.phase - k * (x0 * cb + y0 * sb)))
        return encounter, c


def _floats(x, xp):
    """``x`` as a float array of ``xp`` (NumPy: float64; JAX arrays as they are)."""
    return np.asarray(x, dtype=float) if xp is np else x


def _complex(x, xp):
    """``x`` as a complex array of ``xp`` (NumPy: complex128; JAX: complex64)."""
    return x.astype(complex if xp is np else xp.complex64)


def plane_average(x, xp) -> np.ndarray:
    """Mean of ``exp(-i k s)`` over ``s`` in ``[-l, l]`` at ``x = k l``: ``sin(x) / x``."""
    return xp.sinc(_floats(x, xp) / math.pi)


def slope_average(x, xp) -> np.ndarray:
    """Least-squares slope of ``exp(-i k s)`` over ``[-l, l]``, over the point slope
    ``-i k``, at ``x = k l``: ``3 (sin x - x cos x) / x^3`` (-> 1 - x^2 / 10)."""
    x = xp.abs(_floats(x, xp))
    small = x < 1e-3
    safe = xp.where(small, 1.0, x)
    exact = 3.0 * (xp.sin(safe) - safe * xp.cos(safe)) / safe**3
    return xp.where(small, 1.0 - x * x / 10.0, exact)


def _waterplane(omega, wavenumber, heading, length, beam, ops) -> tuple:
    """``(w, k_along, k_across, mean_along, mean_across)`` of a waterplane ``length`` x
    ``beam`` met by waves travelling ``heading`` from its long axis: the frequencies as
    floats, the wavenumbers along and across it, and the elevation averaged along and
    across it (:func:`plane_average`)."""
    xp = ops.xp
    k_along = wavenumber * ops.cos(heading)
    k_across = wavenumber * ops.sin(heading)
    return (_floats(omega, xp), k_along, k_across,
            plane_average(0.5 * k_along * length, xp), plane_average(0.5 * k_across * beam, xp))


@dataclasses.dataclass(frozen=True)
class FloaterResponse:
    """A small floating body that follows the surface (the surfaced AUV).

    Heave is the surface elevation averaged over the waterplane (RAO -> 1 for
    waves much longer than ``length``); roll and pitch are the waterplane's
    least-squares surface slopes through first-order lags ``1 / (1 + i w T)``
    that stand in for the body's own fast roll/pitch dynamics. Long-wave
    approximation of Faltinsen (1990), ch. 3; the lags are assumed values,
    well below the wave periods that carry energy (> 3 s).

    Attributes:
        length, beam: waterplane, m.
        roll_time_constant, pitch_time_constant: s.
    """

    length: float
    beam: float
    roll_time_constant: float = 0.5
    pitch_time_constant: float = 0.3

    def __post_init__(self):
        for name in ("length", "beam"):
            _finite_positive(name, getattr(self, name))
        for name in ("roll_time_constant", "pitch_time_constant"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")

    def transfer(self, omega, wavenumber, relative_heading, ops) -> tuple[np.ndarray, ...]:
        """Complex ``(heave, roll, pitch)`` responses per unit wave amplitude.

        Args:
            omega: (N,) encounter frequencies, rad/s.
            wavenumber: (N,) rad/m.
            relative_heading: wave travel direction minus the body's heading, rad.
            ops: a backend of :mod:`auv_envs.core.ops`.

        Returns:
            heave (m/m), roll (rad/m, right-handed about the bow axis: port
            side up) and pitch (rad/m, nose up), each (N,), referred to the
            elevation at the body's centre.
        """
        xp = ops.xp
        w, k_along, k_across, mean_along, mean_across = _waterplane(
            omega, wavenumber, relative_heading, self.length, self.beam, ops)
        heave = _complex(mean_along * mean_across, xp)
        pitch = (-1j * k_along * slope_average(0.5 * k_along * self.length, xp) * mean_across
                 / (1.0 + 1j * w * self.pitch_time_constant))
        roll = (-1j * k_across * slope_average(0.5 * k_across * self.beam, xp) * mean_along
                / (1.0 + 1j * w * self.roll_time_constant))
        return heave, roll, pitch


@dataclasses.dataclass(frozen=True)
class ShipResponse:
    """Heave, roll and pitch of a ship on station (no speed, heading world +x).

    Each mode is a linear mass-spring-damper driven by the waterplane-averaged
    elevation (heave) or slope (roll, pitch), so that its RAO is 1 in very
    long waves::

        H_j(w) = 1 / (1 - (w / w_j)^2 + 2 i zeta_j w / w_j),   w_j = 2 pi / T_j

    Defaults: a ~32 m workboat with the 8 m beam of the scene's hull; natural
    periods and damping ratios are representative assumed values (heave and
    pitch of ships are strongly damped by wave radiation, roll lightly;
    Faltinsen 1990, chs. 3-4), not a particular vessel's.

    Attributes:
        length, beam: waterplane, m.
        heave_period, roll_period, pitch_period: natural periods, s.
        heave_damping, roll_damping, pitch_damping: damping ratios.
    """

    length: float = 32.0
    beam: float = 8.0
    heave_period: float = 4.0
    roll_period: float = 8.0
    pitch_period: float = 3.8
    heave_damping: float = 0.35
    roll_damping: float = 0.08
    pitch_damping: float = 0.35

    def __post_init__(self):
        for field in dataclasses.fields(self):
            _finite_positive(field.name, getattr(self, field.name))

    @staticmethod
    def _mode(w: np.ndarray, period: float, damping: float) -> np.ndarray:
        r = w * period / (2.0 * math.pi)
        return 1.0 / (1.0 - r * r + 2j * damping * r)

    def transfer(self, omega, wavenumber, heading, ops) -> tuple[np.ndarray, ...]:
        """Complex ``(heave, roll, pitch)`` responses per unit wave amplitude.

        Args:
            omega: (N,) frequencies, rad/s.
            wavenumber: (N,) rad/m.
            heading: wave travel direction relative to the bow, rad.
            ops: a backend of :mod:`auv_envs.core.ops`.

        Returns:
            heave (m/m), roll (rad/m, right-handed about the bow axis: the
            port (+y) side up) and pitch (rad/m, right-handed about +y: bow
            down), each (N,), referred to the elevation at the ship's centre
            of rotation.
        """
        xp = ops.xp
        w, kx, ky, mean_x, mean_y = _waterplane(omega, wavenumber, heading, self.length,
                                                self.beam, ops)
        heave = mean_x * mean_y * self._mode(w, self.heave_period, self.heave_damping)
        roll = (-1j * ky * slope_average(0.5 * ky * self.beam, xp) * mean_x
                * self._mode(w, self.roll_period, self.roll_damping))
        pitch = (1j * kx * slope_average(0.5 * kx * self.length, xp) * mean_y
                 * self._mode(w, self.pitch_period, self.pitch_damping))
        return heave, roll, pitch


@attribute_pytree(("omega", "_matrix"), ("n_channels", "_xp", "_buffer"))
class HarmonicSeries:
    """Channels ``y_j(t) = Re sum_i C_ji exp(i w_i t)`` and their rates, at one ``t``.

    The per-step evaluator of linear responses to a wave realisation: one
    ``cos``/``sin`` of the ``N`` frequencies and one matrix product give every
    channel and its time derivative, as Python floats with NumPy, or as a JAX
    array (``xp=jax.numpy``: the batched environment, where the series is a pytree).
    """

    def __init__(self, blocks, xp):
        """Args:
            blocks: ``(omega, coefficients)`` pairs, ``omega`` (N_b,) and
                ``coefficients`` (M_b, N_b) complex; channels are listed block
                after block, each block with its own frequencies.
            xp: NumPy, or ``jax.numpy``.
        """
        omegas, values, rates = [], [], []
        total = sum(int(np.size(w)) for w, _ in blocks)
        start = 0
        for omega, coefficients in blocks:
            w = np.asarray(omega, dtype=float) if xp is np else omega
            c = (np.atleast_2d(np.asarray(coefficients, dtype=complex)) if xp is np
                 else xp.stack(list(coefficients)))
            n = w.size
            if w.ndim != 1 or c.ndim != 2 or c.shape[1] != n:
                raise ValueError(f"coefficients must be (M, {n}) for {n} frequencies, "
                                 f"got shape {c.shape}")
            # Re(C e^{iwt}) = Cr cos - Ci sin; its rate Re(i w C e^{iwt}) = -w Ci cos - w Cr sin.
            # Each row spans the 2 total columns: cos of every frequency, then sin.
            before = xp.zeros((c.shape[0], start))
            after = xp.zeros((c.shape[0], total - start - n))
            values.append(xp.concatenate([before, c.real, after, before, -c.imag, after], 1))
            rates.append(xp.concatenate([before, -w * c.imag, after, before, -w * c.real,
                                         after], 1))
            omegas.append(w)
            start += n
        self.omega = xp.concatenate(omegas)
        self._xp = xp
        self._matrix = xp.concatenate(values + rates)
        self.n_channels = self._matrix.shape[0] // 2
        self._buffer = np.empty(2 * total) if xp is np else None

    def __call__(self, t: float) -> list[float]:
        """Values of all channels, then their rates (``2 n_channels`` floats, or a JAX
        array)."""
        arg = self.omega * t
        if self._xp is not np:
            return self._matrix @ self._xp.concatenate([self._xp.cos(arg), self._xp.sin(arg)])
        n = self.omega.size
        np.cos(arg, out=self._buffer[:n])
        np.sin(arg, out=self._buffer[n:])
        return (self._matrix @ self._buffer).tolist()

    def __getstate__(self):
        return {"omega": self.omega, "n_channels": self.n_channels, "matrix": self._matrix}

    def __setstate__(self, state):
        self.omega, self.n_channels, self._matrix = (
            state["omega"], state["n_channels"], state["matrix"])
        self._xp = np
        self._buffer = np.empty(self._matrix.shape[1])
