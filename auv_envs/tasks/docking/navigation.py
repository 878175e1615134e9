"""An AUV's navigation sensors: DVL, AHRS, pressure depth and a USBL fix of a transponder.

[OFNMPC] §1: an AUV's navigation sensors are typically a Doppler velocity log, an
inertial navigation system and a pressure sensor, and its position relative to a
docking station comes from acoustic equipment or from vision. Each model here is a
frozen dataclass of its parameters (the figures and their sources are in
``docs/navigation.md``, and at the presets in :mod:`auv_envs.tasks.docking.env`) whose
methods draw from the episode's generator and take the backend's scalar arithmetic
``ops`` (:mod:`auv_envs.core.ops`: Python floats on the CPU, ``jax.numpy`` under
``jit``/``vmap``; the USBL's fix, made once a period, the array module ``xp``). Every
step draws the same numbers of the same shapes whatever happens, so one code path serves
both; only on the CPU does a step without a USBL ping skip the fix and its draws
(``ops.either``).

* **DVL** (bottom lock): the body-frame velocity over the seabed, each axis scaled by
  ``1 + s_i`` with ``s_i`` drawn once per episode (N(0, ``scale_std``^2): the
  data sheets' "long-term accuracy"), plus white noise ``noise_std`` per ping. No
  lock (reading zero, ``valid`` false) below ``min_altitude`` or above
  ``max_altitude`` over the seabed, and on a ping lost with probability ``dropout``.
* **AHRS**: roll, pitch and heading with white errors (``roll_pitch_std``,
  ``heading_std``; an AHRS filter's output error), the heading also off by a deviation
  drawn once per episode (std ``heading_bias_std``: relative to the station's frame, the
  compass's deviation near the station's steel and the error of the station's surveyed
  heading; drawn only when nonzero, so the other presets' streams are unchanged), and
  the body rates from gyros with
  white noise of density ``rate_noise_density`` (rad/s/sqrt(Hz); a reading averaged
  over the step ``dt`` has std ``density / sqrt(dt)``) plus a bias: drawn at the
  episode's start with std ``bias_instability`` and wandering as a random walk that
  grows by ``bias_instability`` in ``bias_time`` seconds.
* **Depth** from pressure: the true depth plus white noise ``noise_std``, quantised to
  ``resolution``.
* **USBL**: a transceiver of four elements on the vehicle fixes a transponder (on the
  station) once every ``period`` seconds through the acoustic measurement model of
  :mod:`auv_envs.core.acoustics` (its :class:`~auv_envs.core.acoustics.HydrophoneArray`
  is the transceiver, in body axes): the direct path and its surface and bottom
  mirror images, transmission loss, SNR, each element's arrival-time noise (the
  Cramer-Rao bound with the hardware floor) and the detection probability; the
  water's true sound speed differs from the nominal one by the episode's draw
  (``AcousticConfig.sound_speed_error_std``). The fix is the first detected arrival:
  the direct path, unless it is shadowed (probability ``shadowing``, e.g. by the
  vehicle's own hull) or missed, then the earliest detected mirror image (a multipath
  fix, metres off); with probability ``outlier_rate`` a spurious detection instead
  (uniform in range up to ``max_range`` and in direction). Range is the nominal sound
  speed times the mean one-way travel time and direction the least-squares plane wave
  through the elements' arrival times, refined by two Gauss-Newton steps on the
  spherical wave (the least-squares fix of the arrival times). It arrives later by the
  reply's two-way travel time plus ``processing_delay``; the observation carries its
  age.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, NamedTuple

import numpy as np

from auv_envs.core import frames
from auv_envs.core.acoustics import AcousticConfig, HydrophoneArray
from auv_envs.core.plant import CompiledFunction, SymbolicDraws


def _check(owner: str, **values) -> None:
    """``ValueError`` for a field that is not a finite number >= 0."""
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value) or value < 0:
            raise ValueError(f"{owner}.{name} must be a finite number >= 0, got {value!r}")


@dataclasses.dataclass(frozen=True)
class DVL:
    """Doppler velocity log in bottom lock (module docstring). Speeds m/s, altitudes m."""

    noise_std: float = 0.02
    scale_std: float = 0.01
    min_altitude: float = 0.05
    max_altitude: float = 50.0
    dropout: float = 0.0

    def __post_init__(self):
        _check("DVL", noise_std=self.noise_std, scale_std=self.scale_std,
               min_altitude=self.min_altitude, max_altitude=self.max_altitude,
               dropout=self.dropout)
        if not self.min_altitude < self.max_altitude or self.dropout > 1:
            raise ValueError("DVL needs min_altitude < max_altitude and dropout <= 1")

    def draw_scale(self, draws, ops):
        """The episode's scale-factor errors (3 scalars)."""
        return ops.vector([self.scale_std * e for e in ops.unpack(draws.standard_normal(3))])

    def read(self, velocity, altitude, scale, draws, ops):
        """``(reading (3 scalars), valid)`` for the body-frame velocity over the seabed (3
        scalars) at ``altitude`` m; draws 3 normals and 1 uniform."""
        noise = ops.unpack(draws.standard_normal(3))
        lost = draws.random() < self.dropout
        valid = ops.logical_and(ops.logical_and(altitude >= self.min_altitude,
                                                altitude <= self.max_altitude),
                                ops.logical_not(lost))
        reading = [(1.0 + s) * v + self.noise_std * e
                   for s, v, e in zip(scale, velocity, noise, strict=True)]
        return ops.where(valid, ops.vector(reading), ops.vector((0.0, 0.0, 0.0))), valid


