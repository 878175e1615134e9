"""Sea surface effects (wave heave, wash-over crests, floating look-alikes, occlusion)
and a slowly varying ocean current.

Everything here is kinematic and analytic (no ray casting): a wash-over crest
is a world-axis-aligned slab of water and a point is hidden from a camera when
the segment between them crosses the slab, which :func:`segments_cross_box`
decides with the slab method in a few vectorised operations.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from auv_envs.core.ops import FLOATS
from auv_envs.core.pytree import dataclass_pytree


@dataclass_pytree(meta=("sweep", "overtop", "half_size"))
@dataclasses.dataclass(frozen=True)
class WashOver:
    """Periodic crests that sweep along a floating body and hide its top.

    An event starts every ``period`` seconds (first at ``phase``), lasts
    ``duration`` seconds, during which a slab of water with half sizes
    ``half_size`` travels along world x from ``-sweep`` to ``+sweep`` relative
    to the body's centre, its top ``overtop`` metres above the body's top.
    """

    period: float
    duration: float
    phase: float
    sweep: float = 1.3
    overtop: float = 0.03
    half_size: tuple[float, float, float] = (0.3, 0.8, 0.06)

    def offset(self, t: float) -> float | None:
        """Crest x offset from the body centre at time ``t``; None between events."""
        active, shift = self.shift(t)
        return shift if active else None

    def shift(self, t) -> tuple:
        """``(active, offset)`` at time ``t``: whether an event is on, and the crest's x
        offset from the body centre were it on (Python floats, or arrays elementwise)."""
        since = (t - self.phase) % self.period
        return since < self.duration, -self.sweep + 2.0 * self.sweep * since / self.duration

    @classmethod
    def sample(
        cls,
        rng: np.random.Generator,
        period: tuple[float, float] = (3.0, 5.0),
        duration: tuple[float, float] = (1.2, 2.0),
    ) -> WashOver:
        """Draw an event schedule from the episode's generator."""
        p = rng.uniform(*period)
        return cls(period=p, duration=rng.uniform(*duration), phase=rng.uniform(0.0, p))


@dataclass_pytree()
@dataclasses.dataclass(frozen=True)
class FloatingAnalog:
    """A look-alike floating object that drifts beside the target.

    Its centre is at ``target + (dx0 + drift t, dy, 0)`` on the surface,
    heaving with the local wave plus ``heave_lag`` of phase.
    """

    dx0: float
    dy: float
    drift: float
    yaw: float
    heave_lag: float

    @classmethod
    def sample(cls, rng: np.random.Generator, side: float) -> FloatingAnalog:
        """Draw one analog on the ``side`` (+1 port, -1 starboard) of the target."""
        return cls(
            dx0=rng.uniform(-0.8, 0.8),
            dy=side * rng.uniform(0.38, 0.5),
            drift=rng.uniform(-0.06, 0.06),
            yaw=rng.uniform(-0.5, 0.5),
            heave_lag=rng.uniform(-0.5, 0.5),
        )


def segments_cross_box(starts, ends, center, half_size, xp):
    """Whether each segment ``starts[i] -> ends[i]`` crosses an axis-aligned box.

    Args:
        starts, ends: (..., 3) segment end points (broadcast together).
        center, half_size: the box, (3,) each.
        xp: the array module (NumPy, or ``jax.numpy`` elementwise under ``vmap``).

    Returns:
        Boolean array of the broadcast leading shape.
    """
    lo = xp.asarray(center) - xp.asarray(half_size)
    hi = xp.asarray(center) + xp.asarray(half_size)
    d = ends - starts
    # An axis parallel to the segment: inside the slab => (-inf, inf), outside => empty.
    parallel = d == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / xp.where(parallel, 1.0, d)
        t0 = (lo - starts) * inv
        t1 = (hi - starts) * inv
    near = xp.minimum(t0, t1)
    far = xp.maximum(t0, t1)
    inside = (starts >= lo) & (starts <= hi)
    near = xp.where(parallel, xp.where(inside, -np.inf, np.inf), near)
    far = xp.where(parallel, xp.where(inside, np.inf, -np.inf), far)
    t_enter = xp.maximum(near.max(axis=-1), 0.0)
    t_exit = xp.minimum(far.min(axis=-1), 1.0)
    return t_enter <= t_exit


def heave(t, amplitude, omega, phase, ops) -> tuple:
    """Sinusoidal heave ([LTAT], motion model) and its rate at time ``t`` (Python floats,
    or any backend of :mod:`auv_envs.core.ops`)."""
    arg = omega * t + phase
    return amplitude * ops.sin(arg), amplitude * omega * ops.cos(arg)


