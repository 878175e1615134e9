"""The acoustic RL front end, written once for NumPy and JAX: one least-squares fix per
detection, and the fixes of the last step that had any held beside them.

``AcousticTracking-v2``'s ``measurements`` observation is a padded set of detections per
band (the source, its boundary ghosts, clutter) in an order that carries no meaning.
:func:`observe` turns one observation into tokens: each real detection is fixed by the
paper's least-squares positioner ([GMPHD] §1.1-1.3,
:class:`~baselines.acoustic.perception.positioning.LeastSquaresPositioner`, fused
TDOA-DOA rows, noise weighting, node dropouts honoured) from the measurements and the
documented calibration, never from ``info``, and becomes its fix (in the learner's action
units, [-1, 1] over the tank), the log10 standard deviations of the fix's covariance (m),
the log of its residual ``chi2 / dof`` and a validity flag (real, finite, inside the tank,
inside the residual gate). Beside them it holds the tokens of the last earlier step that
had a valid fix, with their age: a frame stack of depth two that skips empty frames, so
that the estimate survives steps without any fix (the ``hard`` level's dropouts). No clock
calibration.

With a memory (:class:`DetectionTrack`, ``detection_track: true``) the fixes are corrected
by an online estimate of the nodes' clock offsets, as ``ls-kf``'s are
(:class:`~baselines.acoustic.perception.positioning.ClockOffsetEstimator`), and a Kalman
track runs over them (:func:`track_step`: ``ls-kf``'s constant-velocity filter,
nearest-neighbour gate and restart, on each axis with the fixes' variances). Its estimate
joins the set as one more token, every token carrying its deviation from the track's
prediction, so that the set encoder can weigh the fixes by how well they agree with what
was heard before.

The functions take the array namespace ``xp``. On NumPy (:class:`DetectionFixes`, the
Gymnasium wrapper that ``train.py`` and the shipped agents apply, ``detection_fixes:
true``) the positioner solves the real detections only, in float64; on JAX
(:class:`DetectionFixesMJX`, the batched wrapper the compiled PPO trains on) it solves
every padded entry at fixed shapes (:meth:`LeastSquaresPositioner.solve_fixed`, float32;
within 5 mm of the float64 fixes, ``tests/test_detection_fixes.py``). The policy that
reads the tokens is :class:`baselines.rl.detections.DetectionSetPolicy`.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from baselines.acoustic.agents import (
    FIX_VARIANCE_FLOOR,
    LSKF_ACCEL_STD,
    LSKF_GATE,
    LSKF_MAX_MISSES,
)
from baselines.acoustic.perception.positioning import (
    ClockOffsetEstimator,
    ClockState,
    LeastSquaresPositioner,
)
from baselines.kalman import constant_velocity_blocks
from baselines.rl.batched_front_end import BatchedFrontEnd, FrontEnd
from baselines.rl.config import ConfigError

#: The observation keys of one step's tokens.
FIX_KEYS = ("fix", "fix_log_std", "fix_log_fit", "fix_valid")
#: Every observation key the front end writes (the current tokens, the held ones, the age).
OBS_KEYS = (*FIX_KEYS, *(f"held_{key}" for key in FIX_KEYS), "held_age")
#: Floor on a fix's standard deviation and residual fit before their logarithms.
LOG_FLOOR = 1e-6


def token_spaces(bands: int, slots: int) -> dict:
    """The spaces of one step's tokens (:data:`FIX_KEYS`) for ``bands`` x ``slots``
    detections."""
    q, k = bands, slots
    return {
        "fix": spaces.Box(-np.inf, np.inf, (q, k, 3), np.float32),
        "fix_log_std": spaces.Box(-np.inf, np.inf, (q, k, 3), np.float32),
        "fix_log_fit": spaces.Box(-np.inf, np.inf, (q, k), np.float32),
        "fix_valid": spaces.MultiBinary((q, k)),
    }


def token_size(bands: int, track: bool = False) -> int:
    """The width of one token as the set encoder reads it: the fix (3), its log standard
    deviations (3), its log fit (1), the band one-hot (``bands``), the held flag and the
    log age, and with a track (:class:`DetectionTrack`) the track flag and the token's
    deviation from the track (:class:`~baselines.rl.detections.DetectionSetExtractor`, and
    :func:`baselines.rl.compiled.set_features` in JAX)."""
    return 3 + 3 + 1 + bands + 2 + 2 * int(track)


@dataclasses.dataclass(frozen=True)
class FixParams:
    """What the front end reads from the environment: the positioner (its calibration) and
    the action box the fixes are expressed in."""

    positioner: LeastSquaresPositioner
    low: np.ndarray
    span: np.ndarray
    bands: int
    slots: int
    #: The track's constant-velocity model over one measurement interval.
    motion: Motion
    #: The clock offsets' estimator (its constants; the track's front end carries the
    #: estimate).
    clock: ClockOffsetEstimator

    @classmethod
    def of(cls, env) -> FixParams:
        """The parameters of an acoustic environment in ``measurements`` mode (a CPU one,
        or the setup of one, :func:`auv_envs.tasks.acoustic.config.params`; its
        ``calibration`` and action box).

        Raises:
            ConfigError: it is not such an environment.
        """
        base = getattr(env, "unwrapped", env)
        if getattr(base, "obs_mode", None) != "measurements" or not hasattr(base,
                                                                            "calibration"):
            spec = getattr(env, "spec", None)
            raise ConfigError("detection_fixes needs auv_envs/AcousticTracking-v2 with "
                              f"obs_mode='measurements', got {spec.id if spec else env}"
                              f" with obs_mode={getattr(base, 'obs_mode', None)!r}")
        space = base.action_space
        q, k = base.observation_space["mask"].shape
        return cls(LeastSquaresPositioner(base.calibration, method="fused"),
                   space.low.astype(np.float64), (space.high - space.low).astype(np.float64),
                   q, k, Motion.of(1.0 / float(base.calibration.sample_rate)),
                   ClockOffsetEstimator(base.calibration))

    def observation_space(self) -> spaces.Dict:
        """The front end's observation space (:data:`OBS_KEYS`)."""
        tokens = token_spaces(self.bands, self.slots)
        return spaces.Dict({
            **tokens,
            **{f"held_{key}": space for key, space in tokens.items()},
            "held_age": spaces.Box(0.0, np.inf, (1,), np.float32),
        })