@dataclasses.dataclass(frozen=True)
class AHRS:
    """Attitude and heading reference system (module docstring). Angles rad, rates rad/s."""

    roll_pitch_std: float = math.radians(0.5)
    heading_std: float = math.radians(1.0)
    rate_noise_density: float = math.radians(0.007)
    bias_instability: float = math.radians(10.0) / 3600.0
    bias_time: float = 100.0
    heading_bias_std: float = 0.0

    def __post_init__(self):
        _check("AHRS", roll_pitch_std=self.roll_pitch_std, heading_std=self.heading_std,
               rate_noise_density=self.rate_noise_density,
               bias_instability=self.bias_instability, bias_time=self.bias_time,
               heading_bias_std=self.heading_bias_std)
        if self.bias_time <= 0:
            raise ValueError("AHRS.bias_time must be positive")

    def draw_bias(self, draws, ops):
        """The gyros' bias at the episode's start (3 scalars)."""
        return ops.vector([self.bias_instability * e
                           for e in ops.unpack(draws.standard_normal(3))])

    def draw_heading_bias(self, draws, ops):
        """The episode's heading deviation (rad); draws 1 normal, or none (and returns 0)
        when ``heading_bias_std`` is 0."""
        if self.heading_bias_std == 0.0:
            return ops.real(0.0)
        return ops.real(self.heading_bias_std * draws.standard_normal())

    def read(self, euler, rates, bias, dt: float, draws, ops, heading_bias):
        """``(attitude, rates, bias)``, 3 scalars each: the readings of the true ``euler``
        (roll, pitch, yaw) and body ``rates`` (p, q, r) over a step of ``dt`` s, the
        heading off by the episode's ``heading_bias``, and the gyro bias after the step's
        random walk; draws 9 normals."""
        noise = ops.unpack(draws.standard_normal(9))
        roll, pitch, yaw = (angle + std * e for angle, std, e in zip(
            euler, (self.roll_pitch_std, self.roll_pitch_std, self.heading_std), noise[:3],
            strict=True))
        attitude = (roll, pitch, frames.wrap_angle(yaw + heading_bias, ops.mod))
        rate_std = self.rate_noise_density / math.sqrt(dt)
        walk = self.bias_instability * math.sqrt(dt / self.bias_time)
        reading = [r + b + rate_std * e for r, b, e in zip(rates, bias, noise[3:6], strict=True)]
        bias = [b + walk * e for b, e in zip(bias, noise[6:], strict=True)]
        return ops.vector(attitude), ops.vector(reading), ops.vector(bias)


@dataclasses.dataclass(frozen=True)
class DepthSensor:
    """Pressure depth sensor (module docstring). Metres."""

    noise_std: float = 0.014
    resolution: float = 0.001

    def __post_init__(self):
        _check("DepthSensor", noise_std=self.noise_std, resolution=self.resolution)

    def read(self, depth, draws, ops):
        """The reading of the true ``depth`` (m, positive down); draws 1 normal."""
        reading = depth + self.noise_std * draws.standard_normal()
        if self.resolution > 0:
            reading = ops.round(reading / self.resolution) * self.resolution
        return reading


#: The USBL transceiver's elements in body axes, m: a regular tetrahedron of 0.1 m edges
#: centred on the transceiver (four elements give the three directions; our choice).
TETRAHEDRON = tuple((0.1 / math.sqrt(8.0) * x, 0.1 / math.sqrt(8.0) * y, 0.1 / math.sqrt(8.0) * z)
                    for x, y, z in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)))
