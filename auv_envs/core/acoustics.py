"""Passive acoustic measurements of a broadband source by a hydrophone array [GMPHD].

The source (an end effector) emits a broadband signal that every node of an
array of ``N`` hydrophones receives. The signal is split into ``Q`` frequency
sub-bands; per band and sample period (``1 / fs``) the array reports a *set*
of detections. A detection is the vector

* ``tdoa`` (N-1,): time differences of arrival against node 1,
  ``tau_1i = t_i - t_1`` ([GMPHD] §1.1: ``c * tau_1i = D_i - D_1``), seconds;
* ``azimuth`` (N,): ``alpha_i = atan2(y - y_i, x - x_i)`` in (-pi, pi];
* ``elevation`` (N,): [GMPHD] §1.2's angle ``theta_i`` with
  ``tan(theta_i) = hypot(x - x_i, y - y_i) / (z - z_i)``, i.e. the angle
  between the upward vertical through node ``i`` and the line to the source,
  in [0, pi].

The measurement model (all in :class:`AcousticConfig`; the symbols below are
its fields):

* **Transmission loss** (spherical spreading plus absorption; Urick,
  *Principles of Underwater Sound*, ch. 5):
  ``TL = 20 log10(max(R, 1 m)) + a(f) R / 1000`` dB, with Thorp's absorption
  ``a(f)`` in dB/km (f in kHz)
  ``0.11 f^2/(1 + f^2) + 44 f^2/(4100 + f^2) + 2.75e-4 f^2 + 0.003``.
  Absorption grows with frequency, so high bands fade faster with range.
* **Ambient noise** spectrum level (dB re 1 uPa^2/Hz): wind/shipping noise
  ``50 - 18 log10 f`` (Coates' approximation to the Wenz curves) plus
  thermal noise ``-15 + 20 log10 f``, summed in power; the band noise level
  adds ``10 log10(B)``.
* **SNR** per band and node: ``SL - TL - NL_band + PG`` with the processing
  gain of correlating over one sample period ``PG = 10 log10(B / fs)``.
* **Arrival-time noise** per node (the Cramer-Rao bound of a delay estimate
  for a flat band of width ``B``, rms bandwidth ``beta = B / sqrt(12)``, plus
  a hardware floor): ``sigma_t = noise_scale * hypot(timing_floor,
  1 / (2 pi beta sqrt(2 snr)))``, ``snr`` linear. TDOA noise is the difference
  of two arrival-time noises: ``std(tau_1i) = hypot(sigma_t_i, sigma_t_1)``
  and the TDOAs of one detection are correlated through node 1.
* **Angle noise** per node (a two-element interferometer of aperture ``d``
  at wavelength ``lambda = c / f``): ``sigma_theta = noise_scale *
  hypot(angle_floor, lambda / (2 pi d sqrt(2 snr)))``; the azimuth's is
  ``sigma_theta / max(sin(theta), 0.05)`` (azimuth is ill defined
  straight above or below a node). Noisy azimuths are wrapped to (-pi, pi]
  and elevations clipped to [0, pi].
* **Flow noise** (off unless ``flow_noise_level`` is set; our addition to
  [GMPHD], whose tank currents come from three current generators): the
  generators' radiated noise fills the tank as a uniform reverberant field
  whose spectrum level follows Ross's classical source-spectrum model
  (Ross, *Mechanics of Underwater Noise*, 1976; as summarised by Wales &
  Heitmeyer, JASA 111(3), 2002): a baseline spectrum falling 20 dB per decade
  of frequency, scaled by ``60 log10`` of the flow speed,
  ``NL_flow = flow_noise_level + 60 log10(U / 1 m/s) - 20 log10(f / 1 kHz)``.
  It adds to the ambient noise in power, so a stronger current lowers every
  SNR, most in the low bands. The flow speed ``U`` is the current's speed in
  the sample period (:meth:`HydrophoneArray.measure`'s ``current_speed``).
* **Sound-speed error**: the water's true sound speed differs from the
  nominal ``sound_speed`` a tracker is given (``calibration.sound_speed``) by
  a per-episode offset drawn from N(0, ``sound_speed_error_std``^2) m/s; the
  arrival times use the true speed. By Mackenzie's equation (J. Acoust. Soc.
  Am. 70(3), 1981) dc/dT is about 3.2 m/s per degC at 15 degC and dc/dS about
  1.3 m/s per psu, so an uncertainty of 1 degC in a tank's temperature gives
  about 3 m/s (the draw is clipped at ``SOUND_SPEED_ERROR_LIMIT``). Every
  TDOA is then scaled by ``c / c_true``: a bias that grows with the range
  difference and that no averaging over bands removes.
* **Propagation delay** (off unless ``propagation_delay``): sound takes
  ``R / c`` to reach a node (0.03-0.28 s across [GMPHD]'s tank), so a
  measurement made at time ``t`` describes where a moving source was when it
  emitted. A node's angles see the source at its own emission time
  ``t - R_i / c``; the TDOAs, which align the same emitted stretch of signal at
  node 1 and node ``i``, see the source where it was at node 1's emission time
  ``t - R_1 / c`` (:meth:`HydrophoneArray.emission_positions`). Multipath
  ghosts use the direct path's emission times. A source moving at 1 m/s
  150 m from node 1 is measured 0.1 m behind where it is.
* **Travel-time wander** (off unless ``fluctuation_intensity`` > 0): the
  water's sound speed fluctuates about its mean (thermal microstructure,
  the current generators' turbulence), so each path's travel time wanders.
  In geometric acoustics the travel-time variance over a range ``R`` is
  ``<mu^2> L_p R / c^2`` (Flatte et al., *Sound Transmission through a
  Fluctuating Ocean*, 1979, ch. 7; Munk & Zachariasen 1976), with ``mu``
  the fractional sound-speed fluctuation (``fluctuation_intensity``, its
  rms) and ``L_p`` its correlation length (``fluctuation_length``, m). Each
  node's wander is a unit first-order Gauss-Markov process with time
  constant ``fluctuation_time`` (s; the eddies advect through the path),
  scaled by that standard deviation at the node's range; it adds to the
  arrival time of every path and band (one medium), so band fusion cannot
  average it out, and a tracker's filter only over times longer than
  ``fluctuation_time``.
* **Band fading** (off unless ``fading_std`` > 0): the same fluctuating
  medium, and the surface and bottom paths interfering with the direct
  one, make each band's received level scintillate: in the saturated
  regime the intensity is Rayleigh distributed, about 5.6 dB rms in dB
  (Flatte et al. 1979, ch. 8), and bands further apart than the channel's
  coherence bandwidth (the inverse of its delay spread; tens of Hz to a few
  kHz here, against our 10 kHz band spacing) fade independently. Each band
  and node's SNR gets a log-normal fade, ``fading_std`` dB rms, a
  Gauss-Markov process with time constant ``fading_time`` (s): a faded band
  misses and gets noisier while the others do not, which is what fusing the
  bands averages out.
* **Node dropouts** (off unless ``node_dropout_rate`` > 0): a node can stop
  delivering data for a while (its cable or telemetry link drops out, its
  receiver saturates or resets). Each node is a two-state Markov chain, the
  Gilbert-Elliott channel (Gilbert, Bell Syst. Tech. J. 39(5), 1960; Elliott,
  Bell Syst. Tech. J. 42(5), 1963), in continuous time: a working node drops
  out at ``node_dropout_rate`` per second and an outage ends at rate
  ``1 / node_dropout_duration``, so outages last ``node_dropout_duration``
  seconds on average and a node is out ``rate duration / (1 + rate
  duration)`` of the time. The chain is sampled exactly at the sample
  period (:meth:`HydrophoneArray.draw_node_states`), nodes independently,
  starting from its stationary distribution. While a node is out it measures
  nothing: its azimuths and elevations and every TDOA that involves it are
  missing, in every band and detection, false alarms included; the TDOAs are
  referenced to node 1, so while node 1 is out there is no TDOA at all and
  only the working nodes' angles remain. Missing entries are zero, like the
  padding, and only the node states say which they are (the environment
  reports them as ``node_mask``). The array's detection probability is then
  that of the working nodes (their mean SNR); with no node working there is
  no detection. The rates are our choice: no source reports outage
  statistics of a tank array.
* **Clock offsets**: each node's clock is offset from node 1's by a constant
  per episode (``clock_offset_std``, node 1 is the reference), biasing every
  TDOA of that node.
* **Detection probability** per band and path: a logistic function of the
  *array SNR* (the mean over nodes of the per-node SNR in dB),
  ``p_D = 1 / (1 + exp(-(SNR_array - snr50) / snr_slope))``.
* **Multipath ghosts** (image method): the surface reflection is a source at
  the mirror image above the surface ``(x, y, 2 z_s - z)`` and the bottom
  reflection one below the bottom ``(x, y, 2 z_b - z)``; their paths are
  longer and lose ``surface_loss`` / ``bottom_loss`` dB at the boundary, so
  they are weaker and noisier. A ghost detection is the full measurement of
  its image source.
* **False alarms**: Poisson(``clutter_rate``) per band and period, each a
  vector uniform over the measurement space (TDOAs within the physically
  possible range ``|h_i - h_1| / c``, azimuth over (-pi, pi], elevation over
  [0, pi]).

Each band's detections are shuffled and at most ``max_detections`` kept (the
excess, if any, is dropped at random and counted). Everything is vectorised
over periods, bands, paths and nodes, and drawn from the episode's generator,
so seeded runs are bit-identical.

Each formula is written once and takes the array namespace ``xp``: NumPy (the CPU
environments) or ``jax.numpy``, whose arrays pass through ``jit``
and ``vmap`` (the batched environment, its draws from a JAX key). There the
detection sets are drawn at fixed shapes (:meth:`HydrophoneArray.measure`'s
``noise_draws="fixed"``): the same model, other draws.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from auv_envs.core.pytree import dataclass_pytree

#: Codes of ``Measurements.origin``: where each detection came from.
ORIGIN_EMPTY, ORIGIN_TARGET, ORIGIN_SURFACE, ORIGIN_BOTTOM, ORIGIN_CLUTTER = -1, 0, 1, 2, 3


def thorp_absorption(frequency_hz) -> np.ndarray:
    """Thorp's seawater absorption coefficient in dB/km (frequency in Hz)."""
    f2 = (np.asarray(frequency_hz, dtype=np.float64) / 1000.0) ** 2
    return 0.11 * f2 / (1.0 + f2) + 44.0 * f2 / (4100.0 + f2) + 2.75e-4 * f2 + 0.003