def _fixes(p: FixParams, observation: dict, xp=np, clock: ClockState | None = None) -> tuple:
    """One ``measurements`` observation's least-squares fixes (the TDOAs corrected by the
    ``clock`` estimate if one is given): position (Q, K, 3) m (the tank's centre where not
    valid), the variances of the covariance's diagonal (Q, K, 3) m^2 (1 where not valid),
    the fit ``chi2 / dof`` (Q, K) and the validity (Q, K)."""
    nodes = observation.get("node_mask")
    correction = None if clock is None else (clock.offset, 1.0 / xp.sqrt(clock.precision))
    if xp is np:
        fixes = p.positioner.solve(observation["tdoa"], observation["azimuth"],
                                   observation["elevation"], observation["mask"],
                                   correction, nodes=nodes)
    else:
        fixes = p.positioner.solve_fixed(
            *(xp.asarray(observation[key], xp.float32) for key in ("tdoa", "azimuth",
                                                                    "elevation")),
            observation["mask"], nodes=nodes, xp=xp, clock=correction)
    valid = fixes.valid
    position = xp.where(valid[..., None], fixes.position, p.low + 0.5 * p.span)
    variance = xp.diagonal(xp.where(valid[..., None, None], fixes.covariance, 1.0),
                           axis1=-2, axis2=-1)
    fit = xp.where(valid, fixes.chi2 / xp.maximum(fixes.dof, 1), 1.0)
    return position, variance, fit, valid


def _token(p: FixParams, position, variance, fit, valid, xp=np) -> dict:
    """Tokens of positions (m), their variances (m^2), fits and validity (module
    docstring; the arrays' leading shapes are kept)."""
    log_std = xp.where(valid[..., None],
                       0.5 * xp.log10(xp.maximum(variance, LOG_FLOOR ** 2)), 0.0)
    return {
        "fix": (2.0 * (position - p.low) / p.span - 1.0).astype(xp.float32),
        "fix_log_std": log_std.astype(xp.float32),
        "fix_log_fit": xp.log(xp.maximum(fit, LOG_FLOOR)).astype(xp.float32),
        "fix_valid": valid.astype(xp.int8),
    }


def tokens(p: FixParams, observation: dict, xp=np) -> dict:
    """One ``measurements`` observation's tokens (:data:`FIX_KEYS`, float32; ``fix_valid``
    int8). Tokens that are not valid fixes are zero (``fix``: the tank's centre, 0)."""
    return _token(p, *_fixes(p, observation, xp), xp)


class Held(NamedTuple):
    """The tokens of the latest step with a valid fix (zero before there was one) and how
    many steps ago that was."""

    tokens: dict
    steps: object

    @classmethod
    def start(cls, p: FixParams, xp=np) -> Held:
        zeros = {key: xp.zeros(space.shape, space.dtype)
                 for key, space in token_spaces(p.bands, p.slots).items()}
        return cls(zeros, xp.asarray(0, xp.int32))


