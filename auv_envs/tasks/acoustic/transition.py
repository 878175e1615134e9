"""The acoustic tracking task's transition: one episode as :func:`reset` then :func:`step`.

An episode is an immutable :class:`EpisodeState`: its :class:`Plan` (the
carrier's route, the arm's sweep, the current, the clocks and the water,
drawn at reset), the current :class:`Block` of simulated and measured sample
periods, and the record of the agent's estimates. The static
:class:`AcousticParams` say which task it is. Both functions keep the protocol of
:mod:`auv_envs.core.task` and take a :class:`~auv_envs.core.ops.Backend`: the
arithmetic, the episode's random draws (NumPy ``Generator``'s interface) and the plant
(the carrier and arm in MuJoCo on the CPU, on MJX batched), a function of its state
``rig``: ``place(carrier, arm) -> rig`` (the rig at rest at those joint positions) and
``follow(rig, carrier_ref, carrier_vel, arm_ref, current, start) -> (rig, positions,
velocities)`` (the source's positions and velocities, (count, 3) each, at sample periods
``start``, ``start + 1``, ...: the rig moved on one period towards each row of
references, in each row's current). The start draw, the step's order (score the
estimate, move on one period, measure the next block when this one is served), the
reward, the end (an episode never terminates: it is truncated at its horizon), the
observations, the step's metrics, ``info`` and the episode summary exist here only;
:class:`auv_envs.tasks.acoustic.env.AcousticTrackingTask` is the task
on the CPU around them, which the one Gymnasium env runs (it renders and computes the bound).

The agent's estimates do not act on the physics, so the physics runs and the
measurements are drawn in blocks of :data:`BLOCK` sample periods, vectorised
over the block, and served one period per step: the same as stepping one
period at a time (the blocks are a computational device, not a change of
model) and many times faster. The draws come in the order the environment
has always made them, so its episodes are the released ones, bit for bit.

The same functions run on JAX arrays (:mod:`auv_envs.tasks.acoustic.jax_task`):
with ``ops`` :func:`~auv_envs.core.ops.jax_ops`, a JAX key's draws and the rig on MJX,
whose plant declares blocks of one period (every step simulates its own period, so the
state keeps fixed shapes) and no record of the estimates: the plant's ``block``,
``record`` and ``noise_draws`` (:mod:`auv_envs.tasks.acoustic.plant`).

On the CPU the record of the estimates and truths is a :class:`Trail`, append-only and
persistent: a step's state has one more row than the last's, and the last's stays as it
was, without a copy of the record per step.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np

from auv_envs import metrics
from auv_envs.core.acoustics import HydrophoneArray, Measurements
from auv_envs.core.ops import FLOATS, Backend
from auv_envs.core.task import Transition
from auv_envs.tasks.acoustic.plant import BLOCK  # noqa: F401  (its home before the plant's)

#: The reward's terms, in the order they sum (each reported as ``info["reward_<term>"]``).
REWARD_TERMS = ("estimate",)
#: The metrics of every step that are numbers (:func:`scores`'s keys).
STEP_METRICS = ("estimate_error", "running_rmse", "tracked", "is_success")
#: Current speed ranges in m/s ([GMPHD] §3.4's disturbance levels).
DISTURBANCES = {"low": (0.05, 0.15), "medium": (0.16, 0.30), "high": (0.31, 0.50)}
#: [GMPHD] Table 1: the five static end-effector positions (tank frame, m).
STATIC_POINTS = (
    (50.0, 102.0, -10.0),
    (170.0, 234.0, -15.5),
    (215.0, 236.0, -12.0),
    (289.0, 245.0, -8.0),
    (47.0, 251.0, -20.0),
)
#: TCFE ([GMPHD] §3.4): the entropy of the lengths of the estimate's consecutive
#: differences in bins of this width (m). ``tcfe`` is the paper's literal definition (first
#: differences), which also bins the end effector's own speed; ``tcfe_fluctuation`` uses
#: second differences, which the true motion leaves at 0 (measured: ``CHANGELOG.md``).
TCFE_BIN_WIDTH = 0.01
#: Source positions kept from before a block for the propagation delay (0.64 s at 100 Hz:
#: sound crosses the tank's 424 m diagonal in 0.28 s).
HISTORY = 64
#: The arm's nominal joint posture (rad): the source about 3.5 m ahead of
#: and 0.9 m below the carrier's centre.
NOMINAL_POSTURE = (0.0, 0.6, -1.2, 0.0, 0.6, 0.0)
#: Carrier route limits (m): keeps the end effector inside the work area
#: x, y in [40, 295], z in [-25, -5].
ROUTE_XY = (45.0, 285.0)
ROUTE_Z = (-20.0, -8.0)
CARRIER_SPEED = (0.2, 0.8)


@dataclasses.dataclass(frozen=True)
class AcousticParams:
    """What makes an acoustic tracking task this one; fixed for the environment's life.

    Attributes:
        obs_mode: ``"state"`` or ``"measurements"``.
        trajectory: ``"dynamic"`` or ``"static"``; ``static_point`` 1-5 or None (drawn).
        current_range: the current's speed range, m/s (:data:`DISTURBANCES`).
        dt: the sample period, s (one step). horizon: steps of an episode.
        array: the :class:`~auv_envs.core.acoustics.HydrophoneArray` (its model draws
            the measurements).
        source_offset: (3,) the source relative to the carrier at yaw 0 in
            :data:`NOMINAL_POSTURE` (places the static points).
        error_clip, track_gate, success_radius: m (the reward's clip, the tracked
            gate, the success radius of the running RMSE).
        draw_detections: whether the blocks draw the detections (and the nuisance
            behind them: wander, fading, node states); without them a block holds the
            source's motion only, which is all the ``state`` observation and the reward
            read.
        planner: ``"segments"`` (:func:`draw_route`) or ``"tabulated"``
            (:func:`plan_route`, ``AcousticTracking-v0``/``-v1``).
    """

    obs_mode: str
    trajectory: str
    static_point: int | None
    current_range: tuple
    dt: float
    horizon: int
    array: HydrophoneArray
    source_offset: Any
    error_clip: float
    track_gate: float
    success_radius: float
    draw_detections: bool = True
    planner: str = "segments"


class Plan(NamedTuple):
    """An episode's draws at reset, fixed through it: the carrier's route (a
    :class:`Route`, :class:`StillRoute` or :class:`TabulatedRoute`), the arm's
    :class:`Sweep`, the current's :class:`Flow`, the nodes' clock offsets (N,), the
    water's true sound speed (m/s) and the static point (None on a dynamic route).
    :func:`references` gives the servos' references and the current at any periods."""

    route: Any
    sweep: Sweep
    flow: Flow
    clock_offsets: Any
    sound_speed: Any
    static_point: Any