@dataclasses.dataclass(frozen=True)
class GaussMarkovCurrent:
    """A slowly varying horizontal ocean current: speed and direction, each a
    first-order Gauss–Markov process.

    Fossen (2011), *Handbook of Marine Craft Hydrodynamics and Motion Control*,
    ch. 8 (ocean currents): the current speed obeys
    ``dV/dt + mu V = w`` with ``w`` Gaussian white noise, saturated to a
    physical range; the direction is modelled the same way. Here each process
    relaxes towards its mean (an Ornstein–Uhlenbeck process, Fossen's model
    about a mean value) and is sampled *exactly* at the control period:

        x[k+1] = mean + a (x[k] - mean) + s sqrt(1 - a^2) e[k],   a = exp(-dt / T)

    with ``e[k] ~ N(0, 1)``, so its stationary standard deviation is ``s`` and
    its autocorrelation at lag ``dt`` is ``a`` whatever ``dt``. The speed is
    then saturated to ``[0, max_speed]``.

    Attributes:
        speed_std: stationary standard deviation of the speed, m/s.
        direction_std_deg: stationary standard deviation of the direction, deg.
        time_constant: correlation time ``T = 1 / mu`` of both processes, s.
        max_speed: upper saturation of the speed, m/s.
    """

    speed_std: float = 0.0
    direction_std_deg: float = 0.0
    time_constant: float = 60.0
    max_speed: float = 1.5

    def __post_init__(self):
        for name in ("speed_std", "direction_std_deg", "time_constant", "max_speed"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if self.time_constant == 0:
            raise ValueError("time_constant must be positive")

    @property
    def active(self) -> bool:
        """Whether the current varies at all (otherwise it stays at its mean, no draws)."""
        return self.speed_std > 0 or self.direction_std_deg > 0

    def start(self, mean_speed: float, mean_direction: float, rng: np.random.Generator,
              ops) -> tuple[float, float]:
        """``(speed, direction)`` drawn from the stationary distribution (direction in rad);
        the means, drawing nothing, when the process is not :attr:`active`. ``rng``: the
        episode's draws (NumPy's ``Generator``, or a JAX key's with ``ops``)."""
        if not self.active:
            return min(max(mean_speed, 0.0), self.max_speed), mean_direction
        return self.start_from(mean_speed, mean_direction, rng.standard_normal(),
                               rng.standard_normal(), ops)

    def start_from(self, mean_speed, mean_direction, noise_speed, noise_direction,
                   ops) -> tuple:
        """:meth:`start` given its two standard normal draws (any backend of
        :mod:`auv_envs.core.ops`)."""
        speed = mean_speed + self.speed_std * noise_speed
        direction = mean_direction + math.radians(self.direction_std_deg) * noise_direction
        return ops.clip(speed, 0.0, self.max_speed), direction

    def advance(self, speed: float, direction: float, mean_speed: float, mean_direction: float,
                dt: float, rng: np.random.Generator, ops) -> tuple[float, float]:
        """The ``(speed, direction)`` one period ``dt`` later (exact discretisation)."""
        noise_speed, noise_direction = rng.standard_normal(2)
        return self.relax(speed, direction, mean_speed, mean_direction, dt, noise_speed,
                          noise_direction, ops)

    def relax(self, speed, direction, mean_speed, mean_direction, dt: float, noise_speed,
              noise_direction, ops) -> tuple:
        """:meth:`advance` given its two standard normal draws (any backend of
        :mod:`auv_envs.core.ops`)."""
        a = math.exp(-dt / self.time_constant)
        gain = math.sqrt(1.0 - a * a)
        speed = mean_speed + a * (speed - mean_speed) + self.speed_std * gain * noise_speed
        direction = (mean_direction + a * (direction - mean_direction)
                     + math.radians(self.direction_std_deg) * gain * noise_direction)
        return ops.clip(speed, 0.0, self.max_speed), direction


def current_vector(speed: float, direction: float) -> np.ndarray:
    """World-frame velocity (3) of a horizontal current flowing towards ``direction`` (rad)."""
    return np.array(current_components(speed, direction, FLOATS))


def current_components(speed, direction, ops) -> tuple:
    """:func:`current_vector`'s three components (any backend of :mod:`auv_envs.core.ops`)."""
    return speed * ops.cos(direction), speed * ops.sin(direction), 0.0