#: The USBL's acoustic link: one medium-frequency band (19-34 kHz, as most USBLs) and a
#: transponder's source level; the elements' timing floor (phase-difference precision)
#: sets the bearing accuracy (``docs/navigation.md``). No clock offsets or clutter (the
#: spurious fixes are ``USBL.outlier_rate``'s).
USBL_ACOUSTICS = AcousticConfig(
    band_centres=(26_500.0,), bandwidth=15_000.0, sample_rate=1.0, source_level=190.0,
    timing_floor=0.5e-6, clock_offset_std=0.0, clutter_rate=0.0, aperture=0.1,
    sound_speed_error_std=3.0, max_detections=3)


@dataclasses.dataclass(frozen=True)
class USBL:
    """USBL fix of a transponder (module docstring). Seconds, metres."""

    period: float = 1.0
    processing_delay: float = 0.2
    shadowing: float = 0.0
    outlier_rate: float = 0.0
    max_range: float = 1000.0
    elements: tuple = TETRAHEDRON
    acoustics: AcousticConfig = USBL_ACOUSTICS

    def __post_init__(self):
        _check("USBL", period=self.period, processing_delay=self.processing_delay,
               shadowing=self.shadowing, outlier_rate=self.outlier_rate,
               max_range=self.max_range)
        if self.period <= 0 or self.max_range <= 0 or self.shadowing > 1 \
                or self.outlier_rate > 1:
            raise ValueError("USBL needs period > 0, max_range > 0, and shadowing and "
                             "outlier_rate in [0, 1]")
        if len(self.elements) < 4:
            raise ValueError("USBL needs at least four elements")

    @functools.cached_property
    def _plane_wave(self) -> np.ndarray:
        """The least-squares solver (3, N) of the plane wave through the elements."""
        return np.linalg.pinv(self._elements - self._elements.mean(axis=0))

    @functools.cached_property
    def _elements(self) -> np.ndarray:
        """The elements' positions (N, 3), built once."""
        return np.asarray(self.elements, dtype=float)

    def array(self, surface_z: float, bottom_z: float) -> HydrophoneArray:
        """The transceiver as a hydrophone array: elements in body axes, the water's
        surface and bottom heights in the world (the mirror images are formed there)."""
        return HydrophoneArray(self.elements, surface_z, bottom_z, self.acoustics)

    def fix(self, array: HydrophoneArray, transceiver, rows, transponder, sound_speed,
            draws, xp):
        """One fix: ``(vector (3,), valid)``, the transponder as measured from the
        transceiver in body axes (m). ``transceiver`` and ``transponder`` are world
        positions (3,), ``rows`` the body-to-world rotation (3, 3), ``sound_speed`` the
        water's true one. Draws 3 + 1 uniforms, N normals and 1 + 3 uniforms, always."""
        sources = array.image_sources(xp.asarray(transponder), xp)  # (3 paths, 3), world
        body = (sources - xp.asarray(transceiver)) @ xp.asarray(rows)  # rows: R; R^T d
        ranges = array.ranges(body, xp)  # (P, N)
        snr = array.snr_db(ranges, array.path_loss, xp=xp)  # (1 band, P, N)
        timing = array.timing_std(snr, xp)[0]  # (P, N) s
        pd = array.detection_probability(snr, xp=xp)[0]  # (P,)
        detected = xp.asarray(draws.random(3)) < pd
        shadowed = draws.random() < self.shadowing
        detected = detected & xp.asarray([xp.logical_not(shadowed), True, True])
        # The first detected arrival: the nearest detected path (range of the centroid).
        # Means as sums over counts and norms as roots of sums of squares: NumPy's own
        # arithmetic in ``mean`` and ``linalg.norm``, without their per-call overhead.
        n = len(self.elements)
        centre = ranges.sum(axis=1) / n
        path = xp.argmin(xp.where(detected, centre, xp.inf))
        found = xp.any(detected)
        arrival = ranges[path] / sound_speed + timing[path] * xp.asarray(
            draws.standard_normal(n))
        nominal = self.acoustics.sound_speed
        mean = arrival.sum() / n
        # Plane wave: t_i - mean = -(e_i - e_mean) . u / c, solved by least squares.
        direction = -nominal * (xp.asarray(self._plane_wave) @ (arrival - mean))
        direction = direction / xp.sqrt(direction @ direction)
        vector = nominal * mean * direction
        # Two Gauss-Newton steps on the spherical wave |v - e_i| = c t_i give the
        # least-squares fix (the far-field plane wave alone is millimetres off at 20-160 m),
        # each by least squares on the Jacobian itself: its normal matrix is singular in
        # float32 a few hundred metres out, where the elements' unit vectors nearly coincide.
        elements = xp.asarray(self._elements)
        for _ in range(2):
            offsets = vector - elements
            ranges_now = xp.sqrt((offsets * offsets).sum(axis=1))
            jacobian = offsets / ranges_now[:, None]
            vector = vector + xp.linalg.lstsq(jacobian, nominal * arrival - ranges_now)[0]
        # A spurious detection: uniform in range and over the sphere.
        outlier = draws.random() < self.outlier_rate
        u = xp.asarray(draws.random(3))
        z = 2.0 * u[1] - 1.0
        ring = xp.sqrt(1.0 - z * z)
        angle = 2.0 * math.pi * u[2]
        spurious = self.max_range * u[0] * xp.stack([ring * xp.cos(angle),
                                                     ring * xp.sin(angle), z])
        vector = xp.where(outlier, spurious, vector)
        return xp.where(found | outlier, vector, 0.0), found | outlier

    def solve(self, array: HydrophoneArray, transceiver, euler, transponder, sound_speed,
              draws, ops):
        """:meth:`fix` in the scalar arithmetic of ``ops`` (:mod:`auv_envs.core.ops`), so
        that it compiles into one call: ``(vector (3 scalars), valid)``. ``transceiver``
        is the vehicle's world position and ``euler`` its attitude (3 scalars each),
        ``transponder`` a constant world position. The same model and the same draws as
        :meth:`fix`; the least squares of each Gauss-Newton step by a QR factorisation
        (modified Gram-Schmidt), so the numbers differ from :meth:`fix`'s at round-off."""
        n = len(self.elements)
        rows = frames.rotation_rows_from_euler(*euler, ops)
        # Each path's source (the transponder or its mirror image; constants) in body axes.
        ranges = []
        for source in array.image_sources(np.asarray(transponder, dtype=float), np).tolist():
            offset = [source[k] - transceiver[k] for k in range(3)]
            body = [sum(rows[k][j] * offset[k] for k in range(3)) for j in range(3)]
            ranges.append([_norm([body[j] - e[j] for j in range(3)], ops)
                           for e in self.elements])
        snr = [[array.path_snr_db(r, path, ops) for r in path_ranges]
               for path, path_ranges in enumerate(ranges)]
        pd = [array.path_detection(sum(path_snr) / n, ops) for path_snr in snr]
        hits = draws.random(3)
        shadowed = draws.random() < self.shadowing
        detected = [ops.logical_and(hits[0] < pd[0], ops.logical_not(shadowed)),
                    hits[1] < pd[1], hits[2] < pd[2]]
        # The first detected arrival: the detected path of the least mean range (the
        # first of equals, as argmin; the direct path where none is detected).
        first, least = ranges[0], ops.where(detected[0], sum(ranges[0]) / n, math.inf)
        timing = [array.timing_std(v, ops) for v in snr[0]]
        found = detected[0]
        for path in (1, 2):
            centre = sum(ranges[path]) / n
            nearer = ops.logical_and(detected[path], centre < least)
            least = ops.where(nearer, centre, least)
            first = [ops.where(nearer, a, b) for a, b in zip(ranges[path], first, strict=True)]
            timing = [ops.where(nearer, array.timing_std(v, ops), b)
                      for v, b in zip(snr[path], timing, strict=True)]
            found = ops.logical_or(found, detected[path])
        noise = draws.standard_normal(n)
        arrival = [r / sound_speed + t * noise[i]
                   for i, (r, t) in enumerate(zip(first, timing, strict=True))]
        nominal = self.acoustics.sound_speed
        mean = sum(arrival) / n
        # The plane wave, then two Gauss-Newton steps on the spherical wave (as in fix).
        solver = self._plane_wave.tolist()
        direction = [-nominal * sum(w * (t - mean) for w, t in zip(row, arrival, strict=True))
                     for row in solver]
        length = _norm(direction, ops)
        vector = [nominal * mean * (d / length) for d in direction]
        for _ in range(2):
            offsets = [[vector[j] - e[j] for j in range(3)] for e in self.elements]
            lengths = [_norm(o, ops) for o in offsets]
            columns = [[o[j] / r for o, r in zip(offsets, lengths, strict=True)]
                       for j in range(3)]
            residual = [nominal * t - r for t, r in zip(arrival, lengths, strict=True)]
            step = _least_squares(columns, residual, ops)
            vector = [v + d for v, d in zip(vector, step, strict=True)]
        outlier = draws.random() < self.outlier_rate
        u = draws.random(3)
        z = 2.0 * u[1] - 1.0
        ring = ops.sqrt(1.0 - z * z)
        angle = 2.0 * math.pi * u[2]
        radius = self.max_range * u[0]
        spurious = (radius * (ring * ops.cos(angle)), radius * (ring * ops.sin(angle)),
                    radius * z)
        valid = ops.logical_or(found, outlier)
        return [ops.where(valid, ops.where(outlier, a, b), 0.0)
                for a, b in zip(spurious, vector, strict=True)], valid