class Block(NamedTuple):
    """Sample periods ``[start, start + B)`` simulated and measured.

    ``positions``/``velocities`` (B, 3) the source's; ``current`` (B, 3) the
    current at those periods; ``heard`` what the nodes
    heard (propagation delay); ``fades`` (B, Q, N) dB and ``nodes`` (B, N)
    which work (None when off); ``measurements`` the detection sets (None, as
    ``heard``, when the task draws no detections). What
    the next block continues: ``history`` (<= :data:`HISTORY`, 3) source
    positions, ``wander`` (N,) and ``fading`` (Q, N) at the last period.
    """

    start: int
    positions: np.ndarray
    velocities: np.ndarray
    current: np.ndarray
    heard: np.ndarray
    fades: np.ndarray | None
    nodes: np.ndarray | None
    measurements: Measurements
    history: np.ndarray | None
    wander: np.ndarray | None
    fading: np.ndarray | None


class Assessment(NamedTuple):
    """A step's judgement: the reward terms and whether the episode ended (never: it is
    truncated at its horizon)."""

    terms: dict
    terminated: Any


class Trail:
    """Rows recorded one per step in several series (an episode's estimates and truths),
    persistent: :meth:`append` returns a trail one step longer and leaves this one as it
    was. Trails of one episode share a buffer, each reading its first ``length`` steps; an
    append writes the step after them, which no trail reads, and copies the buffer first
    when another trail has already grown it past this one (a state stepped twice), so no
    trail's rows ever change."""

    __slots__ = ("_buffer", "length", "_filled")

    def __init__(self, buffer: np.ndarray, length: int, filled: list):
        #: (capacity, series, width) rows, NaN beyond the written ones.
        self._buffer = buffer
        #: Steps recorded.
        self.length = length
        #: ``[steps written to the buffer]``, shared by the trails on it.
        self._filled = filled

    @classmethod
    def empty(cls, capacity: int, series: int, width: int) -> Trail:
        """A trail of no steps, room for ``capacity`` steps of ``series`` rows of ``width``."""
        return cls(np.full((capacity, series, width), np.nan), 0, [0])

    def append(self, *rows) -> Trail:
        """This trail with one more step: ``rows``, one per series."""
        buffer, filled, n = self._buffer, self._filled, self.length
        if filled[0] != n:  # another trail grew the buffer past this one
            buffer, filled = buffer.copy(), [n]
        step = buffer[n]
        for k, row in enumerate(rows):
            step[k] = row
        filled[0] = n + 1
        return Trail(buffer, n + 1, filled)

    def series(self, k: int) -> np.ndarray:
        """Series ``k``'s recorded rows, (length, width), a read-only view."""
        view = self._buffer[: self.length, k]
        view.flags.writeable = False
        return view