def observe(p: FixParams, held: Held, observation: dict, xp=np) -> tuple[Held, dict]:
    """The front end's observation of one ``measurements`` observation, and what it holds
    for the next step."""
    return _hold(held, tokens(p, observation, xp), xp)


def _hold(held: Held, current: dict, xp=np) -> tuple[Held, dict]:
    """The observation of one step's tokens ``current`` beside the held ones, and what is
    held for the next step."""
    out = {**current, **{f"held_{key}": value for key, value in held.tokens.items()},
           "held_age": xp.asarray(xp.log1p(held.steps * 1.0), xp.float32)[None]}
    fixed = xp.any(current["fix_valid"] > 0)
    kept = {key: xp.where(fixed, current[key], held.tokens[key]) for key in FIX_KEYS}
    return Held(kept, xp.where(fixed, 1, held.steps + 1).astype(xp.int32)), out


class DetectionFixes(FrontEnd):
    """Replaces the ``measurements`` observation by one least-squares fix per detection,
    with the fixes of the last step that had any held beside them (module docstring).

    Observation (float32 unless stated; Q bands, K padded detections per band):
    ``fix`` (Q, K, 3) the fix in [-1, 1] units of the action space (the tank box,
    as ``RescaleAction`` maps it), ``fix_log_std`` (Q, K, 3) log10 of the square
    roots of the covariance's diagonal (m), ``fix_log_fit`` (Q, K) ln(chi2 / dof),
    ``fix_valid`` ``MultiBinary((Q, K))``. Tokens that are not valid fixes are zero.
    The same four under ``held_fix*`` are those of the latest earlier step with at least
    one valid fix (all zero before there was one), and ``held_age`` (1,) is how many
    steps ago that was, as ln(1 + steps). :meth:`reset` (and :meth:`clear`) forget them
    (:class:`~baselines.rl.batched_front_end.FrontEnd`).

    Raises:
        ConfigError: the environment is not an acoustic one in ``measurements`` mode.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.params = FixParams.of(env)
        self.observation_space = self.params.observation_space()
        self.clear()

    def start(self) -> Held:
        return Held.start(self.params)

    def advance(self, carry: Held, obs) -> tuple:
        return observe(self.params, carry, obs)


class DetectionFixesMJX(BatchedFrontEnd):
    """A batched acoustic env (:class:`~auv_envs.batched.functional.FunctionalEnv`,
    ``measurements``) whose observation is :class:`DetectionFixes`'s, computed in JAX by
    the same functions. The held tokens ride in ``state.info["detection_fixes"]`` and start
    afresh where an episode restarted (:class:`~baselines.rl.batched_front_end.BatchedFrontEnd`)."""

    INFO_KEY = "detection_fixes"

    def __init__(self, env):
        super().__init__(env)
        self.params = FixParams.of(env.task.setup)
        self.observation_space = self.around(self.params.observation_space())

    def start(self) -> Held:
        return Held.start(self.params, self._jnp)

    def advance(self, carry: Held, obs) -> tuple[Held, dict]:
        return observe(self.params, carry, obs, self._jnp)


# ---------------------------------------------------------------------- the track
#: The track's constant-velocity model, gate and re-initialisation, and the floor added to
#: each fix's variances: ``ls-kf``'s (:class:`~baselines.acoustic.agents.LSKalmanAgent`).
TRACK_ACCEL_STD, TRACK_GATE, TRACK_MAX_MISSES = LSKF_ACCEL_STD, LSKF_GATE, LSKF_MAX_MISSES
TRACK_VARIANCE_FLOOR = FIX_VARIANCE_FLOOR
#: The observation keys of the track's token.
TRACK_KEYS = tuple(f"track_{key}" for key in FIX_KEYS)
#: The keys of every token's deviation from the track.
DEVIATION_KEYS = ("fix_deviation", "held_fix_deviation", "track_fix_deviation")


class Track(NamedTuple):
    """A constant-velocity Kalman filter on each axis: position and velocity (3,) m and
    m/s, and the covariance of each axis's (position, velocity) as its three entries
    ``pp``, ``pv``, ``vv`` (3,), float32 on NumPy as on JAX; the steps since its last
    gated fix; whether it has started."""

    position: object
    velocity: object
    pp: object
    pv: object
    vv: object
    misses: object
    started: object

    @classmethod
    def start(cls, xp=np) -> Track:
        zeros = xp.zeros(3, xp.float32)
        return cls(zeros, zeros, xp.ones(3, xp.float32), zeros, xp.ones(3, xp.float32),
                   xp.asarray(0, xp.int32), xp.asarray(False))


class Motion(NamedTuple):
    """One axis of the track's constant-velocity model over a step: the step ``dt`` (s) and
    the white-acceleration noise's covariance entries ``q_pp``, ``q_pv``, ``q_vv``
    (:func:`baselines.kalman.constant_velocity_blocks`, sigma_q :data:`TRACK_ACCEL_STD`)."""

    dt: float
    q_pp: float
    q_pv: float
    q_vv: float

    @classmethod
    def of(cls, dt: float) -> Motion:
        _, q = constant_velocity_blocks(dt, TRACK_ACCEL_STD)
        return cls(float(dt), float(q[0, 0]), float(q[0, 1]), float(q[1, 1]))


def _predict(motion: Motion, track: Track) -> Track:
    """The track one step later by its constant-velocity model (nothing measured)."""
    dt = motion.dt
    return track._replace(
        position=track.position + dt * track.velocity,
        pp=track.pp + 2.0 * dt * track.pv + dt * dt * track.vv + motion.q_pp,
        pv=track.pv + dt * track.vv + motion.q_pv,
        vv=track.vv + motion.q_vv)


def _distance(track: Track, position, variance, xp=np):
    """The squared Mahalanobis distances (...) of positions (..., 3) m with variances
    (..., 3) m^2 from the track's position (its variances and theirs, floored, on each
    axis), and the innovations (..., 3)."""
    nu = position - track.position
    return xp.sum(nu * nu / (track.pp + variance + TRACK_VARIANCE_FLOOR), axis=-1), nu


def track_step(motion: Motion, track: Track, position, variance, valid, xp=np) -> Track:
    """One step of the track over one observation's fixes (position (Q, K, 3) m, their
    variances (Q, K, 3) m^2, validity (Q, K)): ``ls-kf``'s filter on each axis alone,
    the fixes' covariances taken by their diagonals. Predict by the constant-velocity
    model; update with the valid fix nearest in the Mahalanobis sense if it lies inside
    the gate; (re)start at the valid fix nearest the fixes' median when there was no track
    yet or :data:`TRACK_MAX_MISSES` steps passed without a gated fix (position variance
    the fix's, velocity variance 1 (m/s)^2)."""
    z = position.reshape(-1, 3)
    r = variance.reshape(-1, 3) + TRACK_VARIANCE_FLOOR
    ok = valid.reshape(-1) > 0
    predicted = _predict(motion, track)
    x, pp, pv, vv = predicted.position, predicted.pp, predicted.pv, predicted.vv
    d2, nu = _distance(predicted, z, variance.reshape(-1, 3), xp)
    d2 = xp.where(ok, d2, xp.inf)
    i = xp.argmin(d2)
    any_ok = xp.any(ok)
    restart = any_ok & (~track.started | (track.misses >= TRACK_MAX_MISSES))
    gated = track.started & ~restart & (d2[i] <= TRACK_GATE)
    s_i, nu_i = pp + r[i], nu[i]
    updated = (x + pp / s_i * nu_i, track.velocity + pv / s_i * nu_i, pp * r[i] / s_i,
               pv * r[i] / s_i, xp.maximum(vv - pv * pv / s_i, 0.0))
    # the (re)start: the valid fix nearest the valid fixes' median
    candidates = xp.where((ok | ~any_ok)[:, None], z, xp.nan)
    centre = xp.nanmedian(candidates, axis=0)
    j = xp.argmin(xp.where(ok, xp.sum((z - centre) ** 2, axis=-1), xp.inf))
    zeros = xp.zeros(3, xp.float32)
    fresh = (z[j], zeros, r[j], zeros, xp.ones(3, xp.float32))
    parts = [xp.where(restart, a, xp.where(gated, b, c)).astype(xp.float32)
             for a, b, c in zip(fresh, updated, (x, track.velocity, pp, pv, vv), strict=True)]
    misses = xp.where(restart | gated, 0, xp.where(track.started, track.misses + 1, 0))
    return Track(*parts, misses.astype(xp.int32), track.started | restart)


def deviation(p: FixParams, track: Track, token: dict, xp=np):
    """How far each token of ``token`` (:data:`FIX_KEYS`) lies from the track:
    ln(1 + squared Mahalanobis distance), 0 before the track has started (float32, the
    tokens' leading shape)."""
    position = p.low + 0.5 * (token["fix"] + 1.0) * p.span
    variance = 10.0 ** (2.0 * token["fix_log_std"])
    d2, _ = _distance(track, position, variance, xp)
    return xp.where(track.started, xp.log1p(d2), 0.0).astype(xp.float32)


def track_token(p: FixParams, track: Track, xp=np) -> dict:
    """The track as one token (:data:`TRACK_KEYS`, shapes (1, ...)): its position, the log
    standard deviations of its position, ln(1 + steps since its last gated fix) as the fit
    and whether it has started."""
    token = _token(p, track.position[None], track.pp[None],
                   (1.0 + track.misses * 1.0)[None], track.started[None], xp)
    return {f"track_{key}": value for key, value in token.items()}


def observe_track(p: FixParams, carry: tuple, observation: dict, xp=np) -> tuple:
    """:func:`observe` with the clock calibration and the track: the fixes corrected by the
    clock offsets' estimate so far (as ``ls-kf``'s), which then folds them in
    (:class:`~baselines.acoustic.perception.positioning.ClockOffsetEstimator`); the track's
    token (:data:`TRACK_KEYS`) and each token's :func:`deviation` from its prediction for
    this step (``fix_deviation``, ``held_fix_deviation``; the track's own,
    ``track_fix_deviation``, is 0). ``carry`` is ``(Held, Track, ClockState)``."""
    held, track, clock = carry
    position, variance, fit, valid = _fixes(p, observation, xp, clock)
    dtype = np.float64 if xp is np else xp.float32
    clock = p.clock.step(clock, *(xp.asarray(observation[key], dtype) for key in (
        "tdoa", "azimuth", "elevation")), valid, observation.get("node_mask"), xp)
    held, out = _hold(held, _token(p, position, variance, fit, valid, xp), xp)
    predicted = _predict(p.motion, track)
    deviations = {f"{prefix}fix_deviation": deviation(
        p, predicted, {key: out[f"{prefix}{key}"] for key in FIX_KEYS}, xp)
        for prefix in ("", "held_")}
    track = track_step(p.motion, track, position, variance, valid, xp)
    tokens = track_token(p, track, xp)
    return (held, track, clock), {**out, **deviations, **tokens,
                           "track_fix_deviation": xp.zeros(1, xp.float32)}


def _track_space(p: FixParams) -> spaces.Dict:
    def deviation_space(*shape):
        return spaces.Box(0.0, np.inf, shape, np.float32)

    track = {"track_fix": spaces.Box(-np.inf, np.inf, (1, 3), np.float32),
             "track_fix_log_std": spaces.Box(-np.inf, np.inf, (1, 3), np.float32),
             "track_fix_log_fit": spaces.Box(-np.inf, np.inf, (1,), np.float32),
             "track_fix_valid": spaces.MultiBinary(1)}
    return spaces.Dict({**p.observation_space().spaces, **track,
                        "fix_deviation": deviation_space(p.bands, p.slots),
                        "held_fix_deviation": deviation_space(p.bands, p.slots),
                        "track_fix_deviation": deviation_space(1)})


class DetectionTrack(DetectionFixes):
    """:class:`DetectionFixes` with a memory: a Kalman track over the fixes
    (:func:`track_step`, ``ls-kf``'s filter on each axis) whose estimate is one more token,
    ``track_fix`` (1, 3), ``track_fix_log_std`` (1, 3), ``track_fix_log_fit`` (1,)
    (ln(1 + steps since its last gated fix)) and ``track_fix_valid`` (1,) (it has started),
    and each token's :func:`deviation` from the track's prediction, ``fix_deviation``
    (Q, K), ``held_fix_deviation`` (Q, K), ``track_fix_deviation`` (1,) (zero). The set
    encoder weighs the track with the fixes (``detection_track: true``).

    Raises:
        ConfigError: the environment is not an acoustic one in ``measurements`` mode.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.observation_space = _track_space(self.params)

    def start(self) -> tuple:
        return Held.start(self.params), Track.start(), self.params.clock.start()

    def advance(self, carry: tuple, obs) -> tuple:
        return observe_track(self.params, carry, obs)


class DetectionTrackMJX(DetectionFixesMJX):
    """:class:`DetectionTrack`'s observation on the batched acoustic env, in JAX by the same
    functions (the carry in ``state.info["detection_fixes"]``)."""

    def __init__(self, env):
        super().__init__(env)
        self.observation_space = self.around(_track_space(self.params))

    def start(self) -> tuple:
        return (Held.start(self.params, self._jnp), Track.start(self._jnp),
                self.params.clock.start(self._jnp))

    def advance(self, carry: tuple, obs) -> tuple:
        return observe_track(self.params, carry, obs, self._jnp)
