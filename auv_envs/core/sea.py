"""Sea surface effects: wave heave, wash-over crests, floating look-alikes, occlusion.

Everything here is kinematic and analytic (no ray casting): a wash-over crest
is a world-axis-aligned slab of water and a point is hidden from a camera when
the segment between them crosses the slab, which :func:`segments_cross_box`
decides with the slab method in a few vectorised operations.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


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
        since = (t - self.phase) % self.period
        if since >= self.duration:
            return None
        return -self.sweep + 2.0 * self.sweep * since / self.duration

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


def segments_cross_box(starts: np.ndarray, ends: np.ndarray, center, half_size) -> np.ndarray:
    """Whether each segment ``starts[i] -> ends[i]`` crosses an axis-aligned box.

    Args:
        starts, ends: (..., 3) segment end points (broadcast together).
        center, half_size: the box, (3,) each.

    Returns:
        Boolean array of the broadcast leading shape.
    """
    lo = np.asarray(center) - half_size
    hi = np.asarray(center) + half_size
    d = ends - starts
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (lo - starts) * inv
        t1 = (hi - starts) * inv
    near = np.minimum(t0, t1)
    far = np.maximum(t0, t1)
    # An axis parallel to the segment: inside the slab => (-inf, inf), outside => empty.
    parallel = d == 0.0
    if parallel.any():
        inside = (starts >= lo) & (starts <= hi)
        near = np.where(parallel, np.where(inside, -np.inf, np.inf), near)
        far = np.where(parallel, np.where(inside, np.inf, -np.inf), far)
    t_enter = np.maximum(near.max(axis=-1), 0.0)
    t_exit = np.minimum(far.min(axis=-1), 1.0)
    return t_enter <= t_exit


def heave(t: float, amplitude: float, omega: float, phase: float) -> tuple[float, float]:
    """Sinusoidal heave (seed 000, motion model) and its rate at time ``t``."""
    arg = omega * t + phase
    return amplitude * math.sin(arg), amplitude * omega * math.cos(arg)
