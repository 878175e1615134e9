"""Irregular seas for the LARS capture task (opt-in: ``LARSCaptureEnv(sea=SeaSpectrum(...))``).

What the sea does to one episode, built from :mod:`auv_envs.core.waves`:

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
  (:func:`wash_over_timing`, :func:`analogs_in_play`).

All of it is linear in the wave components, so one :class:`~auv_envs.core.waves.HarmonicSeries`
per episode evaluates every channel at any time (no filter state to carry).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from auv_envs.core.waves import (
    DEFAULT_BAND,
    DEFAULT_COMPONENTS,
    FloaterResponse,
    HarmonicSeries,
    SeaSpectrum,
    ShipResponse,
    WaveRealisation,
    sea_state_code,
)
from auv_envs.tasks.lars_scene import AUV_DIAMETER, AUV_FREEBOARD, AUV_LENGTH

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
        auv, analog, ship: response models (:mod:`auv_envs.core.waves`).
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


class EpisodeSea:
    """Every sea-driven channel of one episode, as a function of time.

    Args:
        model: the sea model.
        waves: the episode's realisation.
        x0, y0, surge, yaw: the AUV's track (CG at ``(x0 + surge t, y0)``) and heading.
        analog_tracks: ``(x0, y0, speed)`` of each analog's centre.
    """

    def __init__(self, model: LARSSeaModel, waves: WaveRealisation, x0: float, y0: float,
                 surge: float, yaw: float, analog_tracks=()):
        k = waves.wavenumber
        encounter, c = waves.along_track(x0, y0, surge)
        heave, roll, pitch = model.auv.transfer(encounter, k, waves.heading - yaw)
        blocks = [(encounter, [c * heave, c * roll, c * pitch, c])]
        ox, oy, _ = model.ship_origin
        omega, c = waves.along_track(ox, oy)
        blocks.append((omega, [c * h for h in model.ship.transfer(omega, k, waves.heading)]))
        for ax, ay, speed in analog_tracks:
            encounter, c = waves.along_track(ax, ay, speed)
            heave = model.analog.transfer(encounter, k, waves.heading - yaw)[0]
            blocks.append((encounter, [c * heave]))
        self._series = HarmonicSeries(blocks)
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

    def __init__(self, origin, sample: SeaSample):
        cr, sr = math.cos(sample.ship_roll), math.sin(sample.ship_roll)
        cp, sp = math.cos(sample.ship_pitch), math.sin(sample.ship_pitch)
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

    def to_ship(self, point) -> np.ndarray:
        """The ship-frame point (3,) that is at world ``point`` now."""
        origin = np.asarray(self._origin)
        offset = np.asarray(point, dtype=float) - origin - (0.0, 0.0, self._heave)
        return origin + np.array(self._rows).T @ offset

    def transform(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` with ``p_world = R p_ship + t``."""
        rot = np.array(self._rows)
        origin = np.asarray(self._origin)
        return rot, origin + (0.0, 0.0, self._heave) - rot @ origin