class EpisodeState(NamedTuple):
    """Everything an episode changes besides the plant: the plan, the block being
    served, the steps taken, the sum of squared errors and the record of the estimates and
    the truths they were scored against (a :class:`Trail` of the two series; None where the
    plant keeps no record)."""

    plan: Plan
    block: Block
    steps: int
    squared_error_sum: float
    record: Trail | None

    @property
    def estimates(self) -> np.ndarray:
        """The estimates so far, (steps, 3), read-only (a plant with a ``record`` only)."""
        return self.record.series(0)

    @property
    def truths(self) -> np.ndarray:
        """The truths the estimates were scored against, (steps, 3), read-only."""
        return self.record.series(1)


# ------------------------------------------------------------------ the plan
def plan_route(rng: np.random.Generator, n: int, dt: float):
    """A carrier route of ``n`` samples: straight segments, curves and pauses.

    Segment kinds come from shuffled bags of two straights, two curves and
    one pause, so every route mixes all three: straight (4-12 s), curve
    (6-15 s, turning 30-120 deg), pause (1.5-5 s); speeds
    uniform in ``CARRIER_SPEED`` and a slow climb or descent (|w| <= 0.05 m/s)
    while moving. Near the route limits a segment heads back towards the
    centre. Returns (reference (n, 4) of x, y, z, yaw and its rate (n, 4)).
    """
    lo, hi = ROUTE_XY
    centre = 0.5 * (lo + hi)
    speed = np.zeros(n)
    turn = np.zeros(n)
    climb = np.zeros(n)
    heading0 = np.zeros(n)
    position = np.array([rng.uniform(lo + 20, hi - 20), rng.uniform(lo + 20, hi - 20),
                         rng.uniform(*ROUTE_Z)])
    start = position.copy()
    heading = rng.uniform(-math.pi, math.pi)
    i = 0
    bag: list[int] = []
    while i < n:
        if not bag:
            bag = list(rng.permutation((0, 0, 1, 1, 2)))
        kind = bag.pop()
        duration = (rng.uniform(4, 12), rng.uniform(6, 15), rng.uniform(1.5, 5))[kind]
        count = min(n - i, max(1, int(round(duration / dt))))
        v = rng.uniform(*CARRIER_SPEED) if kind != 2 else 0.0
        w = 0.0
        home = math.atan2(centre - position[1], centre - position[0])
        near_edge = np.any(position[:2] < lo + 25) or np.any(position[:2] > hi - 25)
        if near_edge and math.cos(heading - home) < 0.5:
            heading = home + rng.uniform(-0.5, 0.5)
        if kind == 1:
            sign = rng.choice((-1.0, 1.0))
            w = sign * rng.uniform(math.pi / 6, 2 * math.pi / 3) / (count * dt)
        vz = rng.uniform(-0.05, 0.05) if v > 0 else 0.0
        if not ROUTE_Z[0] + 1 < position[2] < ROUTE_Z[1] - 1:
            vz = math.copysign(abs(vz), 0.5 * sum(ROUTE_Z) - position[2])
        speed[i : i + count], turn[i : i + count], climb[i : i + count] = v, w, vz
        heading0[i : i + count] = heading + w * dt * np.arange(count)
        heading += w * dt * count
        travel = heading0[i : i + count]
        position = position + dt * np.array(
            [np.sum(v * np.cos(travel)), np.sum(v * np.sin(travel)), vz * count]
        )
        i += count
    velocity = np.stack([speed * np.cos(heading0), speed * np.sin(heading0), climb, turn], 1)
    reference = np.empty((n, 4))
    reference[0, :3] = start
    reference[1:, :3] = start + np.cumsum(velocity[:-1, :3] * dt, axis=0)
    reference[:, 3] = heading0
    reference[:, 0:2] = np.clip(reference[:, 0:2], lo, hi)
    reference[:, 2] = np.clip(reference[:, 2], *ROUTE_Z)
    return reference, velocity