def _observation(values, flags) -> dict:
    """The ``nav`` observation from its 14 float32 values (DVL velocity, attitude, rates,
    depth, USBL fix, its age) and 2 int8 flags (DVL lock, a fix arrived), in slices."""
    return {
        "dvl_velocity": values[0:3], "dvl_valid": flags[0:1], "attitude": values[3:6],
        "rates": values[6:9], "depth": values[9:10], "usbl": values[10:13],
        "usbl_age": values[13:14], "usbl_valid": flags[1:2],
    }


def _norm(vector, ops):
    """The Euclidean length of a few scalars."""
    return ops.sqrt(sum(v * v for v in vector))


def _least_squares(columns, b, ops) -> list:
    """The least-squares solution ``x`` of ``A x = b`` for ``A`` of full column rank given
    as its ``columns`` (each a list of scalars), by modified Gram-Schmidt: ``A = Q R`` and
    ``R x = Q^T b``, without the normal matrix (whose condition number is the square of
    ``A``'s)."""
    q, r, y = [], {}, list(b)
    for j, column in enumerate(columns):
        v = list(column)
        for k, unit in enumerate(q):
            r[k, j] = sum(a * c for a, c in zip(unit, v, strict=True))
            v = [c - r[k, j] * a for a, c in zip(unit, v, strict=True)]
        r[j, j] = _norm(v, ops)
        q.append([c / r[j, j] for c in v])
    coefficients = []
    for unit in q:  # Q^T b, removing each direction from b in turn (as for the columns)
        coefficients.append(sum(a * c for a, c in zip(unit, y, strict=True)))
        y = [c - coefficients[-1] * a for a, c in zip(unit, y, strict=True)]
    x = [0.0] * len(columns)
    for j in reversed(range(len(columns))):
        x[j] = (coefficients[j] - sum(r[j, k] * x[k] for k in range(j + 1, len(columns)))
                ) / r[j, j]
    return x