#: The sound-speed error is clipped to this fraction of the nominal speed (5 %, 75 m/s at
#: 1500 m/s: far beyond any water's temperature and salinity uncertainty), which keeps the
#: TDOAs within the observation space's bounds (10 % beyond the array's baselines).
SOUND_SPEED_ERROR_LIMIT = 0.05
#: Reference flow speed (m/s) and frequency (Hz) of ``AcousticConfig.flow_noise_level``.
FLOW_NOISE_REF_SPEED = 1.0
FLOW_NOISE_REF_FREQUENCY = 1000.0
#: The flow-noise level the [GMPHD] reproduction uses (dB re 1 uPa^2/Hz at
#: 1 m/s and 1 kHz). Our choice, as ``source_level`` is: at 0.5 m/s, the top of
#: [GMPHD]'s high current range, it raises the noise of the 20 kHz band by
#: 23 dB and of the 110 kHz band by 10 dB; at 0.15 m/s, the top of the low
#: range, by 0.6 and 0.0 dB (:meth:`HydrophoneArray.flow_noise_rise`).
GMPHD_FLOW_NOISE_LEVEL = 94.0


def flow_noise_level(frequency_hz, speed, level: float) -> np.ndarray:
    """Flow-noise spectrum level, dB re 1 uPa^2/Hz (module docstring; -inf at rest).

    Broadcasts ``frequency_hz`` (Hz) against ``speed`` (m/s, >= 0).
    """
    f = np.asarray(frequency_hz, dtype=np.float64) / FLOW_NOISE_REF_FREQUENCY
    u = np.asarray(speed, dtype=np.float64) / FLOW_NOISE_REF_SPEED
    with np.errstate(divide="ignore"):
        return level + 60.0 * np.log10(u) - 20.0 * np.log10(f)


def ambient_noise_level(frequency_hz) -> np.ndarray:
    """Ambient noise spectrum level, dB re 1 uPa^2/Hz: wind/shipping plus thermal."""
    log_f = np.log10(np.asarray(frequency_hz, dtype=np.float64) / 1000.0)
    wind = 50.0 - 18.0 * log_f
    thermal = -15.0 + 20.0 * log_f
    return 10.0 * np.log10(10.0 ** (wind / 10.0) + 10.0 ** (thermal / 10.0))