class TabulatedRoute(NamedTuple):
    """A route as :func:`plan_route` draws it (``AcousticTracking-v0``/``-v1``): the
    carrier's reference (n, 4) and its rate (n, 4) at every period."""

    reference: np.ndarray
    velocity: np.ndarray

    def at(self, rows, dt: float, xp):
        return self.reference[rows], self.velocity[rows]


class StillRoute(NamedTuple):
    """The carrier held at ``position`` (3,), yaw 0 (the static trajectories)."""

    position: Any

    def at(self, rows, dt: float, xp):
        shape = xp.shape(rows)
        reference = xp.broadcast_to(xp.append(self.position, 0.0 * self.position[0]),
                                    (*shape, 4))
        return reference, xp.zeros((*shape, 4), reference.dtype)


class Route(NamedTuple):
    """A route as :func:`draw_route` draws it: (S,) segments of constant speed, turn
    rate and climb, segment ``s`` starting at period ``start[s]`` at ``origin[s]`` (3,)
    heading ``heading[s]`` (segments past the horizon are never reached)."""

    start: Any
    heading: Any
    speed: Any
    turn: Any
    climb: Any
    origin: Any

    def at(self, rows, dt: float, xp):
        """The reference (..., 4) x, y, z, yaw and its rate (..., 4) at periods ``rows``:
        the segment's start plus its travel so far, in closed form
        (:func:`_turn_sums`), clipped to the route's limits."""
        s = xp.searchsorted(self.start, rows, side="right") - 1
        m = rows - self.start[s]
        heading, speed, turn, climb = (self.heading[s], self.speed[s], self.turn[s],
                                       self.climb[s])
        along_x, along_y = _turn_sums(heading, turn * dt, m, xp)
        origin = self.origin[s]
        yaw = heading + turn * dt * m
        reference = xp.stack([
            xp.clip(origin[..., 0] + dt * speed * along_x, *ROUTE_XY),
            xp.clip(origin[..., 1] + dt * speed * along_y, *ROUTE_XY),
            xp.clip(origin[..., 2] + dt * climb * m, *ROUTE_Z),
            yaw,
        ], -1)
        velocity = xp.stack([speed * xp.cos(yaw), speed * xp.sin(yaw), climb, turn], -1)
        return reference, velocity


def _turn_sums(heading, step, count, xp):
    """``sum_{j < count} (cos, sin)(heading + step j)``: the sums' closed form
    ``sin(count step / 2) / sin(step / 2)`` times the (cos, sin) of the middle heading,
    ``count`` times those of ``heading`` when ``step`` is 0."""
    straight = step == 0.0
    half = 0.5 * xp.where(straight, 1.0, step)
    scale = xp.where(straight, count, xp.sin(count * half) / xp.sin(half))
    middle = heading + 0.5 * xp.where(straight, 0.0, step) * (count - 1)
    return scale * xp.cos(middle), scale * xp.sin(middle)


#: A route's segment kinds (straight, curve, pause) come from shuffled bags of these.
ROUTE_BAG = (0, 0, 1, 1, 2)
#: Each kind's duration range, s.
SEGMENT_SECONDS = ((4.0, 12.0), (6.0, 15.0), (1.5, 5.0))


