"""Irregular seas for the LARS capture task (opt-in: ``LARSCaptureTask(sea=SeaSpectrum(...))``).

What the sea does to one episode, built from :mod:`auv_envs.tasks.lars.waves`:

* the AUV (1.8 m x 0.2 m waterplane) heaves, rolls and pitches with the
  waves it meets along its surge track (:data:`AUV_RESPONSE`);
* the analogs heave with the elevation at their own drifting positions;
* the ship under the arm heaves, rolls and pitches (:data:`SHIP_RESPONSE`)
  about :data:`SHIP_ORIGIN`, and carries the arm with it: the arm's joint
  angles are relative to the ship, its end point moves as a point of the
  ship (:class:`ShipPose`), and the gimballed capture head below it stays
  level as before, so the cameras and the capture tip translate with it.
  The ship's accelerations and the tilt of gravity are not fed back into
  the arm's dynamics (its drives hold it; the loads are a few per cent of
  gravity at these motions);
* in ``severe`` sea, wash-over and look-alikes follow ``Hs``
  (:func:`wash_over_timing`, :func:`analogs_in_play`);
* with ``glint=SunGlint(...)``, the sun glitters on the water: specular
  points of the wind-roughened surface (:class:`SunGlint`, :class:`GlintField`)
  whose number follows the Cox–Munk slope variance of the wind that raised ``Hs``.

All of it is linear in the wave components, so one
:class:`~auv_envs.tasks.lars.waves.HarmonicSeries` per episode evaluates every channel at
any time (no filter state to carry).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from auv_envs.core.frames import GRAVITY
from auv_envs.core.ops import FLOATS
from auv_envs.core.pytree import attribute_pytree, dataclass_pytree
from auv_envs.tasks.lars.scene import AUV_DIAMETER, AUV_FREEBOARD, AUV_LENGTH, uniform_draws
from auv_envs.tasks.lars.waves import (
    DEFAULT_BAND,
    DEFAULT_COMPONENTS,
    PM_ALPHA,
    PM_BETA,
    FloaterResponse,
    HarmonicSeries,
    SeaSpectrum,
    ShipResponse,
    WaveRealisation,
    sea_state_code,
)

#: The AUV's response: its waterplane, roll/pitch lags (assumed, see FloaterResponse).
AUV_RESPONSE = FloaterResponse(AUV_LENGTH, AUV_DIAMETER)
#: The analogs' 0.9 m hulls (heave only).
ANALOG_RESPONSE = FloaterResponse(0.9, AUV_DIAMETER)
SHIP_RESPONSE = ShipResponse()
#: The ship's centre of rotation (world, m): amidships under the arm's slew axis
#: (x = 0), on the centreline half a beam inboard of the side (y = 0), at the
#: calm waterline.
SHIP_ORIGIN = (0.0, -SHIP_RESPONSE.beam / 2.0, 0.0)


def wash_over_timing(spectrum: SeaSpectrum, freeboard: float = AUV_FREEBOARD):
    """Mean interval between wash-overs and their mean duration, s.

    A crest washes over when it rises above the AUV's ``freeboard``: with
    Rayleigh-distributed crest heights (Longuet-Higgins 1952, narrow band),
    ``P(crest > f) = exp(-8 f^2 / Hs^2)``, one crest per mean zero-crossing
    period ``Tz``, so the mean interval is ``Tz / P``. A crest of the
    significant amplitude ``Hs / 2`` stays above ``f`` for
    ``Tz acos(2 f / Hs) / pi``. The hull's heave is not credited (it
    follows the long waves that carry the energy), so this is an upper bound
    on how often it happens. ``(inf, 0)`` when ``Hs / 2 <= f``.
    """
    crest = 0.5 * spectrum.hs
    if crest <= freeboard:
        return math.inf, 0.0
    tz = spectrum.zero_crossing_period
    return tz / math.exp(-8.0 * (freeboard / spectrum.hs) ** 2), tz * math.acos(
        freeboard / crest) / math.pi


def analogs_in_play(hs: float) -> int:
    """Look-alikes in view in ``severe`` sea: 0 up to sea state code 1, 1 at code 2
    (smooth, Hs 0.1-0.5 m), 2 from code 3 (slight, whitecaps) up. A convention
    of this benchmark (more clutter in rougher seas), not a physical law."""
    return min(max(sea_state_code(hs) - 1, 0), 2)


@dataclasses.dataclass(frozen=True)
class LARSSeaModel:
    """The sea model of an env built with ``sea=`` (``calibration.sea``).

    Attributes:
        spectrum: the wave spectrum.
        auv, analog, ship: response models (:mod:`auv_envs.tasks.lars.waves`).
        ship_origin: world point (m) the ship's roll and pitch turn about.
        n_components: harmonic components per realisation.
        band: frequency band, in units of the peak frequency.
        wash_interval, wash_duration: :func:`wash_over_timing` (s), the
            centres of the ``severe`` schedule's ranges (+-25 %).
        analogs: :func:`analogs_in_play` of ``Hs``.
        heading_range: (low, high) of the wave direction drawn per episode, rad.
    """

    spectrum: SeaSpectrum
    auv: FloaterResponse = AUV_RESPONSE
    analog: FloaterResponse = ANALOG_RESPONSE
    ship: ShipResponse = SHIP_RESPONSE
    ship_origin: tuple[float, float, float] = SHIP_ORIGIN
    n_components: int = DEFAULT_COMPONENTS
    band: tuple[float, float] = DEFAULT_BAND
    wash_interval: float = math.inf
    wash_duration: float = 0.0
    analogs: int = 0
    heading_range: tuple[float, float] = (0.0, 2.0 * math.pi)

    @classmethod
    def from_spectrum(cls, spectrum: SeaSpectrum) -> LARSSeaModel:
        if not isinstance(spectrum, SeaSpectrum):
            raise ValueError(f"sea must be a SeaSpectrum or None, got {spectrum!r}")
        interval, duration = wash_over_timing(spectrum)
        return cls(spectrum, wash_interval=interval, wash_duration=duration,
                   analogs=analogs_in_play(spectrum.hs))

    def wash_ranges(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """``WashOver.sample``'s (period, duration) ranges; None: crests never overtop."""
        if not math.isfinite(self.wash_interval):
            return None
        return ((0.75 * self.wash_interval, 1.25 * self.wash_interval),
                (0.75 * self.wash_duration, 1.25 * self.wash_duration))