@dataclasses.dataclass(frozen=True)
class AcousticConfig:
    """Parameters of the measurement model (see the module docstring).

    Defaults: ten 8-kHz bands centred at 20, 30, ..., 110 kHz, fs = 100 Hz and
    Q = 10 as in [GMPHD]'s experiments; c = 1500 m/s. The source level,
    aperture, floors, clock offsets and clutter rate are our choices, set so
    that detections fade and get noisier with range in the high bands.
    ``flow_noise_level`` (dB re 1 uPa^2/Hz at 1 m/s and 1 kHz) switches the
    current generators' flow noise on; None (the default) leaves it out, and
    ``GMPHD_FLOW_NOISE_LEVEL`` is the level [GMPHD]'s reproduction uses.
    ``node_dropout_rate`` (1/s, a working node's rate of dropping out; 0, the
    default, switches dropouts off) and ``node_dropout_duration`` (s, the mean
    outage) set the nodes' Gilbert-Elliott outages (module docstring).
    """

    sound_speed: float = 1500.0
    sample_rate: float = 100.0
    band_centres: tuple[float, ...] = tuple(20_000.0 + 10_000.0 * q for q in range(10))
    bandwidth: float = 8_000.0
    source_level: float = 120.0
    surface_loss: float = 4.0
    bottom_loss: float = 10.0
    aperture: float = 0.1
    timing_floor: float = 2e-6
    angle_floor: float = math.radians(0.05)
    noise_scale: float = 1.0
    clock_offset_std: float = 20e-6
    sound_speed_error_std: float = 0.0
    propagation_delay: bool = False
    fluctuation_intensity: float = 0.0
    fluctuation_length: float = 10.0
    fluctuation_time: float = 2.0
    fading_std: float = 0.0
    fading_time: float = 0.5
    node_dropout_rate: float = 0.0
    node_dropout_duration: float = 5.0
    snr50: float = 10.0
    snr_slope: float = 2.0
    clutter_rate: float = 1.0
    flow_noise_level: float | None = None
    multipath: bool = True
    ideal_detection: bool = False
    max_detections: int = 8

    def __post_init__(self):
        positive = ("sound_speed", "sample_rate", "bandwidth", "aperture", "snr_slope",
                    "fluctuation_length", "fluctuation_time", "fading_time",
                    "node_dropout_duration")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"AcousticConfig.{name} must be positive, got {value}")
        non_negative = ("surface_loss", "bottom_loss", "timing_floor", "angle_floor",
                        "noise_scale", "clock_offset_std", "clutter_rate",
                        "sound_speed_error_std", "fluctuation_intensity", "fading_std",
                        "node_dropout_rate")
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"AcousticConfig.{name} must be >= 0, got {value}")
        level = self.flow_noise_level
        if level is not None and (isinstance(level, bool) or not isinstance(level, (int, float))
                                  or not math.isfinite(level)):
            raise ValueError(f"AcousticConfig.flow_noise_level must be None or a finite "
                             f"level in dB, got {level!r}")
        if not self.band_centres or any(not f > 0 for f in self.band_centres):
            raise ValueError("AcousticConfig.band_centres must be positive frequencies")
        if self.max_detections < 1:
            raise ValueError("AcousticConfig.max_detections must be at least 1")

    @property
    def n_bands(self) -> int:
        return len(self.band_centres)

    def noise_free(self) -> AcousticConfig:
        """The same geometry with no noise, clock offsets, misses, dropouts or clutter
        (ghosts stay)."""
        return dataclasses.replace(self, noise_scale=0.0, clock_offset_std=0.0,
                                   clutter_rate=0.0, ideal_detection=True,
                                   sound_speed_error_std=0.0, fluctuation_intensity=0.0,
                                   fading_std=0.0, node_dropout_rate=0.0)


@dataclass_pytree()
@dataclasses.dataclass(frozen=True)
class Measurements:
    """One sample period's detections, padded to ``max_detections`` per band.

    Arrays are (Q, K, ...) with ``mask`` (Q, K) marking real detections;
    padded entries are zero. ``values`` (Q, K, 3N - 1) holds each detection's
    N - 1 TDOAs (s), N azimuths and N elevations (rad), of which ``tdoa``,
    ``azimuth`` and ``elevation`` are views. ``origin`` (ground truth, for
    metrics and tests only) holds the ``ORIGIN_*`` code of each entry;
    ``dropped`` (Q,) counts detections that did not fit. Every array may have
    leading axes (periods) before these.
    """

    values: np.ndarray
    mask: np.ndarray
    origin: np.ndarray
    dropped: np.ndarray

    @property
    def n_nodes(self) -> int:
        return (self.values.shape[-1] + 1) // 3

    @property
    def tdoa(self) -> np.ndarray:
        return self.values[..., : self.n_nodes - 1]

    @property
    def azimuth(self) -> np.ndarray:
        n = self.n_nodes
        return self.values[..., n - 1 : 2 * n - 1]

    @property
    def elevation(self) -> np.ndarray:
        return self.values[..., 2 * self.n_nodes - 1 :]


def unit_gauss_markov(rng, count: int, shape: tuple[int, ...], rate: float,
                      previous=None, *, xp):
    """``count`` steps (count, *shape) of independent first-order Gauss-Markov processes
    with unit variance and ``exp(-rate)`` correlation between steps, continuing
    ``previous`` (None: the first step drawn from the stationary distribution).
    ``rng`` draws as NumPy's ``Generator`` (a JAX key's draws with ``xp`` ``jax.numpy``);
    ``count`` is static."""
    a = math.exp(-rate)
    innovation = math.sqrt(1.0 - a * a)
    shocks = rng.standard_normal((count, *shape))
    state = shocks[0] if previous is None else a * previous + innovation * shocks[0]
    steps = [state]
    for shock in shocks[1:]:
        state = a * state + innovation * shock
        steps.append(state)
    return xp.stack(steps)


def two_state_markov(rng, count: int, shape: tuple[int, ...], p_fail: float,
                     p_repair: float, previous=None, *, xp):
    """``count`` steps (count, *shape) of independent two-state Markov chains, True in the
    good state: per step a good chain turns bad with probability ``p_fail`` and a bad one
    good with ``p_repair``. Continues ``previous`` (None: the first step drawn from the
    stationary distribution, bad with probability ``p_fail / (p_fail + p_repair)``).
    ``rng`` and ``xp`` as :func:`unit_gauss_markov`'s."""
    u = rng.random((count, *shape))
    if previous is None:
        state = u[0] >= p_fail / (p_fail + p_repair)
    else:
        state = xp.where(previous, u[0] >= p_fail, u[0] < p_repair)
    steps = [state]
    for draw in u[1:]:
        state = xp.where(state, draw >= p_fail, draw < p_repair)
        steps.append(state)
    return xp.stack(steps)


#: The two orders of :meth:`HydrophoneArray.measure`'s draws on NumPy (the CPU
#: environment's choices); ``FIXED_DRAWS`` is the third, of fixed shapes, that every
#: backend runs.
NOISE_DRAWS = ("kept", "all")
FIXED_DRAWS = "fixed"
#: ``10 ** (x / -20) = exp(x * _MINUS_LN10_OVER_20)`` (NumPy's ``exp`` is several times
#: faster than its ``power``).
_MINUS_LN10_OVER_20 = -math.log(10.0) / 20.0


def _snr_db(ranges, offset, absorption, loss, xp):
    """The SNR (dB) at ``ranges`` (m): the band's ``offset`` less spherical spreading, the
    ``absorption`` (dB/m) and the path's boundary ``loss`` (dB)."""
    spreading = 20.0 * xp.log10(xp.maximum(ranges, 1.0))
    return offset - spreading - absorption * ranges - loss


def _lift(elevation, xp):
    """What the azimuth's deviation divides by at an elevation: ``max(sin(el), 0.05)``."""
    return xp.maximum(xp.sin(elevation), 0.05)