def route_segments(n: int, dt: float) -> int:
    """How many segments :func:`draw_route` draws for ``n`` periods: whole bags, enough
    for a route of the shortest segments."""
    shortest_bag = sum(SEGMENT_SECONDS[kind][0] for kind in ROUTE_BAG) / dt
    return len(ROUTE_BAG) * math.ceil(n / shortest_bag)


def draw_route(draws, n: int, dt: float, ops) -> Route:
    """A carrier route of ``n`` periods: straight segments, curves and pauses (the model
    of :func:`plan_route`, its draws made up front, so that the same code draws on NumPy
    and under JAX; ``AcousticTracking-v2``).

    Segment kinds come from shuffled bags of two straights, two curves and one pause:
    straight (4-12 s), curve (6-15 s, turning 30-120 deg), pause (1.5-5 s); speeds
    uniform in ``CARRIER_SPEED`` and a slow climb or descent (|w| <= 0.05 m/s) while
    moving, towards mid-depth near the depth limits. Near the route's edges a
    segment heads back towards the centre. Draws, in order: the start, the heading, the
    bags, then per segment (:func:`route_segments` of them) three durations, the speed,
    the turn-back heading, the turn's sign and angle and the climb.
    """
    xp = ops.xp
    lo, hi = ROUTE_XY
    count = route_segments(n, dt)
    start = draws.uniform(xp.asarray([lo + 20, lo + 20, ROUTE_Z[0]]),
                          xp.asarray([hi - 20, hi - 20, ROUTE_Z[1]]), 3)
    heading = draws.uniform(-math.pi, math.pi)
    kinds = xp.concatenate([draws.permutation(xp.asarray(ROUTE_BAG))
                            for _ in range(count // len(ROUTE_BAG))])
    low = xp.asarray([[*(s[0] for s in SEGMENT_SECONDS), CARRIER_SPEED[0], -0.5, 0.0,
                       math.pi / 6, -0.05]])
    high = xp.asarray([[*(s[1] for s in SEGMENT_SECONDS), CARRIER_SPEED[1], 0.5, 1.0,
                        2 * math.pi / 3, 0.05]])
    uniforms = draws.uniform(low, high, (count, low.shape[1]))
    (_, _, _), rows = ops.scan(lambda carry, row: _segment(carry, row, dt, xp),
                               (start, heading, 0), (kinds, uniforms))
    return Route(*rows)


def _segment(carry, row, dt: float, xp):
    """One segment of :func:`draw_route`: from ``carry`` (the position (3,), heading and
    period it starts at) and ``row`` (its kind and its uniform draws), the segment's
    :class:`Route` row and the next segment's ``carry``."""
    position, heading, start = carry
    kind, (*durations, speed, back, side, angle, climb) = row[0], row[1]
    lo, hi = ROUTE_XY
    centre = 0.5 * (lo + hi)
    count = xp.maximum(1, xp.round(xp.stack(durations)[kind] / dt).astype(int))
    speed = xp.where(kind == 2, 0.0, speed)
    home = xp.arctan2(centre - position[1], centre - position[0])
    near_edge = xp.any(position[:2] < lo + 25) | xp.any(position[:2] > hi - 25)
    heading = xp.where(near_edge & (xp.cos(heading - home) < 0.5), home + back, heading)
    turn = xp.where(kind == 1, xp.where(side < 0.5, -1.0, 1.0) * angle / (count * dt), 0.0)
    climb = xp.where(speed > 0, climb, 0.0)
    level = (ROUTE_Z[0] + 1 < position[2]) & (position[2] < ROUTE_Z[1] - 1)
    climb = xp.where(level, climb, xp.copysign(xp.abs(climb), 0.5 * sum(ROUTE_Z) - position[2]))
    along_x, along_y = _turn_sums(heading, turn * dt, count, xp)
    travelled = position + dt * xp.stack([speed * along_x, speed * along_y, climb * count])
    return ((travelled, heading + turn * dt * count, start + count),
            (start, heading, speed, turn, climb, position))


class Sweep(NamedTuple):
    """The arm's joint references: ``NOMINAL_POSTURE + amplitude (sin(2 pi t / period +
    phase) - sin(phase))`` per joint ((6,) each; amplitude 0 holds the posture)."""

    amplitude: Any
    period: Any
    phase: Any

    def at(self, t, xp):
        """The references (..., 6) at times ``t`` (..., 1) s."""
        return xp.asarray(NOMINAL_POSTURE) + self.amplitude * (
            xp.sin(2 * np.pi * t / self.period + self.phase) - xp.sin(self.phase))


def draw_sweep(draws) -> Sweep:
    """Amplitudes 0.1-0.35 rad (first three joints), 0.05-0.2 rad (wrist), periods
    12-40 s, phases uniform."""
    amplitude = draws.uniform(np.array([0.1] * 3 + [0.05] * 3),
                              np.array([0.35] * 3 + [0.2] * 3), 6)
    return Sweep(amplitude, draws.uniform(12.0, 40.0, 6), draws.uniform(0, 2 * np.pi, 6))


class Flow(NamedTuple):
    """A horizontal current: speed ``lo + (hi - lo) (1 + sin(2 pi t / speed_period +
    speed_phase)) / 2``, direction ``direction + 0.3 sin(2 pi t / veer_period +
    veer_phase)``."""

    low: float
    high: float
    speed_period: Any
    speed_phase: Any
    direction: Any
    veer_period: Any
    veer_phase: Any

    def at(self, t, xp):
        """The current (..., 3) m/s at times ``t`` (...) s."""
        speed = self.low + (self.high - self.low) * 0.5 * (
            1 + xp.sin(2 * np.pi * t / self.speed_period + self.speed_phase))
        direction = self.direction + 0.3 * xp.sin(2 * np.pi * t / self.veer_period
                                                  + self.veer_phase)
        return xp.stack([speed * xp.cos(direction), speed * xp.sin(direction),
                         0.0 * speed], -1)


def draw_flow(draws, speed_range) -> Flow:
    """The current's periods (speed 20-60 s, direction 30-90 s), phases and mean
    direction, drawn in that order."""
    speed_period = draws.uniform(20, 60)
    speed_phase = draws.uniform(0, 2 * np.pi)
    direction = draws.uniform(-np.pi, np.pi)
    veer_period = draws.uniform(30, 90)
    return Flow(float(speed_range[0]), float(speed_range[1]), speed_period, speed_phase,
                direction, veer_period, draws.uniform(0, 2 * np.pi))


def draw_plan(params: AcousticParams, draws, ops) -> Plan:
    """The episode's plan. Draws, in order: the route (:func:`draw_route`, or
    :func:`plan_route` with ``params.planner == "tabulated"``) and the arm's sweep, or
    the static point when drawn; the current (:func:`draw_flow`); the clock offsets;
    the sound speed."""
    xp = ops.xp
    n = params.horizon + 1
    static_point = None
    if params.trajectory == "dynamic":
        if params.planner == "tabulated":
            route = TabulatedRoute(*plan_route(draws, n, params.dt))
        else:
            route = draw_route(draws, n, params.dt, ops)
        sweep = draw_sweep(draws)
    else:
        static_point = params.static_point or draws.integers(1, len(STATIC_POINTS) + 1)
        points = xp.asarray(STATIC_POINTS) - xp.asarray(params.source_offset)
        route = StillRoute(points[static_point - 1])
        zeros = np.zeros(6)
        sweep = Sweep(zeros, np.ones(6), zeros)
    flow = draw_flow(draws, params.current_range)
    array = params.array
    clock_offsets = array.draw_clock_offsets(draws, xp)
    sound_speed = array.draw_sound_speed(draws, xp)
    return Plan(route, sweep, flow, clock_offsets, sound_speed, static_point)


def references(params: AcousticParams, plan: Plan, rows, xp):
    """The carrier's reference and rate (..., 4), the arm's joint references (..., 6) and
    the current (..., 3) at periods ``rows`` (an integer array)."""
    t = params.dt * rows
    carrier_ref, carrier_vel = plan.route.at(rows, params.dt, xp)
    return carrier_ref, carrier_vel, plan.sweep.at(t[..., None], xp), plan.flow.at(t, xp)


# ------------------------------------------------------------------ blocks
def simulate_block(params: AcousticParams, plan: Plan, previous: Block | None, start, rig,
                   backend: Backend) -> tuple[Any, Block]:
    """Advance the plant from ``rig`` over sample periods ``[start, start + plant.block)``
    (to the horizon) and measure them, continuing ``previous`` (None at reset):
    ``(rig, block)``."""
    ops, draws, plant = backend
    xp = ops.xp
    count = 1 if plant.block == 1 else min(plant.block, params.horizon + 1 - start)
    # The block's periods and the one before it (whose current moves the rig into the first).
    rows = xp.maximum(xp.arange(count + 1) + (start - 1), 0)
    carrier_ref, carrier_vel, arm_ref, current = references(params, plan, rows, xp)
    rig, positions, velocities = plant.follow(rig, carrier_ref[1:], carrier_vel[1:],
                                              arm_ref[1:], current[:-1], start)
    current = current[1:]
    start = ops.integer(start)  # the Block's, a typed scalar (the plant reads the literal 0)
    if not params.draw_detections:
        return rig, Block(start, positions, velocities, current, None, None, None, None, None,
                          None, None)
    array = params.array
    history = wander = fading = nodes = None
    if previous is not None:
        history, wander, fading = previous.history, previous.wander, previous.fading
        nodes = previous.nodes
    heard = positions
    if array.config.propagation_delay:
        if history is None and plant.block == 1:
            # A fixed-size history from the start (JAX's shapes): the first position
            # repeated, the source held still before the episode, as emission_positions
            # clamps earlier times to a track's first row.
            history = xp.broadcast_to(positions[:1], (HISTORY, 3))
        track = positions if history is None else xp.concatenate([history, positions])
        heard = array.emission_positions(track, count, params.dt, plan.sound_speed, xp=xp)
        history = track[-HISTORY:]
    wanders = array.draw_wander(draws, count, wander, xp=xp)
    if wanders is not None:
        wander = wanders[-1]
    fades = array.draw_fading(draws, count, fading, xp=xp)
    if fades is not None:
        fading = fades[-1]
    nodes = array.draw_node_states(draws, count, None if nodes is None else nodes[-1], xp=xp)
    measurements = array.measure(
        draws, heard, plan.clock_offsets, xp.linalg.norm(current, axis=1), plan.sound_speed,
        wanders, fades, nodes, noise_draws=plant.noise_draws, xp=xp,
    )
    return rig, Block(start, positions, velocities, current, heard, fades, nodes,
                      measurements, history, wander, fading)


# ------------------------------------------------------------------ reset and step
def reset(params: AcousticParams, backend: Backend) -> Transition:
    """A new episode (:class:`~auv_envs.core.task.Transition`, no judgement); its truth is
    ``{"k": 0, "error": NaN}`` (nothing estimated yet)."""
    return begin(params, draw_plan(params, backend.draws, backend.ops), backend)


def begin(params: AcousticParams, plan: Plan, backend: Backend) -> Transition:
    """The episode of ``plan`` at its start: :func:`reset` after the plan's draws."""
    ops = backend.ops
    xp = ops.xp
    carrier, _, arm, _ = references(params, plan, xp.asarray(0), xp)
    rig, block = simulate_block(params, plan, None, 0, backend.plant.place(carrier, arm),
                                backend)
    state = EpisodeState(plan=plan, block=block, steps=ops.integer(0),
                         squared_error_sum=ops.real(0.0),
                         record=(Trail.empty(params.horizon, 2, 3) if backend.plant.record
                                 else None))
    now = {"k": state.steps, "error": ops.real(float("nan"))}
    return Transition(rig, state, now, observe(params, state, xp))


def step(params: AcousticParams, rig, state: EpisodeState, action,
         backend: Backend) -> Transition:
    """Score the estimate ``action`` (the (3,) array already checked) against the truth
    at the last observation, then move the rig at ``rig`` on one sample period; the
    judgement is an :class:`Assessment` (an episode never terminates; it is truncated at
    its horizon)."""
    ops = backend.ops
    k = state.steps  # the estimate is scored against the truth at observation k
    block = state.block
    position = block.positions[k - block.start]
    difference = action - position
    error = ops.sqrt(difference.dot(difference))  # np.linalg.norm's arithmetic, sooner
    plant = backend.plant
    record = state.record.append(action, position) if plant.record else state.record
    state = state._replace(steps=k + 1, squared_error_sum=state.squared_error_sum + error * error,
                           record=record)
    if plant.block == 1 or state.steps - block.start >= plant.block:
        rig, block = simulate_block(params, state.plan, block, state.steps, rig, backend)
        state = state._replace(block=block)
    now = {"k": state.steps, "error": error}
    terms = {"estimate": -ops.minimum(error, params.error_clip) / params.error_clip}
    return Transition(rig, state, now, observe(params, state, ops.xp),
                      Assessment(terms, ops.boolean(False)))


# ------------------------------------------------------------------ what is seen
def observe(params: AcousticParams, state: EpisodeState, xp):
    """The ``state`` or ``measurements`` observation at the state's step."""
    k = state.steps
    block = state.block
    j = k - block.start
    if params.obs_mode == "state":
        return xp.concatenate([block.positions[j], block.velocities[j],
                               block.current[j]]).astype(xp.float32)
    m = block.measurements
    n = m.n_nodes
    values = m.values[j].copy()  # one copy, then views of it
    obs = {
        "tdoa": values[..., : n - 1],
        "azimuth": values[..., n - 1 : 2 * n - 1],
        "elevation": values[..., 2 * n - 1 :],
        "mask": m.mask[j].astype(xp.int8),
    }
    if block.nodes is not None:
        obs["node_mask"] = block.nodes[j].astype(xp.int8)
    return obs


def info(params: AcousticParams, state: EpisodeState, now: dict) -> dict:
    """The step's ``info`` without the reward terms (see the environment's docstring)."""
    block = state.block
    k = now["k"]
    j = k - block.start
    out = {
        **scores(params, state, now, FLOATS),
        "true_position": block.positions[j].copy(),
        "true_velocity": block.velocities[j].copy(),
        "current": block.current[j].copy(),
        "time": k * params.dt,
    }
    if block.measurements is not None:
        out["detection_origin"] = block.measurements.origin[j].copy()
    if block.nodes is not None:
        out["nodes_working"] = int(np.count_nonzero(block.nodes[j]))
    return out


def scores(params: AcousticParams, state: EpisodeState, now: dict, ops) -> dict:
    """The step's scores: the estimate's error (m), the running RMSE over the steps so
    far (NaN before the first), whether the estimate is within the track gate and the
    running RMSE within the success radius."""
    k, error = now["k"], now["error"]
    mean = state.squared_error_sum / ops.maximum(k, 1)
    rmse = ops.where(k > 0, ops.sqrt(mean), float("nan"))
    return {
        "estimate_error": error,
        "running_rmse": rmse,
        "tracked": error <= params.track_gate,
        "is_success": rmse <= params.success_radius,
    }


def summary(params: AcousticParams, state: EpisodeState) -> dict:
    """The episode's summary (``info["episode_metrics"]`` at its end), from the record
    of estimates and truths (the CPU plant's ``record``)."""
    est, truth = state.estimates, state.truths
    errors = metrics.position_errors(est, truth)
    rmse = metrics.rmse(est, truth)
    # One estimate per step: the track is "on" the source while within the
    # gate (label 0) and lost otherwise; TFC counts the re-acquisitions.
    labels = np.where(errors <= params.track_gate, 0, metrics.NO_TRACK)
    out = {
        "rmse": rmse,
        "max_error": metrics.max_error(est, truth),
        # The systematic part of the error: rmse^2 = error_bias^2 + (random part)^2.
        "error_bias": float(np.linalg.norm(np.mean(est - truth, axis=0))),
        "tfc": metrics.track_fragmentation_count(labels),
        # [GMPHD] §3.4's TCFE as written (first differences), and the same
        # entropy on second differences, which the true motion leaves at 0.
        "tcfe": metrics.tcfe(est, bin_width=TCFE_BIN_WIDTH),
        "tcfe_fluctuation": metrics.tcfe(est, bin_width=TCFE_BIN_WIDTH, order=2),
        # OSPA between singleton sets {estimate} and {truth} (p = 1, c =
        # error_clip) is min(error, c) per step.
        "mean_ospa": float(np.mean(np.minimum(errors, params.error_clip))),
        "steps": state.steps,
        "success": bool(rmse <= params.success_radius),
    }
    if state.plan.static_point is not None:
        out["static_point"] = int(state.plan.static_point)
    return out