@dataclasses.dataclass(frozen=True)
class NavigationSensors:
    """The navigation suite of a docking scene (module docstring).

    Attributes:
        dvl, ahrs, depth, usbl: the sensors.
        station_depth: depth of the station's entrance below the surface, m (the
            pressure sensor's zero and the USBL's surface mirror).
        transponder: the USBL transponder's position in the station frame, m.
    """

    dvl: DVL = DVL()
    ahrs: AHRS = AHRS()
    depth: DepthSensor = DepthSensor()
    usbl: USBL = USBL()
    station_depth: float = 50.0
    transponder: tuple = (0.5, 0.0, 1.0)

    def __post_init__(self):
        for name, kind in (("dvl", DVL), ("ahrs", AHRS), ("depth", DepthSensor),
                           ("usbl", USBL)):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"NavigationSensors.{name} must be a {kind.__name__}")
        _check("NavigationSensors", station_depth=self.station_depth)
        if len(self.transponder) != 3 or not all(math.isfinite(v) for v in self.transponder):
            raise ValueError(f"transponder must be 3 finite coordinates, got "
                             f"{self.transponder!r}")


class NavState(NamedTuple):
    """The navigation sensors' part of an episode: per-episode draws, the gyro bias, the
    fix in flight and the last delivered one, and this step's readings (every field an
    array or scalar; a pytree)."""

    dvl_scale: Any
    gyro_bias: Any
    heading_bias: Any
    sound_speed: Any
    next_ping: Any
    pending: Any
    pending_valid: Any
    pending_time: Any
    pending_due: Any
    fix: Any
    fix_valid: Any
    fix_time: Any
    dvl: Any
    dvl_valid: Any
    attitude: Any
    rates: Any
    depth: Any


