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
calibration and no filter.

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

from baselines.acoustic.perception.positioning import LeastSquaresPositioner
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


def token_size(bands: int) -> int:
    """The width of one token as the set encoder reads it: the fix (3), its log standard
    deviations (3), its log fit (1), the band one-hot (``bands``), the held flag and the
    log age (:class:`~baselines.rl.detections.DetectionSetExtractor`, and
    :func:`baselines.rl.compiled.set_features` in JAX)."""
    return 3 + 3 + 1 + bands + 2


@dataclasses.dataclass(frozen=True)
class FixParams:
    """What the front end reads from the environment: the positioner (its calibration) and
    the action box the fixes are expressed in."""

    positioner: LeastSquaresPositioner
    low: np.ndarray
    span: np.ndarray
    bands: int
    slots: int

    @classmethod
    def of(cls, env) -> FixParams:
        """The parameters of an acoustic environment in ``measurements`` mode (a CPU or a
        batched one; its ``calibration`` and action box).

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
                   q, k)

    def observation_space(self) -> spaces.Dict:
        """The front end's observation space (:data:`OBS_KEYS`)."""
        tokens = token_spaces(self.bands, self.slots)
        return spaces.Dict({
            **tokens,
            **{f"held_{key}": space for key, space in tokens.items()},
            "held_age": spaces.Box(0.0, np.inf, (1,), np.float32),
        })


def tokens(p: FixParams, observation: dict, xp=np) -> dict:
    """One ``measurements`` observation's tokens (:data:`FIX_KEYS`, float32; ``fix_valid``
    int8). Tokens that are not valid fixes are zero (``fix``: the tank's centre, 0)."""
    nodes = observation.get("node_mask")
    if xp is np:
        fixes = p.positioner.solve(observation["tdoa"], observation["azimuth"],
                                   observation["elevation"], observation["mask"], nodes=nodes)
    else:
        fixes = p.positioner.solve_fixed(
            *(xp.asarray(observation[key], xp.float32) for key in ("tdoa", "azimuth",
                                                                    "elevation")),
            observation["mask"], nodes=nodes, xp=xp)
    valid = fixes.valid
    position = xp.where(valid[..., None], fixes.position, p.low + 0.5 * p.span)
    variance = xp.diagonal(xp.where(valid[..., None, None], fixes.covariance, 1.0),
                           axis1=-2, axis2=-1)
    fit = xp.where(valid, fixes.chi2 / xp.maximum(fixes.dof, 1), 1.0)
    log_std = xp.where(valid[..., None],
                       0.5 * xp.log10(xp.maximum(variance, LOG_FLOOR ** 2)), 0.0)
    return {
        "fix": (2.0 * (position - p.low) / p.span - 1.0).astype(xp.float32),
        "fix_log_std": log_std.astype(xp.float32),
        "fix_log_fit": xp.log(xp.maximum(fit, LOG_FLOOR)).astype(xp.float32),
        "fix_valid": valid.astype(xp.int8),
    }


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
    current = tokens(p, observation, xp)
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
    """A batched acoustic env (:class:`~auv_envs.batched.acoustic_env.AcousticMJX`,
    ``measurements``) whose observation is :class:`DetectionFixes`'s, computed in JAX by
    the same functions. The held tokens ride in ``state.info["detection_fixes"]`` and start
    afresh where an episode restarted (:class:`~baselines.rl.batched_front_end.BatchedFrontEnd`)."""

    INFO_KEY = "detection_fixes"

    def __init__(self, env):
        super().__init__(env)
        self.params = FixParams.of(env.cpu_env)
        self.observation_space = self.around(self.params.observation_space())

    def start(self) -> Held:
        return Held.start(self.params, self._jnp)

    def advance(self, carry: Held, obs) -> tuple[Held, dict]:
        return observe(self.params, carry, obs, self._jnp)
