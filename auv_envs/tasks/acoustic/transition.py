"""The acoustic tracking task's transition: one episode as :func:`reset` then :func:`step`.

An episode is an immutable :class:`EpisodeState`: its :class:`Plan` (the
carrier's route, the arm's sweep, the current, the clocks and the water,
drawn at reset), the current :class:`Block` of simulated and measured sample
periods, and the record of the agent's estimates. The static
:class:`AcousticParams` say which task it is. Both functions take a
:class:`~auv_envs.core.ops.Backend`: the arithmetic, the episode's random
draws (NumPy ``Generator``'s interface) and the plant (the carrier and arm in
MuJoCo on the CPU), whose methods are ``place(carrier, arm)`` (the rig at rest
at those joint positions) and ``follow(carrier_ref, carrier_vel, arm_ref,
current, start)`` (the source's positions and velocities, (count, 3) each, at
sample periods ``start``, ``start + 1``, ...: the rig moved on one period
towards each row of references, in each row's current). The start
draw, the step's order (score the estimate, move on one period, measure the
next block when this one is served), the reward, the
observations, ``info`` and the episode summary exist here only;
:class:`auv_envs.tasks.acoustic.env.AcousticTrackingEnv` is the Gymnasium
shell around them (it renders and computes the bound).

The agent's estimates do not act on the physics, so the physics runs and the
measurements are drawn in blocks of :data:`BLOCK` sample periods, vectorised
over the block, and served one period per step: the same as stepping one
period at a time (the blocks are a computational device, not a change of
model) and many times faster. The draws come in the order the environment
has always made them, so its episodes are the released ones, bit for bit.

On the CPU the record's arrays (``estimates``, ``truths``) are written in
place, row by row (:func:`record_row`): a copy per step would cost more than
the step, so a state is current until the next step (the shell keeps only the
latest).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np

from auv_envs import metrics
from auv_envs.core.acoustics import HydrophoneArray, Measurements
from auv_envs.core.ops import Backend

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
#: Sample periods simulated and measured per block (0.5 s at 100 Hz).
BLOCK = 50
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
        noise_draws: the order of the measurement model's draws
            (:meth:`~auv_envs.core.acoustics.HydrophoneArray.measure`).
        draw_detections: whether the blocks draw the detections (and the nuisance
            behind them: wander, fading, node states); without them a block holds the
            source's motion only, which is all the ``state`` observation and the reward
            read.
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
    noise_draws: str = "kept"
    draw_detections: bool = True


class Plan(NamedTuple):
    """An episode's draws at reset, fixed through it: the carrier's reference (T+1, 4) x,
    y, z, yaw and its rate, the arm's joint references (T+1, 6), the current (T+1, 3),
    the nodes' clock offsets (N,), the water's true sound speed (m/s) and the static
    point (None on a dynamic route)."""

    carrier_ref: np.ndarray
    carrier_vel: np.ndarray
    arm_ref: np.ndarray
    current: np.ndarray
    clock_offsets: np.ndarray
    sound_speed: float | None
    static_point: int | None


class Block(NamedTuple):
    """Sample periods ``[start, start + B)`` simulated and measured.

    ``positions``/``velocities`` (B, 3) the source's; ``heard`` what the nodes
    heard (propagation delay); ``fades`` (B, Q, N) dB and ``nodes`` (B, N)
    which work (None when off); ``measurements`` the detection sets (None, as
    ``heard``, when the task draws no detections). What
    the next block continues: ``history`` (<= :data:`HISTORY`, 3) source
    positions, ``wander`` (N,) and ``fading`` (Q, N) at the last period.
    """

    start: int
    positions: np.ndarray
    velocities: np.ndarray
    heard: np.ndarray
    fades: np.ndarray | None
    nodes: np.ndarray | None
    measurements: Measurements
    history: np.ndarray | None
    wander: np.ndarray | None
    fading: np.ndarray | None


class EpisodeState(NamedTuple):
    """Everything an episode changes besides the plant: the plan, the block being
    served, the steps taken, the estimates and truths so far (T, 3; NaN ahead) and
    the sum of squared errors."""

    plan: Plan
    block: Block
    steps: int
    squared_error_sum: float
    estimates: np.ndarray
    truths: np.ndarray


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


def current_profile(rng: np.random.Generator, n: int, dt: float, speed_range) -> np.ndarray:
    """A horizontal current (n, 3): speed sweeping ``speed_range``, direction veering.

    ``speed(t) = lo + (hi - lo) (1 + sin(2 pi t / T_s + phi)) / 2`` with
    ``T_s`` uniform in 20-60 s, and direction ``theta0 + 0.3 sin(2 pi t / T_d
    + psi)`` with ``T_d`` uniform in 30-90 s.
    """
    lo, hi = speed_range
    t = dt * np.arange(n)
    speed = lo + (hi - lo) * 0.5 * (1 + np.sin(2 * np.pi * t / rng.uniform(20, 60)
                                               + rng.uniform(0, 2 * np.pi)))
    direction = rng.uniform(-np.pi, np.pi) + 0.3 * np.sin(
        2 * np.pi * t / rng.uniform(30, 90) + rng.uniform(0, 2 * np.pi)
    )
    return np.stack([speed * np.cos(direction), speed * np.sin(direction), np.zeros(n)], 1)


def draw_plan(params: AcousticParams, draws) -> Plan:
    """The episode's plan. Draws, in order: the route (:func:`plan_route`) and the arm's
    sweep (amplitudes, periods, phases), or the static point when drawn; the current
    (:func:`current_profile`); the clock offsets; the sound speed."""
    n = params.horizon + 1
    dt = params.dt
    static_point = None
    if params.trajectory == "dynamic":
        carrier_ref, carrier_vel = plan_route(draws, n, dt)
        t = dt * np.arange(n)[:, None]
        amplitude = np.concatenate([draws.uniform(0.1, 0.35, 3), draws.uniform(0.05, 0.2, 3)])
        period = draws.uniform(12.0, 40.0, 6)
        phase = draws.uniform(0, 2 * np.pi, 6)
        arm_ref = NOMINAL_POSTURE + amplitude * (
            np.sin(2 * np.pi * t / period + phase) - np.sin(phase)
        )
    else:
        static_point = params.static_point or int(draws.integers(1, len(STATIC_POINTS) + 1))
        ref = np.append(np.asarray(STATIC_POINTS[static_point - 1]) - params.source_offset, 0.0)
        carrier_ref = np.broadcast_to(ref, (n, 4)).copy()
        carrier_vel = np.zeros((n, 4))
        arm_ref = np.broadcast_to(NOMINAL_POSTURE, (n, 6)).copy()
    current = current_profile(draws, n, dt, params.current_range)
    array = params.array
    clock_offsets = array.draw_clock_offsets(draws)
    sound_speed = array.draw_sound_speed(draws)
    return Plan(carrier_ref, carrier_vel, arm_ref, current, clock_offsets, sound_speed,
                static_point)


# ------------------------------------------------------------------ blocks
def simulate_block(params: AcousticParams, plan: Plan, previous: Block | None, start: int,
                   backend: Backend) -> Block:
    """Advance the plant over sample periods ``[start, start + BLOCK)`` (to the horizon)
    and measure them, continuing ``previous`` (None at reset)."""
    _, draws, plant = backend
    count = min(BLOCK, params.horizon + 1 - start)
    rows = slice(start, start + count)
    before = np.arange(start - 1, start + count - 1).clip(0)  # the current of the period before
    positions, velocities = plant.follow(plan.carrier_ref[rows], plan.carrier_vel[rows],
                                         plan.arm_ref[rows], plan.current[before], start)
    if not params.draw_detections:
        return Block(start, positions, velocities, None, None, None, None, None, None, None)
    array = params.array
    history = wander = fading = nodes = None
    if previous is not None:
        history, wander, fading = previous.history, previous.wander, previous.fading
        nodes = previous.nodes
    heard = positions
    if array.config.propagation_delay:
        track = positions if history is None else np.concatenate([history, positions])
        heard = array.emission_positions(track, count, params.dt, plan.sound_speed)
        history = track[-HISTORY:]
    wanders = array.draw_wander(draws, count, wander)
    if wanders is not None:
        wander = wanders[-1]
    fades = array.draw_fading(draws, count, fading)
    if fades is not None:
        fading = fades[-1]
    nodes = array.draw_node_states(draws, count, None if nodes is None else nodes[-1])
    measurements = array.measure(
        draws, heard, plan.clock_offsets,
        np.linalg.norm(plan.current[start:start + count], axis=1), plan.sound_speed, wanders,
        fades, nodes, noise_draws=params.noise_draws,
    )
    return Block(start, positions, velocities, heard, fades, nodes, measurements, history,
                 wander, fading)


# ------------------------------------------------------------------ reset and step
def reset(params: AcousticParams, backend: Backend):
    """A new episode: ``(state, truth, observation)``; ``truth`` is ``{"k": 0, "error":
    NaN}`` (nothing estimated yet)."""
    plan = draw_plan(params, backend.draws)
    backend.plant.place(plan.carrier_ref[0], plan.arm_ref[0])
    block = simulate_block(params, plan, None, 0, backend)
    state = EpisodeState(plan=plan, block=block, steps=0, squared_error_sum=0.0,
                         estimates=np.full((params.horizon, 3), np.nan),
                         truths=np.full((params.horizon, 3), np.nan))
    now = {"k": 0, "error": float("nan")}
    return state, now, observe(params, state)


def record_row(array: np.ndarray, k: int, row) -> np.ndarray:
    """``array`` with row ``k`` set to ``row`` (in place on the CPU: module docstring)."""
    array[k] = row
    return array


def step(params: AcousticParams, state: EpisodeState, action, backend: Backend):
    """Score the estimate ``action`` (the (3,) array already checked) against the truth
    at the last observation, then move on one sample period: ``(state, truth,
    observation, terms)``, ``terms`` the reward terms (an episode never terminates;
    it is truncated at its horizon)."""
    k = state.steps  # the estimate is scored against the truth at observation k
    block = state.block
    position = block.positions[k - block.start]
    difference = action - position
    error = math.sqrt(difference.dot(difference))  # np.linalg.norm's arithmetic, sooner
    state = state._replace(
        steps=k + 1, squared_error_sum=state.squared_error_sum + error * error,
        estimates=record_row(state.estimates, k, action),
        truths=record_row(state.truths, k, position))
    if state.steps - block.start >= BLOCK:
        state = state._replace(
            block=simulate_block(params, state.plan, block, state.steps, backend))
    now = {"k": state.steps, "error": error}
    terms = {"estimate": -min(error, params.error_clip) / params.error_clip}
    return state, now, observe(params, state), terms


# ------------------------------------------------------------------ what is seen
def observe(params: AcousticParams, state: EpisodeState):
    """The ``state`` or ``measurements`` observation at the state's step."""
    k = state.steps
    block = state.block
    j = k - block.start
    if params.obs_mode == "state":
        return np.concatenate([block.positions[j], block.velocities[j],
                               state.plan.current[k]]).astype(np.float32)
    m = block.measurements
    n = m.n_nodes
    values = m.values[j].copy()  # one copy, then views of it
    obs = {
        "tdoa": values[..., : n - 1],
        "azimuth": values[..., n - 1 : 2 * n - 1],
        "elevation": values[..., 2 * n - 1 :],
        "mask": m.mask[j].astype(np.int8),
    }
    if block.nodes is not None:
        obs["node_mask"] = block.nodes[j].astype(np.int8)
    return obs


def info(params: AcousticParams, state: EpisodeState, now: dict) -> dict:
    """The step's ``info`` without the reward terms (see the environment's docstring)."""
    block = state.block
    k, error = now["k"], now["error"]
    j = k - block.start
    rmse = math.sqrt(state.squared_error_sum / k) if k else float("nan")
    out = {
        "estimate_error": error,
        "running_rmse": rmse,
        "tracked": error <= params.track_gate,
        "is_success": rmse <= params.success_radius,
        "true_position": block.positions[j].copy(),
        "true_velocity": block.velocities[j].copy(),
        "current": state.plan.current[k].copy(),
        "time": k * params.dt,
    }
    if block.measurements is not None:
        out["detection_origin"] = block.measurements.origin[j].copy()
    if block.nodes is not None:
        out["nodes_working"] = int(np.count_nonzero(block.nodes[j]))
    return out


def summary(params: AcousticParams, state: EpisodeState) -> dict:
    """The episode's summary (``info["episode_metrics"]`` at its end)."""
    est, truth = state.estimates[: state.steps], state.truths[: state.steps]
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
        out["static_point"] = state.plan.static_point
    return out