class Navigation:
    """The suite of :class:`NavigationSensors` in a scene: what a transition calls.

    Args:
        sensors: the suite.
        seabed_z: the seabed's height in the station frame, m.
        dt: the control period, s.
    """

    def __init__(self, sensors: NavigationSensors, seabed_z: float, dt: float):
        self.sensors = sensors
        self.surface_z, self.seabed_z = float(sensors.station_depth), float(seabed_z)
        self.array = sensors.usbl.array(self.surface_z, float(seabed_z))
        self.dt = float(dt)
        self._transponder = np.asarray(sensors.transponder, dtype=float)

    def start(self, truth: dict, draws, ops) -> NavState:
        """The episode's first sensor state and readings (``truth`` from the task's
        kinematics, with ``seabed_clearance``)."""
        return self.advance(self._initial(draws, ops), truth, 0.0, draws, ops)

    def _initial(self, draws, ops) -> NavState:
        """The episode's draws (DVL scale, gyro bias, heading deviation, sound speed) and
        nothing read yet."""
        s = self.sensors
        zero3, zero, no = ops.vector((0.0, 0.0, 0.0)), ops.real(0.0), ops.boolean(False)
        return NavState(
            dvl_scale=s.dvl.draw_scale(draws, ops), gyro_bias=s.ahrs.draw_bias(draws, ops),
            heading_bias=s.ahrs.draw_heading_bias(draws, ops),
            sound_speed=ops.real(self.array.draw_sound_speed(draws, ops.xp)), next_ping=zero,
            pending=zero3, pending_valid=no, pending_time=zero, pending_due=zero, fix=zero3,
            fix_valid=no, fix_time=zero, dvl=zero3, dvl_valid=no, attitude=zero3,
            rates=zero3, depth=zero)

    def advance(self, state: NavState, truth: dict, time, draws, ops) -> NavState:
        """The sensors at ``time`` s with the vehicle at ``truth``: this step's readings,
        a fix delivered if due, a ping made if due. The fix is made only on a ping's step
        on the CPU (its draws too); under JAX every step makes one and keeps it on a
        ping's (``ops.either``), so the batched episodes' draws differ from the CPU's."""
        s = self.sensors
        dvl, dvl_valid, attitude, rates, bias, depth = self.read(state, truth, draws, ops)
        # A fix in flight arrives once due; a new ping goes out on schedule.
        arrived = ops.logical_and(state.pending_valid, time >= state.pending_due - 1e-9)
        ping = time >= state.next_ping - 1e-9

        def fix():
            vector, found, travel = self.fix(state, truth, draws, ops)
            due = time + travel / state.sound_speed + s.usbl.processing_delay
            return ops.vector(ops.unpack(vector)), ops.boolean(found), ops.real(due)

        def no_fix():
            return (state.pending, ops.logical_and(state.pending_valid, ops.logical_not(arrived)),
                    state.pending_due)

        pending, pending_valid, pending_due = ops.either(ping, fix, no_fix)
        return state._replace(
            gyro_bias=bias,
            next_ping=ops.where(ping, state.next_ping + s.usbl.period, state.next_ping),
            pending=pending, pending_valid=pending_valid,
            pending_time=ops.where(ping, time, state.pending_time), pending_due=pending_due,
            fix=ops.where(arrived, state.pending, state.fix),
            fix_valid=ops.logical_or(state.fix_valid, arrived),
            fix_time=ops.where(arrived, state.pending_time, state.fix_time),
            dvl=dvl, dvl_valid=dvl_valid, attitude=attitude, rates=rates,
            depth=ops.real(depth))

    def read(self, state: NavState, truth: dict, draws, ops) -> tuple:
        """This step's readings: ``(dvl, dvl_valid, attitude, rates, gyro_bias, depth)``."""
        s = self.sensors
        velocity = truth["velocity"]
        dvl, dvl_valid = s.dvl.read(velocity[:3], truth["seabed_clearance"],
                                    state.dvl_scale, draws, ops)
        attitude, rates, bias = s.ahrs.read(truth["euler"], velocity[3:], state.gyro_bias,
                                            self.dt, draws, ops, state.heading_bias)
        depth = s.depth.read(self.surface_z - truth["position"][2], draws, ops)
        return dvl, dvl_valid, attitude, rates, bias, depth

    def fix(self, state: NavState, truth: dict, draws, ops) -> tuple:
        """A ping's fix: ``(vector, valid, travel)``, the measured transponder (body axes),
        whether there is one, and the two-way path length (m)."""
        xp = ops.xp
        position = xp.asarray(truth["position"])
        rows = frames.rotation_from_euler(*truth["euler"], ops=xp)
        vector, found = self.sensors.usbl.fix(self.array, position, rows, self._transponder,
                                              state.sound_speed, draws, xp)
        return vector, found, 2.0 * xp.linalg.norm(position - self._transponder)

    @staticmethod
    def observation(state: NavState, time, ops) -> dict:
        """The ``nav`` observation (float32 and int8 arrays)."""
        xp = ops.xp
        age = ops.where(state.fix_valid, time - state.fix_time, 0.0)
        # One array of each type, handed out in slices.
        values = xp.asarray((*state.dvl, *state.attitude, *state.rates, state.depth,
                             *state.fix, age), dtype=xp.float32)
        flags = xp.asarray((state.dvl_valid, state.fix_valid), dtype=xp.int8)
        return _observation(values, flags)