def _wrap(angle, xp):
    """``angle`` wrapped into (-pi, pi]. On NumPy ``np.mod`` runs only where ``pi - angle``
    is outside [0, 2 pi) (it returns the rest unchanged, so the result is the same, several
    times faster)."""
    shifted = xp.subtract(xp.pi, angle)
    if xp is not np:
        return xp.pi - xp.mod(shifted, 2.0 * xp.pi)
    outside = (shifted < 0.0) | (shifted >= 2.0 * np.pi)
    shifted[outside] = np.mod(shifted[outside], 2.0 * np.pi)
    return np.subtract(np.pi, shifted, out=shifted)


def _all_finite(x, xp) -> bool:
    """Whether every entry of ``x`` is finite; True off NumPy (traced values go unchecked)."""
    return xp is not np or bool(np.all(np.isfinite(x)))


class _Paths(NamedTuple):
    """What :meth:`HydrophoneArray.measure` draws a period's detections from, per period,
    band, path and node: detection probabilities (B, Q, P), SNRs (B, Q, P, N) dB, and the
    true arrival times (s), azimuths and elevations (B, P, N)."""

    pd: object
    snr: object
    delays: object
    azimuth: object
    elevation: object


class HydrophoneArray:
    """The array, the water column and the measurement model; read-only.

    Args:
      positions: (N, 3) node positions in the tank frame (z up, surface at
        ``surface_z``); node 1 (index 0) is the TDOA reference.
      surface_z, bottom_z: heights of the reflecting boundaries.
      config: the :class:`AcousticConfig`.
    """

    def __init__(self, positions, surface_z: float, bottom_z: float, config: AcousticConfig):
        h = np.array(positions, dtype=np.float64)
        if h.ndim != 2 or h.shape[1] != 3 or len(h) < 4 or not np.all(np.isfinite(h)):
            raise ValueError(f"need (N >= 4, 3) finite node positions, got shape {h.shape}")
        if not bottom_z < surface_z:
            raise ValueError("bottom_z must lie below surface_z")
        h.setflags(write=False)
        self.positions = h
        self.surface_z = float(surface_z)
        self.bottom_z = float(bottom_z)
        self.config = config
        c = config
        f = np.array(c.band_centres)
        self.band_centres = f
        self.band_centres.setflags(write=False)
        self._absorption = (thorp_absorption(f) / 1000.0)[:, None, None]  # dB/m
        processing_gain = 10.0 * math.log10(c.bandwidth / c.sample_rate)
        band_noise = ambient_noise_level(f) + 10.0 * math.log10(c.bandwidth)
        self._snr_offset = (c.source_level - band_noise + processing_gain)[:, None, None]
        # With flow noise the noise power per band is ambient + flow * U^6: the
        # SNR offset becomes _snr_offset - 10 log10(1 + _flow_ratio * U^6).
        self._flow_ratio = None
        if c.flow_noise_level is not None:
            flow = flow_noise_level(f, FLOW_NOISE_REF_SPEED, c.flow_noise_level)
            self._flow_ratio = 10.0 ** ((flow - ambient_noise_level(f)) / 10.0)
        self._path_loss = np.array([0.0, c.surface_loss, c.bottom_loss])[:, None]
        # Noise-std constants with noise_scale and the sqrt(2 snr) factor folded in.
        s2 = c.noise_scale / math.sqrt(2.0)
        self._timing_floor2 = (c.noise_scale * c.timing_floor) ** 2  # squared: noise_std
        self._timing_k = s2 / (2.0 * math.pi * (c.bandwidth / math.sqrt(12.0)))
        self._angle_floor2 = (c.noise_scale * c.angle_floor) ** 2
        self._angle_k = (s2 * (c.sound_speed / f) / (2.0 * math.pi * c.aperture))[:, None, None]
        baselines = np.linalg.norm(h[1:] - h[0], axis=1) / c.sound_speed
        self.max_tdoa = baselines
        self.max_tdoa.setflags(write=False)
        self._n_paths = 3 if c.multipath else 1
        k = c.max_detections
        self._clutter_slot = np.arange(k)
        # The fixed-shape draw's candidates are the paths and then K false-alarm slots;
        # slot j holds a false alarm when a uniform exceeds P(count <= j), the Poisson
        # count's distribution function (by inverse transform: min(count, K) of them).
        self._candidate_origin = np.concatenate(
            [np.arange(self._n_paths), np.full(k, ORIGIN_CLUTTER)]).astype(np.int8)
        rate = c.clutter_rate
        self._clutter_cdf = np.cumsum(
            [math.exp(-rate) * rate**j / math.factorial(j) for j in range(k)])
        # Image sources as scale * p + shift: direct, surface mirror, bottom mirror.
        self._mirror_scale = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, -1.0], [1.0, 1.0, -1.0]])
        self._mirror_shift = np.array(
            [[0.0, 0.0, 0.0], [0.0, 0.0, 2.0 * surface_z], [0.0, 0.0, 2.0 * bottom_z]]
        )
        # Clutter: uniform over TDOA +-max, azimuth (-pi, pi], elevation [0, pi].
        n = len(h)
        self._clutter_scale = np.concatenate(
            [2.0 * baselines, np.full(n, -2.0 * np.pi), np.full(n, np.pi)]
        )
        self._clutter_shift = np.concatenate([-baselines, np.full(n, np.pi), np.zeros(n)])

    @property
    def n_nodes(self) -> int:
        return len(self.positions)

    @property
    def path_loss(self) -> np.ndarray:
        """The boundary losses (dB) of the direct, surface and bottom paths, (P, 1)."""
        return self._path_loss

    # ------------------------------------------------------------ geometry
    # Every method that computes takes the array namespace ``xp``: NumPy or ``jax.numpy``,
    # whose arrays then pass through (under ``jit`` and ``vmap`` too).
    def image_sources(self, position, xp):
        """The source and its surface and bottom mirror images: (..., 3, 3) for (..., 3)."""
        return xp.asarray(position, dtype=float) * self._mirror_scale + self._mirror_shift

    def _offsets(self, sources, xp):
        """The offsets (..., N, 3) of sources (..., 3) from the nodes, their horizontal
        lengths and their ranges (each (..., N))."""
        d = xp.asarray(sources, dtype=float)[..., None, :] - self.positions
        horizontal = xp.hypot(d[..., 0], d[..., 1])
        return d, horizontal, xp.hypot(horizontal, d[..., 2])

    def ranges(self, sources, xp):
        """The ranges (..., N) of sources (..., 3) from the nodes (:meth:`geometry`'s first)."""
        return self._offsets(sources, xp)[2]

    def geometry(self, sources, xp):
        """Ranges, azimuths and elevations (each (..., N)) of sources (..., 3)."""
        d, horizontal, ranges = self._offsets(sources, xp)
        return ranges, xp.arctan2(d[..., 1], d[..., 0]), xp.arctan2(horizontal, d[..., 2])

    def noise_free(self, sources, xp):
        """Exact (tdoa (..., N-1), azimuth (..., N), elevation (..., N)) of sources (..., 3)."""
        ranges, azimuth, elevation = self.geometry(sources, xp)
        tdoa = (ranges[..., 1:] - ranges[..., :1]) / self.config.sound_speed
        return tdoa, azimuth, elevation

    # ------------------------------------------------------------ noise model
    def flow_noise_rise(self, current_speed, xp):
        """How much the flow noise raises each band's noise, dB: (..., Q) for speeds (...).

        Zero everywhere when the config has no ``flow_noise_level``.
        """
        u = xp.asarray(current_speed, dtype=float)
        if not _all_finite(u, xp) or (xp is np and np.any(u < 0)):
            raise ValueError(f"current_speed must be finite and >= 0, got {current_speed!r}")
        if self._flow_ratio is None:
            return xp.zeros(u.shape + self.band_centres.shape, dtype=u.dtype)
        u = u[..., None] / FLOW_NOISE_REF_SPEED
        return 10.0 * xp.log10(1.0 + self._flow_ratio * u**6)

    def snr_db(self, ranges, path_loss, noise_rise=None, *, xp):
        """Per-band SNR (Q, P, N) in dB for path ranges (P, N) with boundary losses (P, 1).

        ``noise_rise`` (Q,) dB, e.g. :meth:`flow_noise_rise`, lowers every SNR
        of its band (broadcast against (..., Q) leading axes as (..., Q, 1, 1)).
        """
        snr = _snr_db(ranges, self._snr_offset, self._absorption, path_loss, xp)
        if noise_rise is not None:
            snr = snr - xp.asarray(noise_rise)[..., None, None]
        return snr

    def noise_std(self, snr_db, elevation, xp):
        """Arrival-time, azimuth and elevation standard deviations for an SNR array
        (Q, ...) per band."""
        timing, theta = self._timing_and_angle_std(snr_db, self._angle_k, xp)
        return timing, theta / xp.maximum(xp.sin(elevation), 0.05), theta

    def timing_std(self, snr_db, xp):
        """The arrival-time standard deviations (s) alone, for an SNR array (Q, ...)."""
        return self._timing_std(xp.exp(snr_db * _MINUS_LN10_OVER_20), xp)

    def _timing_std(self, inv_root, xp):
        """Arrival-time deviations for ``inv_root``, 1 / sqrt(snr) with the SNR linear."""
        timing = self._timing_k * inv_root
        return xp.sqrt(self._timing_floor2 + timing * timing)

    def _timing_and_angle_std(self, snr_db, angle_k, xp):
        """:meth:`noise_std`'s arrival-time and elevation deviations, with the band's
        angle constant ``angle_k`` broadcast against ``snr_db``."""
        inv_root = xp.exp(snr_db * _MINUS_LN10_OVER_20)  # 1 / sqrt(snr), snr linear
        theta = angle_k * inv_root
        return self._timing_std(inv_root, xp), xp.sqrt(self._angle_floor2 + theta * theta)

    def detection_probability(self, snr_db, working=None, *, xp):
        """Per band and path: logistic in the array SNR (mean over nodes, dB).

        ``working`` (bool, broadcast against ``snr_db``'s (..., N)) restricts the mean to
        the working nodes (node dropouts); with none working the probability is 0.
        """
        c = self.config
        if working is None:
            if c.ideal_detection:
                return xp.ones(snr_db.shape[:-1], dtype=snr_db.dtype)
            return self._logistic(snr_db.mean(axis=-1), xp)
        count = xp.sum(xp.broadcast_to(working, snr_db.shape), axis=-1)
        if c.ideal_detection:
            return (count > 0).astype(snr_db.dtype)
        array_snr = xp.sum(xp.where(working, snr_db, 0.0), axis=-1) / xp.maximum(count, 1)
        return xp.where(count > 0, self._logistic(array_snr, xp), 0.0)

    def _logistic(self, array_snr, xp):
        """The detection probability at an array SNR (dB)."""
        c = self.config
        return 1.0 / (1.0 + xp.exp(-(array_snr - c.snr50) / c.snr_slope))

    # ------------------------------------------------------------ one path, in scalars
    # The noise model above in the scalar arithmetic of an ``ops`` namespace
    # (:mod:`auv_envs.core.ops`: Python floats, JAX arrays elementwise, CasADi symbols),
    # for a fix compiled into one call (:meth:`auv_envs.tasks.docking.navigation.USBL.solve`).
    def path_snr_db(self, range_, path: int, ops, band: int = 0):
        """:meth:`snr_db` of one node's ``range_`` (m) on ``path`` (0 direct, 1 surface,
        2 bottom) in ``band``."""
        return _snr_db(range_, float(self._snr_offset[band, 0, 0]),
                       float(self._absorption[band, 0, 0]), float(self._path_loss[path, 0]),
                       ops)

    def path_detection(self, mean_snr_db, ops):
        """:meth:`detection_probability` of a path whose nodes' mean SNR is ``mean_snr_db``."""
        return 1.0 if self.config.ideal_detection else self._logistic(mean_snr_db, ops)

    def model(self, position, current_speed: float = 0.0) -> dict[str, np.ndarray]:
        """The documented noise model at a source position, per band (for users and tests).

        ``current_speed`` (m/s) matters only with flow noise (the default 0
        gives the calm-water model).

        Returns ``snr_db`` (Q, N), ``arrival_std`` (Q, N), ``tdoa_std`` (Q, N-1),
        ``azimuth_std`` (Q, N), ``elevation_std`` (Q, N) and
        ``detection_probability`` (Q,) of the direct path, and
        ``ghost_detection_probability`` (Q, 2) of the surface and bottom paths.
        """
        sources = self.image_sources(position, np)
        ranges, _, elevation = self.geometry(sources, np)
        snr = self.snr_db(ranges, self._path_loss, self.flow_noise_rise(current_speed, np), xp=np)
        timing, azimuth, theta = self.noise_std(snr, elevation, np)
        pd = self.detection_probability(snr, xp=np)
        return {
            "snr_db": snr[:, 0],
            "arrival_std": timing[:, 0],
            "tdoa_std": np.hypot(timing[:, 0, 1:], timing[:, 0, :1]),
            "azimuth_std": azimuth[:, 0],
            "elevation_std": theta[:, 0],
            "detection_probability": pd[:, 0],
            "ghost_detection_probability": pd[:, 1:],
        }

    def position_crb(self, position, current_speed: float = 0.0, periods: int = 1,
                     step: float = 1e-3) -> float:
        """Cramer-Rao bound on the RMSE (m) of any unbiased fix of a static source.

        The bound of the documented measurement model from ``periods`` sample
        periods of every band's direct-path detection (Kay, *Fundamentals of
        Statistical Signal Processing: Estimation Theory*, 1993, §3.9): per band
        the Fisher information ``H^T R^-1 H`` of the stacked TDOAs (their
        covariance ``diag(s_i^2) + s_1^2`` through node 1), azimuths and
        elevations, with ``H`` the measurement Jacobian (central differences of
        :meth:`noise_free`, ``step`` m); a band detected with probability
        ``p_D`` contributes ``p_D`` times its information (the information
        reduction factor of missed detections without clutter; Niu, Willett &
        Bar-Shalom, IEEE Trans. AES 37(1), 2001); bands and periods add. The
        per-episode errors that every band shares (clock offsets, sound-speed
        error, travel-time wander) and clutter and ghosts are not in it: it is
        the limit set by the noise alone, which only a tracker that has
        estimated those can approach. Returns ``sqrt(trace(J^-1))``.
        """
        p = np.asarray(position, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"position must be a finite (3,) point, got {position!r}")
        if periods < 1:
            raise ValueError(f"periods must be >= 1, got {periods}")
        jacobian = np.empty((3 * self.n_nodes - 1, 3))
        for axis in range(3):
            offset = np.zeros(3)
            offset[axis] = step
            plus = np.concatenate(self.noise_free(p + offset, np))
            minus = np.concatenate(self.noise_free(p - offset, np))
            difference = plus - minus
            n = self.n_nodes
            difference[n - 1 : 2 * n - 1] = _wrap(difference[n - 1 : 2 * n - 1], np)
            jacobian[:, axis] = difference / (2.0 * step)
        model = self.model(p, current_speed)
        information = np.zeros((3, 3))
        for q in range(self.config.n_bands):
            arrival = model["arrival_std"][q]
            tdoa_cov = np.diag(arrival[1:] ** 2) + arrival[0] ** 2
            n = self.n_nodes
            precision = np.zeros((3 * n - 1, 3 * n - 1))
            precision[: n - 1, : n - 1] = np.linalg.inv(tdoa_cov)
            angles = np.concatenate([model["azimuth_std"][q], model["elevation_std"][q]])
            precision[n - 1 :, n - 1 :] = np.diag(angles ** -2.0)
            information += model["detection_probability"][q] * (
                jacobian.T @ precision @ jacobian)
        return float(np.sqrt(np.trace(np.linalg.inv(periods * information))))

    def draw_clock_offsets(self, rng, xp):
        """Per-episode clock offsets (N,), node 1's zero."""
        offsets = rng.normal(0.0, 1.0, self.n_nodes) * self.config.clock_offset_std
        return xp.where(xp.arange(self.n_nodes) == 0, 0.0, offsets)

    def emission_positions(self, track, count: int, dt: float, sound_speed=None, *, xp):
        """Where the source was when the sound each node hears now left it (propagation delay).

        Args:
          track: (M, 3) source positions at consecutive sample periods ``dt`` apart; the
            last ``count`` rows are the periods to measure, the rows before them the
            history (earlier times are clamped to the first row: the source held still).
          count: periods to measure (the last ``count`` rows of ``track``).
          dt: sample period, s.
          sound_speed: the water's true sound speed (m/s); None: the nominal one.

        Returns:
          (count, N, 3): per period and node, the source's position at the emission time
          ``t - R_i / c`` of the sound node ``i`` hears at ``t``, solved by fixed-point
          iteration (three passes; each cuts the error by v / c ~ 1e-3) with linear
          interpolation between periods.
        """
        track = xp.asarray(track, dtype=float)
        if track.ndim != 2 or track.shape[1] != 3 or not 1 <= count <= len(track):
            raise ValueError(f"need a (M >= count, 3) track, got {track.shape} for {count}")
        c = self.config.sound_speed if sound_speed is None else sound_speed
        now = xp.arange(len(track) - count, len(track), dtype=track.dtype)[:, None]  # (B, 1)
        emitted = xp.broadcast_to(track[-count:, None, :], (count, self.n_nodes, 3))
        for _ in range(3):
            ranges = xp.linalg.norm(emitted - self.positions, axis=-1)  # (B, N)
            index = xp.clip(now - ranges / (c * dt), 0.0, len(track) - 1.0)
            low = xp.floor(index).astype(int)
            high = xp.minimum(low + 1, len(track) - 1)
            frac = (index - low)[..., None]
            emitted = track[low] * (1.0 - frac) + track[high] * frac
        return emitted

    def _node_angles(self, node_positions, paths: int, xp):
        """Azimuths and elevations (B, P, N), node ``i`` seeing its own row of (B, N, 3)."""
        sources = self.image_sources(node_positions[:, :, None, :], xp)[:, :, :paths]
        d = sources - self.positions[None, :, None, :]  # (B, N, P, 3)
        horizontal = xp.hypot(d[..., 0], d[..., 1])
        azimuth = xp.arctan2(d[..., 1], d[..., 0]).transpose(0, 2, 1)
        elevation = xp.arctan2(horizontal, d[..., 2]).transpose(0, 2, 1)
        return azimuth, elevation

    def draw_wander(self, rng, count: int, previous=None, *, xp):
        """``count`` periods of the nodes' unit travel-time wander (count, N), continuing
        ``previous`` (N,) (None: drawn from the stationary distribution). Scale it with
        :meth:`wander_std`. No draw when the wander is off (returns None)."""
        c = self.config
        if c.fluctuation_intensity == 0.0:
            return None
        return unit_gauss_markov(rng, count, (self.n_nodes,),
                                 1.0 / (c.sample_rate * c.fluctuation_time), previous, xp=xp)

    def draw_fading(self, rng, count: int, previous=None, *, xp):
        """``count`` periods of every band's and node's fading (count, Q, N) in dB,
        continuing ``previous`` (Q, N) dB. No draw when fading is off (returns None)."""
        c = self.config
        if c.fading_std == 0.0:
            return None
        unit = None if previous is None else previous / c.fading_std
        return c.fading_std * unit_gauss_markov(
            rng, count, (c.n_bands, self.n_nodes), 1.0 / (c.sample_rate * c.fading_time), unit,
            xp=xp)

    def draw_node_states(self, rng, count: int, previous=None, *, xp):
        """``count`` periods of which nodes work (count, N) bool, continuing ``previous``
        (N,) (None: drawn from the stationary distribution). No draw when dropouts are off
        (returns None).

        The continuous-time chain of the module docstring, with ``lambda`` =
        ``node_dropout_rate`` and ``mu = 1 / node_dropout_duration``, sampled exactly at
        ``dt = 1 / fs``: its transition matrix ``exp(Q dt)`` takes a working node out with
        probability ``pi_out (1 - exp(-(lambda + mu) dt))`` and an out node back with
        ``(1 - pi_out) (1 - exp(-(lambda + mu) dt))``, ``pi_out = lambda / (lambda + mu)``.
        """
        c = self.config
        if c.node_dropout_rate == 0.0:
            return None
        total = c.node_dropout_rate + 1.0 / c.node_dropout_duration
        moves = -math.expm1(-total / c.sample_rate)
        out = c.node_dropout_rate / total
        return two_state_markov(rng, count, (self.n_nodes,), out * moves, (1.0 - out) * moves,
                                previous, xp=xp)

    def wander_std(self, ranges, xp):
        """Travel-time wander's standard deviation, s, over ranges (m): mu sqrt(L_p R) / c."""
        c = self.config
        return c.fluctuation_intensity * xp.sqrt(c.fluctuation_length * ranges) / c.sound_speed

    def draw_sound_speed(self, rng, xp):
        """The water's true sound speed for an episode, m/s (no draw when the error is off;
        a float on NumPy, a scalar array on other backends)."""
        c = self.config
        if c.sound_speed_error_std == 0.0:
            return c.sound_speed
        limit = SOUND_SPEED_ERROR_LIMIT * c.sound_speed
        error = xp.clip(c.sound_speed_error_std * rng.standard_normal(), -limit, limit)
        return c.sound_speed + (float(error) if xp is np else error)

    def measure(self, rng, positions, clock_offsets, current_speed=None, sound_speed=None,
                wander=None, fading=None, working=None, noise_draws: str = "kept", *,
                xp) -> Measurements:
        """Draw the detection sets of ``B`` sample periods, vectorised over periods.

        Args:
          rng: the episode's draws: its NumPy generator (the only source of randomness),
            or an object with the same ``random`` and ``standard_normal`` (a JAX key's,
            :class:`auv_envs.batched.functional.KeyDraws`).
          positions: (B, 3) source positions, one per sample period (or (3,)
            for a single period; the result then has no leading axis); or
            (B, N, 3) per-node emission positions (:meth:`emission_positions`):
            node ``i``'s angles are measured at row ``i``, every TDOA at row 0
            (node 1's emission time).
          clock_offsets: (N,) clock offsets of the nodes (see
            :meth:`draw_clock_offsets`).
          current_speed: (B,) current speed per period (m/s; a scalar for all
            of them). Required when the config has a ``flow_noise_level``
            (a ``ValueError`` otherwise), ignored without one.
          sound_speed: the water's true sound speed (m/s, see
            :meth:`draw_sound_speed`); None: the nominal ``config.sound_speed``.
          wander: (B, N) unit travel-time wander (:meth:`draw_wander`), scaled here
            by :meth:`wander_std` at each node's direct range; None: no wander.
          fading: (B, Q, N) fades in dB added to every path's SNR (:meth:`draw_fading`);
            None: no fading.
          working: (B, N) bool, which nodes work in each period (:meth:`draw_node_states`);
            an out node's angles and every TDOA involving it (all TDOAs while node 1 is
            out) are zero in every detection, and the detection probability is the working
            nodes'. None: every node works.
          noise_draws: ``"kept"`` (the default) draws the measurement noise last, for
            the detections kept only; ``"all"`` first, for every path of every band and
            period, detected or not (``AcousticTracking-v0``'s random stream); both on
            NumPy only. ``"fixed"`` (``FIXED_DRAWS``, any ``xp``) draws at fixed shapes:
            noise for every path, a vector for each of the K false-alarm slots (the
            Poisson count by inverse transform from one uniform per band), keys for the
            shuffle of every candidate. The same model in all three: only the order and
            number of the draws differ.
          xp: the array namespace, NumPy or ``jax.numpy`` (then the inputs may be traced:
            only their shapes are checked).

        Returns:
          :class:`Measurements` with arrays (B, Q, K, ...). Everything is drawn
          from ``rng``, so a seeded episode is reproducible.
        """
        if noise_draws not in (*NOISE_DRAWS, FIXED_DRAWS):
            raise ValueError(f"noise_draws must be one of {(*NOISE_DRAWS, FIXED_DRAWS)}, "
                             f"got {noise_draws!r}")
        if xp is not np and noise_draws != FIXED_DRAWS:
            raise ValueError(f"noise_draws={noise_draws!r} draws sets of varying size: "
                             f"NumPy only (use {FIXED_DRAWS!r})")
        positions = xp.asarray(positions, dtype=float)
        single = positions.ndim == 1
        positions = xp.atleast_2d(positions)
        n, p = self.n_nodes, self._n_paths
        per_node = positions.shape[1:] == (n, 3)
        if not (per_node or positions.shape[1:] == (3,)) or not _all_finite(positions, xp):
            raise ValueError(f"positions must be finite (B, 3) or (B, {n}, 3), "
                             f"got shape {positions.shape}")
        node_positions = positions if per_node else None
        if per_node:
            positions = positions[:, 0]
        b = len(positions)
        rise = None
        if self._flow_ratio is not None:
            if current_speed is None:
                raise ValueError("the config has flow noise: measure() needs current_speed")
            rise = self.flow_noise_rise(xp.broadcast_to(current_speed, (b,)), xp)  # (B, Q)
        sources = self.image_sources(positions[:, None, :], xp)[:, :p]  # (B, P, 3)
        if node_positions is None:
            ranges, azimuth, elevation = self.geometry(sources, xp)  # (B, P, N)
        else:
            ranges = self.ranges(sources, xp)
            azimuth, elevation = self._node_angles(node_positions, p, xp)
        snr = self.snr_db(ranges[:, None], self._path_loss[:p], rise, xp=xp)  # (B, Q, P, N)
        if fading is not None:
            snr = snr + xp.asarray(fading)[:, :, None, :]
        if working is not None:
            working = xp.atleast_2d(xp.asarray(working, dtype=bool))
            if working.shape != (b, n):
                raise ValueError(f"working must be ({b}, {n}) node states, got {working.shape}")
            pd = self.detection_probability(snr, working[:, None, None], xp=xp)  # (B, Q, P)
        else:
            pd = self.detection_probability(snr, xp=xp)  # (B, Q, P)
        speed = self.config.sound_speed if sound_speed is None else sound_speed
        if xp is np:
            speed = float(speed)
            if not (math.isfinite(speed) and speed > 0):
                raise ValueError(f"sound_speed must be a positive speed in m/s, "
                                 f"got {sound_speed!r}")
        delays = ranges / speed + clock_offsets  # (B, P, N) true arrival times
        if wander is not None:
            delays = delays + (wander * self.wander_std(ranges[:, 0], xp))[:, None]

        paths = _Paths(pd, snr, delays, azimuth, elevation)
        if noise_draws == FIXED_DRAWS:
            values, mask, origin, dropped = self._draw_fixed(rng, paths, working, xp)
        else:
            values, mask, origin, dropped = self._draw_sized(rng, paths, working, noise_draws)
        if working is not None:  # an out node measures nothing; without node 1, no TDOA
            columns = xp.concatenate([working[:, 1:] & working[:, :1], working, working], -1)
            values = values * columns[:, None, None, :]
        result = Measurements(values=values, mask=mask, origin=origin, dropped=dropped)
        if single:
            return Measurements(*(getattr(result, f.name)[0]
                                  for f in dataclasses.fields(Measurements)))
        return result

    def _noisy(self, delays, azimuth, elevation, lift, snr, angle_k, noise, xp):
        """Detection vectors (..., 3N - 1) of paths: their true arrival times (s), azimuths
        and elevations (with ``lift``, :func:`_lift` of the elevations), and SNRs (dB)
        (each (..., N)) with their bands' angle constants ``angle_k`` (broadcast against
        them), plus the noise of the module docstring from unit draws ``noise`` (3, ...,
        N)."""
        timing, sigma_el = self._timing_and_angle_std(snr, angle_k, xp)
        sigma_az = sigma_el / lift
        arrival = delays + timing * noise[0]
        return xp.concatenate([arrival[..., 1:] - arrival[..., :1],
                               _wrap(azimuth + sigma_az * noise[1], xp),
                               xp.clip(elevation + sigma_el * noise[2], 0.0, xp.pi)], axis=-1)

    def _false_alarms(self, uniform):
        """False-alarm vectors (..., 3N - 1) from uniforms (..., 3N - 1) on [0, 1)."""
        return uniform * self._clutter_scale + self._clutter_shift

    def _draw_fixed(self, rng, paths: _Paths, working, xp):
        """:meth:`measure`'s sets drawn at fixed shapes (``noise_draws="fixed"``): returns
        (values, mask, origin, dropped).

        The draws, in order: detections, the false alarms' slots and vectors, the
        shuffle's keys, every path's noise. The candidates of a (period, band) are its P
        paths and K false-alarm slots; the first K in the order of the keys (the valid
        ones shuffled, then the others) fill the K slots, an invalid one leaving its slot
        empty.
        """
        b, q, p = paths.pd.shape
        n, k = self.n_nodes, self.config.max_detections
        detected = rng.random((b, q, p)) < paths.pd
        slots = rng.random((b, q))[..., None] > self._clutter_cdf  # (B, Q, K)
        clutter = self._false_alarms(rng.random((b, q, k, 3 * n - 1)))
        valid = xp.concatenate([detected, slots], axis=-1)  # (B, Q, P + K)
        if working is not None:  # no node working: no false alarm either
            valid = valid & xp.any(working, axis=-1)[:, None, None]
        keys = xp.where(valid, rng.random(valid.shape), 2.0)
        noise = rng.standard_normal((3, b, q, p, n))
        elevation = paths.elevation[:, None]
        detections = self._noisy(paths.delays[:, None], paths.azimuth[:, None], elevation,
                                 _lift(elevation, xp), paths.snr, self._angle_k, noise, xp)
        candidates = xp.concatenate([detections, clutter], axis=-2)  # (B, Q, P + K, 3N - 1)
        order = xp.argsort(keys, axis=-1)[..., :k]  # (B, Q, K): the candidate in each slot
        mask = xp.take_along_axis(valid, order, axis=-1)
        values = xp.where(mask[..., None],
                          xp.take_along_axis(candidates, order[..., None], axis=-2), 0.0)
        origin = xp.where(mask, xp.asarray(self._candidate_origin)[order], ORIGIN_EMPTY)
        dropped = xp.maximum(xp.sum(valid, axis=-1, dtype=int) - k, 0)  # beyond the K
        return values, mask, origin.astype(xp.int8), dropped

    def _draw_sized(self, rng: np.random.Generator, paths: _Paths, working, noise_draws: str):
        """:meth:`measure`'s sets drawn on NumPy with as many draws as there are detections
        and false alarms (``"kept"``, ``"all"``): returns (values, mask, origin, dropped)."""
        b, q, p = paths.pd.shape
        n, k = self.n_nodes, self.config.max_detections
        # The draws, in order: [every path's noise], detections, false-alarm counts and
        # vectors, the shuffle's keys, [the kept paths' noise].
        if noise_draws == "all":
            every = rng.standard_normal((3, b, q, p, n), dtype=np.float32)
        valid = np.empty((b, q, p + k), dtype=bool)
        detected = valid[..., :p]
        np.less(rng.random((b, q, p)), paths.pd, out=detected)
        n_clutter = rng.poisson(self.config.clutter_rate, (b, q))
        slots = self._clutter_slot < n_clutter[..., None]  # (B, Q, K)
        clutter = self._false_alarms(rng.random((int(slots.sum()), 3 * n - 1)))
        valid[..., p:] = slots
        if working is not None:  # no node working: no false alarm either
            valid &= working.any(axis=-1)[:, None, None]
        keys = np.where(valid, rng.random(valid.shape), 2.0)
        # Each (period, band) row's candidates in the order of their keys (valid ones
        # first, shuffled; the rest after them, in index order): the rank of each.
        # (The inverse of the sorting permutation is its own argsort.)
        rank = np.argsort(np.argsort(keys, axis=-1, kind="stable"), axis=-1)
        kept = valid & (rank < k)
        path_b, path_q, path_p = np.nonzero(kept[..., :p])
        if noise_draws == "all":
            noise = every[:, path_b, path_q, path_p]  # (3, D, N)
        else:
            noise = rng.standard_normal((3, len(path_b), n), dtype=np.float32)
        noise = noise.astype(np.float64)  # exactly; float64 arithmetic from here on

        # The kept paths' detections (D, 3N - 1), from their rows of the (B * Q * P, N)
        # and (B * P, N) arrays (the elevations' lift once a path, not once a band).
        row = path_b * p + path_p
        elevation = paths.elevation.reshape(-1, n)
        detections = self._noisy(
            paths.delays.reshape(-1, n).take(row, axis=0),
            paths.azimuth.reshape(-1, n).take(row, axis=0),
            elevation.take(row, axis=0), _lift(elevation, np).take(row, axis=0),
            paths.snr.reshape(-1, n).take((path_b * q + path_q) * p + path_p, axis=0),
            self._angle_k[path_q, 0], noise, np)

        # Each kept candidate into its slot; the rest of the K slots empty.
        picked = np.zeros((b, q, k, 3 * n - 1))
        origin = np.full((b, q, k), ORIGIN_EMPTY, dtype=np.int8)
        slot = rank[path_b, path_q, path_p]
        picked[path_b, path_q, slot] = detections
        origin[path_b, path_q, slot] = path_p
        false_b, false_q, false_j = np.nonzero(slots)  # the order of ``clutter``'s rows
        false_kept = kept[false_b, false_q, p + false_j]
        false_b, false_q = false_b[false_kept], false_q[false_kept]
        slot = rank[false_b, false_q, p + false_j[false_kept]]
        picked[false_b, false_q, slot] = clutter[false_kept]
        origin[false_b, false_q, slot] = ORIGIN_CLUTTER
        dropped = np.maximum(valid.sum(axis=-1, dtype=np.int64) - k, 0)  # beyond the K
        return picked, origin != ORIGIN_EMPTY, origin, dropped