class SeaSample(NamedTuple):
    """The sea's state at one time (m, rad, and their rates per second)."""

    auv_heave: float
    auv_roll: float
    auv_pitch: float
    level: float
    ship_heave: float
    ship_roll: float
    ship_pitch: float
    analog_levels: tuple[float, ...]
    auv_heave_rate: float
    ship_heave_rate: float
    ship_roll_rate: float
    ship_pitch_rate: float


@attribute_pytree(("_series",), ("_n_analogs",))
class EpisodeSea:
    """Every sea-driven channel of one episode, as a function of time.

    Args:
        model: the sea model.
        waves: the episode's realisation.
        x0, y0, surge, yaw: the AUV's track (CG at ``(x0 + surge t, y0)``) and heading.
        analog_tracks: ``(x0, y0, speed)`` of each analog's centre.
    """

    def __init__(self, model: LARSSeaModel, waves: WaveRealisation, x0: float, y0: float,
                 surge: float, yaw: float, analog_tracks, ops):
        k = waves.wavenumber
        encounter, c = waves.along_track(x0, y0, surge, ops=ops)
        heave, roll, pitch = model.auv.transfer(encounter, k, waves.heading - yaw, ops)
        blocks = [(encounter, [c * heave, c * roll, c * pitch, c])]
        ox, oy, _ = model.ship_origin
        omega, c = waves.along_track(ox, oy, ops=ops)
        blocks.append((omega, [c * h for h in model.ship.transfer(omega, k, waves.heading,
                                                                  ops)]))
        for ax, ay, speed in analog_tracks:
            encounter, c = waves.along_track(ax, ay, speed, ops=ops)
            heave = model.analog.transfer(encounter, k, waves.heading - yaw, ops)[0]
            blocks.append((encounter, [c * heave]))
        self._series = HarmonicSeries(blocks, ops.xp)
        self._n_analogs = len(analog_tracks)

    def __call__(self, t: float) -> SeaSample:
        v = self._series(t)
        m = self._series.n_channels
        return SeaSample(*v[:7], tuple(v[7:m]), v[m], v[m + 4], v[m + 5], v[m + 6])