#: How the navigation sensors are evaluated on the CPU (the docking tasks' ``sensors``):
#: ``"numpy"`` (:class:`Navigation`: Python floats, the fix in NumPy) or ``"compiled"``
#: (:class:`CompiledNavigation`).
SENSOR_CODES = ("numpy", "compiled")


class CompiledNavigation(Navigation):
    """:class:`Navigation` on the CPU with a step of the sensors, readings, schedule and a
    ping's fix, one compiled call (:class:`auv_envs.core.plant.CompiledFunction`, built
    from :meth:`Navigation.advance` itself on CasADi symbols), fed the same draws in the
    same order from the episode's generator. The readings and the schedule are
    :class:`Navigation`'s to the bit; the fix is :meth:`USBL.solve`, whose least squares
    differ from :meth:`USBL.fix`'s at round-off, as does its arrival time (the travel's
    length a root of a sum of squares, not BLAS's norm).
    The sensors' state is one float64 vector: :data:`NavState`'s fields in order (a
    flag 1.0 or 0.0; :meth:`unpack` names them), then the observation at the step's time
    (its 14 values and 2 flags, as :meth:`Navigation.observation` makes them) and that
    time. Python floats only (``ops`` is
    :data:`~auv_envs.core.ops.FLOATS`); the batched tasks use :class:`Navigation`."""

    def __init__(self, sensors: NavigationSensors, seabed_z: float, dt: float):
        super().__init__(sensors, seabed_z, dt)
        function, draws = _navigation_function(sensors, self.seabed_z, self.dt)
        self._call = CompiledFunction(function)
        draw_input = self._call.inputs[2]
        self._every_step = draws.views(draw_input, slice(0, draws.marks[0]))
        self._on_ping = draws.views(draw_input, slice(draws.marks[0], None))

    def __reduce__(self):  # built again: the draws' views alias the call's inputs
        return type(self), (self.sensors, self.seabed_z, self.dt)

    def start(self, truth: dict, draws, ops) -> np.ndarray:
        initial = self._initial(draws, ops)
        return self.advance(_flatten(initial, float), truth, 0.0, draws, ops)

    def advance(self, state: np.ndarray, truth: dict, time, draws, ops) -> np.ndarray:
        call = self._call
        before, given = call.inputs[0], call.inputs[1]
        before[:] = state[:_STATE_SIZE]
        given[:] = (*truth["velocity"], truth["seabed_clearance"], *truth["euler"],
                    *truth["position"], time)
        SymbolicDraws.draw(self._every_step, draws)
        if time >= state[_NEXT_PING] - 1e-9:  # a ping: its fix's draws (as the call decides)
            SymbolicDraws.draw(self._on_ping, draws)
        return call()[0].copy()

    def observation(self, state: np.ndarray, time, ops) -> dict:
        if state[_SEEN_AT] == time:  # the observation the step made, at its time
            return _observation(state[_SEEN].astype(np.float32),
                                state[_SEEN_FLAGS].astype(np.int8))
        values = np.empty(14, dtype=np.float32)
        values[:13] = state[_OBSERVED]
        values[13] = time - state[_FIX_TIME] if state[_FIX_VALID] > 0.5 else 0.0
        return _observation(values, state[_FLAGS].astype(np.int8))

    @staticmethod
    def unpack(state: np.ndarray) -> NavState:
        """A state vector as a :class:`NavState` of Python floats, bools and tuples."""
        values, fields = state.tolist(), {}
        for name, (part, kind) in _LAYOUT.items():
            value = values[part]
            fields[name] = tuple(value) if kind is tuple else kind(value[0])
        return NavState(**fields)