class ShipPose:
    """The ship's displacement at one time: ``p_world = O + h z + R (p_ship - O)`` with
    ``R = Ry(pitch) Rx(roll)`` (right-handed about world x and y; the ship's
    frame coincides with the world frame in calm water)."""

    __slots__ = ("_origin", "_rows", "_heave", "_omega", "_heave_rate")

    def __init__(self, origin, sample: SeaSample, ops):
        cr, sr = ops.cos(sample.ship_roll), ops.sin(sample.ship_roll)
        cp, sp = ops.cos(sample.ship_pitch), ops.sin(sample.ship_pitch)
        self._origin = origin
        self._rows = ((cp, sp * sr, sp * cr), (0.0, cr, -sr), (-sp, cp * sr, cp * cr))
        self._heave = sample.ship_heave
        self._heave_rate = sample.ship_heave_rate
        # Angular velocity of Ry(pitch) Rx(roll): Ry (roll_rate, 0, 0) + (0, pitch_rate, 0).
        self._omega = (cp * sample.ship_roll_rate, sample.ship_pitch_rate,
                       -sp * sample.ship_roll_rate)

    def carry(self, x, y, z, vx, vy, vz) -> tuple[float, ...]:
        """World position and velocity of a point at ``(x, y, z)`` moving at
        ``(vx, vy, vz)`` in the ship's frame (six floats)."""
        ox, oy, oz = self._origin
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self._rows
        dx, dy, dz = x - ox, y - oy, z - oz
        rx, ry, rz = (r00 * dx + r01 * dy + r02 * dz, r10 * dx + r11 * dy + r12 * dz,
                      r20 * dx + r21 * dy + r22 * dz)
        wx, wy, wz = self._omega
        return (
            ox + rx, oy + ry, oz + self._heave + rz,
            wy * rz - wz * ry + r00 * vx + r01 * vy + r02 * vz,
            wz * rx - wx * rz + r10 * vx + r11 * vy + r12 * vz,
            self._heave_rate + wx * ry - wy * rx + r20 * vx + r21 * vy + r22 * vz,
        )

    def to_ship(self, point, xp) -> np.ndarray:
        """The ship-frame point (3,) that is at world ``point`` now (``xp``: NumPy, or
        ``jax.numpy``)."""
        origin = xp.asarray(self._origin)
        offset = xp.stack(list(point)) - origin - xp.stack([0.0, 0.0, self._heave])
        return origin + xp.asarray(self._rows).T @ offset

    def transform(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` with ``p_world = R p_ship + t``."""
        rot = np.array(self._rows)
        origin = np.asarray(self._origin)
        return rot, origin + (0.0, 0.0, self._heave) - rot @ origin


# ---------------------------------------------------------------------- sun glint
#: Cox & Munk (1954), "Measurement of the roughness of the sea surface from
#: photographs of the sun's glitter", JOSA 44(11), clean surface: mean-square
#: slope (both components summed) ``sigma^2 = 0.003 + 5.12e-3 U``, ``U`` the
#: wind speed at 12.5 m in m/s.
COX_MUNK_SLOPE_VARIANCE = (0.003, 5.12e-3)


def fully_developed_wind_speed(hs: float) -> float:
    """Wind speed (m/s) that raises a fully developed Pierson–Moskowitz sea of ``hs`` (m).

    ``Hs = 2 sqrt(alpha / beta) U^2 / g ~= 0.21 U^2 / g`` (Pierson & Moskowitz
    1964, the relation behind :func:`~auv_envs.tasks.lars.waves.fully_developed_peak_period`).
    PM's ``U`` is at 19.5 m, Cox–Munk's at 12.5 m, about 4 % apart in a
    logarithmic wind profile: neglected.
    """
    if not (math.isfinite(hs) and hs >= 0):
        raise ValueError(f"hs must be a finite number >= 0, got {hs!r}")
    return math.sqrt(GRAVITY * hs / (2.0 * math.sqrt(PM_ALPHA / PM_BETA)))


def cox_munk_slope_variance(wind_speed: float) -> float:
    """Mean-square slope ``sigma^2`` of the sea at ``wind_speed`` (m/s), Cox & Munk (1954)."""
    intercept, per_wind = COX_MUNK_SLOPE_VARIANCE
    return intercept + per_wind * wind_speed


def _angle_range(name: str, value, low: float, high: float) -> tuple[float, float]:
    lo, hi = (float(v) for v in value)
    if not (math.isfinite(lo) and math.isfinite(hi) and low <= lo <= hi <= high):
        raise ValueError(f"{name} must be (low, high) within [{low:.4g}, {high:.4g}] rad, "
                         f"got {value!r}")
    return lo, hi


@dataclasses.dataclass(frozen=True)
class SunGlint:
    """The sun's glitter on the water seen by the stereo pair (``LARSCaptureTask(glint=...)``).

    **Slopes.** The slopes ``(zx, zy)`` of a wind-roughened sea are Gaussian,
    isotropic to first order (Cox & Munk 1954)::

        p(zx, zy) = exp(-(zx^2 + zy^2) / sigma^2) / (pi sigma^2),
        sigma^2 = 0.003 + 5.12e-3 U                (U: wind speed, m/s)

    with ``U`` the wind that raised the episode's ``Hs``
    (:func:`fully_developed_wind_speed`) unless ``wind_speed`` is given.

    **Specular points.** A camera at ``C`` sees the sun at a surface point
    ``P`` when the facet there bisects the directions to the sun ``s`` and to
    the camera ``v = (C - P) / |C - P|`` (law of reflection): the slope needed
    is ``-(hx, hy) / hz`` with ``h = s + v``, ``tan^2 beta = (hx^2 + hy^2) / hz^2``.
    The points where the surface takes that slope number, per unit area,
    ``n = p E|det H|`` (Longuet-Higgins 1960, "Reflection and refraction at a
    random moving surface. I", JOSA 50(9); slope and curvature of a Gaussian
    surface are independent at a point), ``H`` the surface's Hessian. For an
    isotropic surface ``E|det H| = msc / (2 sqrt 3)`` with ``msc =
    E[(eta_xx + eta_yy)^2]`` its mean-square curvature (worked out here:
    ``det H = (msc / 8)(2 X - Y)`` with ``X ~ chi2(1)``, ``Y ~ chi2(2)``
    independent, and ``E|2 X - Y| = 4 / sqrt 3``). The curvature is carried by
    shorter waves than the slope, ``msc = k_s^2 sigma^2``, so::

        n = k_s^2 exp(-tan^2 beta / sigma^2) / (2 sqrt(3) pi)     per m^2

    which grows with the wind wherever the needed slope is not zero (and is
    the same there). ``k_s`` (``curvature_wavenumber``): a saturation range
    ``F(k) ~ k^-3`` (Phillips 1958) from the peak ``k_p ~ 0.1 rad/m`` to the
    gravity–capillary wavenumber ``k_c = sqrt(rho g / T) = 370 rad/m`` gives
    ``msc / mss = k_c^2 / (2 ln(k_c / k_p)) ~= (90 rad/m)^2``; 100 rad/m is
    that, rounded (an assumed value, not a measurement).

    **In the image.** Each specular point mirrors the sun's disc (6.8e-5 sr,
    about 2e7 W m^-2 sr^-1; Fresnel reflectance 0.02) over about
    ``6.8e-5 / (4 |det H|) ~ 1e-7 m^2``, some 3 % of a 2 mm pixel footprint
    at the 0.8 m the head tracks at: three orders of magnitude above the
    water's own few W m^-2 sr^-1. So glints are counted, not shaded: a pixel
    whose footprint on the water is ``A`` holds ``Poisson(n A)`` of them, and
    each saturates its pixel and blooms over those within ``bloom`` px. A
    glint lives about a capillary wave's period (0.01-0.1 s), less than a
    frame (0.04 s): every frame draws afresh, so they flicker. In
    ``features`` a glint within ``detector_radius`` px of a corner takes the
    corner detector: the corner is reported at the glint, or lost when the
    glint's bloom covers it.

    Attributes:
        sun_elevation: (low, high) of the sun's elevation above the horizon,
            rad, drawn uniformly per episode; within ``(0, pi / 2]``.
        sun_azimuth: (low, high) of the direction towards the sun, rad from
            world +x counter-clockwise, drawn uniformly per episode.
        wind_speed: m/s; None: :func:`fully_developed_wind_speed` of the
            sea's ``Hs``.
        curvature_wavenumber: ``k_s``, rad/m.
        detector_radius: px (at ``image_size``): LTAT's corner search margin
            (``MarkerCornerExtractor.find_partial``, 8 px).
        bloom: px a saturated glint spreads over (the pixels within this
            distance of it).
    """

    sun_elevation: tuple[float, float] = (math.radians(40.0), math.radians(80.0))
    sun_azimuth: tuple[float, float] = (0.0, 2.0 * math.pi)
    wind_speed: float | None = None
    curvature_wavenumber: float = 100.0
    detector_radius: float = 8.0
    bloom: int = 1

    def __post_init__(self):
        object.__setattr__(self, "sun_elevation", _angle_range(
            "sun_elevation", self.sun_elevation, 1e-6, 0.5 * math.pi))
        object.__setattr__(self, "sun_azimuth", _angle_range(
            "sun_azimuth", self.sun_azimuth, -2.0 * math.pi, 4.0 * math.pi))
        if self.wind_speed is not None and not (
                isinstance(self.wind_speed, int | float) and math.isfinite(self.wind_speed)
                and self.wind_speed >= 0):
            raise ValueError(f"wind_speed must be None or >= 0 m/s, got {self.wind_speed!r}")
        for name in ("curvature_wavenumber", "detector_radius"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if isinstance(self.bloom, bool) or not isinstance(self.bloom, int) or self.bloom < 0:
            raise ValueError(f"bloom must be an int >= 0 (px), got {self.bloom!r}")

    def slope_variance(self, hs: float | None) -> float:
        """``sigma^2`` at ``wind_speed``, or at the wind of a sea of ``hs`` (m)."""
        wind = self.wind_speed
        if wind is None:
            if hs is None:
                raise ValueError("SunGlint needs a sea (its Hs sets the wind) or a wind_speed")
            wind = fully_developed_wind_speed(hs)
        return cox_munk_slope_variance(wind)

    def sample(self, rng: np.random.Generator, slope_variance: float,
               ops) -> GlintField:
        """The episode's field: the sun's elevation and azimuth drawn from ``rng`` (2 uniforms;
        ``ops`` the backend of :mod:`auv_envs.core.ops`)."""
        elevation, azimuth = uniform_draws(rng, (self.sun_elevation, self.sun_azimuth), ops)
        return GlintField.towards(elevation, azimuth, slope_variance, self.curvature_wavenumber,
                                  ops)


@dataclass_pytree()
@dataclasses.dataclass(frozen=True)
class GlintField:
    """One episode's glitter (:class:`SunGlint`): how densely specular points lie.

    Attributes:
        sun: unit vector towards the sun (world, z up).
        slope_variance: ``sigma^2``.
        peak_density: ``k_s^2 / (2 sqrt(3) pi)``, glints per m^2 where the
            needed slope is zero.
        elevation, azimuth: of the sun, rad.
    """

    sun: tuple[float, float, float]
    slope_variance: float
    peak_density: float
    elevation: float
    azimuth: float

    @classmethod
    def towards(cls, elevation, azimuth, slope_variance: float, curvature_wavenumber: float,
                ops) -> GlintField:
        """The field of a sun at ``elevation`` and ``azimuth`` (rad; scalars of ``ops``)."""
        ce = ops.cos(elevation)
        sun = (ce * ops.cos(azimuth), ce * ops.sin(azimuth), ops.sin(elevation))
        peak = curvature_wavenumber**2 / (2.0 * math.sqrt(3.0) * math.pi)
        if ops is FLOATS:
            elevation, azimuth = float(elevation), float(azimuth)
        return cls(sun, float(slope_variance), peak, elevation, azimuth)

    def density(self, vx, vy, vz, xp) -> np.ndarray:
        """Glints per m^2 of level surface seen along the unit view direction ``(vx, vy, vz)``
        (arrays broadcast together), from the surface towards the camera (world, z up)."""
        sx, sy, sz = self.sun
        hx, hy, hz = vx + sx, vy + sy, vz + sz
        tan2 = (hx * hx + hy * hy) / (hz * hz)
        return self.peak_density * xp.exp(-tan2 / self.slope_variance)

    def pixel_means(self, rays, height: float, focal: float, xp) -> np.ndarray:
        """Mean glints in pixels that look along ``rays`` onto water ``height`` below.

        Args:
            rays: (..., 3) world images of the pixels' camera-frame rays
                ``((u - cx) / f, (v - cy) / f, 1)``.
            height: the camera's height above the water, m.
            focal: ``f``, px.

        Returns:
            (...) ``n A``, ``A = h^2 / (f^2 |d_z|^3)`` the footprint on the
            water of a pixel whose ray is ``d``; 0 where the ray does not go down.
        """
        if xp is np:
            rays = np.asarray(rays, dtype=float)
        down = -rays[..., 2]
        safe = xp.where(down > 0.0, down, 1.0)
        norm = -xp.sqrt(xp.sum(rays * rays, axis=-1))
        area = height**2 / (focal**2 * safe**3)
        density = self.density(rays[..., 0] / norm, rays[..., 1] / norm, rays[..., 2] / norm, xp)
        return xp.where(down > 0.0, density * area, 0.0)


def sample_waves(rng: np.random.Generator, sea: LARSSeaModel, heading,
                 xp) -> WaveRealisation:
    """The episode's wave direction (drawn even when ``heading`` pins it) and realisation
    (``xp``: NumPy, or ``jax.numpy`` with a JAX key's draws)."""
    drawn = rng.uniform(*sea.heading_range)
    if heading is None:
        heading = drawn
    elif isinstance(heading, bool) or not (
        isinstance(heading, int | float) and math.isfinite(heading)
    ):
        raise ValueError(f"wave_heading must be a finite angle in rad, got {heading!r}")
    else:
        heading = float(heading)
    return WaveRealisation.sample(sea.spectrum, rng, sea.n_components, heading, sea.band, xp=xp)