#: :class:`CompiledNavigation`'s state vector: each :class:`NavState` field's slice and
#: type (a vector, a number or a flag).
_LAYOUT, _offset = {}, 0
for _name in NavState._fields:
    _width = 3 if _name in ("dvl_scale", "gyro_bias", "pending", "fix", "dvl", "attitude",
                            "rates") else 1
    _kind = tuple if _width == 3 else bool if _name.endswith("valid") else float
    _LAYOUT[_name] = (slice(_offset, _offset + _width), _kind)
    _offset += _width
del _name, _width, _kind, _offset
_NEXT_PING = _LAYOUT["next_ping"][0].start
_FIX_TIME, _FIX_VALID = _LAYOUT["fix_time"][0].start, _LAYOUT["fix_valid"][0].start
#: The state's entries of the observation's float32 values, in its order, and its flags.
_OBSERVED = np.r_[tuple(np.arange(_LAYOUT[name][0].start, _LAYOUT[name][0].stop)
                        for name in ("dvl", "attitude", "rates", "depth", "fix"))]
_FLAGS = np.array([_LAYOUT["dvl_valid"][0].start, _FIX_VALID])
#: After the fields: the observation's values and flags, and the time it was made at.
_STATE_SIZE = _LAYOUT["depth"][0].stop
_SEEN, _SEEN_FLAGS = slice(_STATE_SIZE, _STATE_SIZE + 14), slice(_STATE_SIZE + 14,
                                                                 _STATE_SIZE + 16)
_SEEN_AT = _STATE_SIZE + 16


def _flatten(state: NavState, scalar) -> list:
    """A :class:`NavState`'s fields as one list of scalars, in :data:`_LAYOUT`'s order
    (``scalar`` turns a flag or a number into one: ``float``, or the identity)."""
    flat = []
    for name, (_, kind) in _LAYOUT.items():
        value = getattr(state, name)
        flat.extend([value[k] for k in range(3)] if kind is tuple else [scalar(value)])
    return flat


class _SymbolicNavigation(Navigation):
    """:class:`Navigation` whose ping makes :meth:`USBL.solve`'s fix (scalar arithmetic),
    marking where the ping's draws begin: what :class:`CompiledNavigation` compiles."""

    def fix(self, state: NavState, truth: dict, draws, ops) -> tuple:
        draws.mark()
        transponder = self._transponder.tolist()
        vector, found = self.sensors.usbl.solve(self.array, truth["position"], truth["euler"],
                                                transponder, state.sound_speed, draws, ops)
        travel = 2.0 * _norm([p - t for p, t in zip(truth["position"], transponder,
                                                     strict=True)], ops)
        return ops.vector(vector), found, travel


@functools.lru_cache(maxsize=16)
def _navigation_function(sensors: NavigationSensors, seabed_z: float, dt: float):
    """:class:`CompiledNavigation`'s CasADi function ``(state[31], given[14], draws) ->
    [state 31, observation 14, flags 2, time]`` (given: body velocity 6, seabed clearance,
    Euler angles 3, position 3, time) and its draws' layout (those of every step, then
    from its first mark those of a ping); built once per suite (a CasADi function is immutable)."""
    import casadi

    from auv_envs.core.ops import casadi_ops

    ops = casadi_ops()
    before, given = casadi.SX.sym("state", _STATE_SIZE), casadi.SX.sym("given", 14)
    state = NavState(**{name: ([before[k] for k in range(part.start, part.stop)]
                               if kind is tuple else before[part.start])
                        for name, (part, kind) in _LAYOUT.items()})
    # Vectors the step only carries or selects stay columns (``ops.where`` of columns).
    state = state._replace(**{name: before[_LAYOUT[name][0]]
                              for name in ("pending", "fix", "dvl", "attitude", "rates")})
    truth = {"velocity": [given[k] for k in range(6)], "seabed_clearance": given[6],
             "euler": [given[7], given[8], given[9]], "position": [given[10], given[11],
                                                                  given[12]]}
    draws = SymbolicDraws("navigation")
    time = given[13]
    after = _SymbolicNavigation(sensors, seabed_z, dt).advance(state, truth, time, draws, ops)
    # The observation at ``time`` (Navigation.observation's values, in float64)
    seen = [vector[k] for vector in (after.dvl, after.attitude, after.rates) for k in range(3)]
    seen += [after.depth, *(after.fix[k] for k in range(3)),
             ops.where(after.fix_valid, time - after.fix_time, 0.0)]
    function = casadi.Function("navigation_step", [before, given, draws.column()],
                               [casadi.vertcat(*_flatten(after, lambda value: value), *seen,
                                               after.dvl_valid, after.fix_valid, time)],
                               {"cse": True})
    return function, draws
