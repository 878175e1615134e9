"""The docking mission on ``nav_features`` for a learner: the navigation filter as a front end.

A position exists in the ``nav`` sensors only by integrating them: the DVL's velocity
over time, corrected by the depth and by USBL fixes that arrive late and are sometimes
wrong (``docs/navigation.md``). ``nav-homing-ofnmpc-ekf`` does it with
:class:`~baselines.docking.estimation.navigation_filter.NavigationFilter`, an error-state
Kalman filter (its docstring gives the equations and their sources). This module is that
filter written as pure functions of arrays, evaluated with NumPy on the CPU
(:class:`NavFilter`, the Gymnasium wrapper a shipped agent applies) and with
``jax.numpy`` under ``jit`` and ``vmap`` (:class:`NavFilterMJX`, around the batched env
the compiled PPO trains on): one definition for both, tested against
``NavigationFilter``.

Two numerical choices differ from ``NavigationFilter`` without changing its equations, so
that the filter holds in float32: the updates are written in forms that cancel nothing
(the depth's covariance as ``P_zz R / (P_zz + R)``; the USBL fix, whose ``H = -R_ping^T``
is orthogonal and whose noise ``r I`` is isotropic, as the same measurement of the
position ``t - R_ping y`` with ``H = I``), and the last steps' states are a ring buffer
of fixed length.

The learner's observation is the ``nav_features`` ``Dict`` with three entries added:

* ``nav_position`` (3): the estimate of the CG position, station frame (m);
* ``nav_entrance`` (3): the entrance centre (the station frame's origin) from the
  estimate, in body axes (m): where to go, as the vehicle sees it;
* ``nav_log_std`` (3): the natural log of the estimate's standard deviation along each
  station axis (m; about ln 1000 before the first fix).
"""

from __future__ import annotations

from typing import NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy import stats

from baselines.rl.batched_front_end import BatchedFrontEnd
from baselines.rl.config import ConfigError

#: Squared Mahalanobis distance beyond which a USBL fix is rejected (chi-square, 3 dof,
#: 99.9 %), as ``NavigationFilter``'s.
USBL_GATE = float(stats.chi2.ppf(0.999, 3))
#: The ``usbl_age`` the filter remembers when no fix is valid (``NavigationFilter``: inf).
NO_FIX_AGE = 1.0e9
#: The entries the front end adds (name, length).
ADDED = (("nav_entrance", 3), ("nav_log_std", 3), ("nav_position", 3))


class FilterParams(NamedTuple):
    """What the filter knows: the navigation suite's nominal figures and the step.

    Defaults as ``NavigationFilter``'s; :meth:`of` reads an env's."""

    transponder: tuple
    surface_z: float
    dt: float
    dvl_var: float = 0.02**2
    depth_var: float = 0.014**2
    usbl_sigma0: float = 0.1
    usbl_k: float = 0.015
    random_walk: float = 1e-4
    initial_var: float = 1000.0**2
    history: int = 50
    held_dvl_var: float = 0.1**2

    @classmethod
    def of(cls, env: gym.Env) -> FilterParams:
        """The parameters ``MissionAgent`` gives its filter, for ``env`` (a
        ``DockingMission-v0`` CPU env in ``nav_features`` mode, wrapped or not)."""
        base = env.unwrapped
        nav = getattr(base, "navigation", None)
        if getattr(base, "obs_mode", None) != "nav_features" or nav is None:
            raise ConfigError("the navigation filter needs a docking env with navigation "
                              "sensors in obs_mode='nav_features' (auv_envs/DockingMission-v0)")
        return cls(tuple(float(v) for v in nav.transponder), float(nav.station_depth),
                   float(base.calibration.control_period), dvl_var=nav.dvl.noise_std**2,
                   depth_var=max(nav.depth.noise_std, 1e-3)**2)

    def observation_space(self, space: spaces.Dict) -> spaces.Dict:
        """``space`` (the env's ``nav_features`` space) with the added entries."""
        added = {name: spaces.Box(-np.inf, np.inf, (n,), np.float32) for name, n in ADDED}
        return spaces.Dict({**space.spaces, **added})


class FilterState(NamedTuple):
    """The filter between observations (a JAX pytree, as it is a tuple)."""

    position: object   # (3,) nominal CG position, station frame, m
    covariance: object  # (3, 3) of the error state, m^2
    velocity: object   # (3,) the last bottom-locked DVL velocity, body, m/s
    last_age: object   # the last valid fix's usbl_age (NO_FIX_AGE: none)
    fixes: object      # fixes accepted
    rejected: object   # fixes gated out
    past_position: object    # (history, 3) ring buffer, after each step's updates
    past_covariance: object  # (history, 3, 3)
    past_rotation: object    # (history, 3, 3)
    length: object     # entries in the ring buffer
    head: object       # where the next entry goes

    @classmethod
    def start(cls, params: FilterParams, xp=np) -> FilterState:
        h = params.history
        dtype = np.float64 if xp is np else xp.float32
        eye = xp.eye(3, dtype=dtype)
        return cls(xp.zeros(3, dtype), eye * params.initial_var, xp.zeros(3, dtype),
                   xp.asarray(NO_FIX_AGE, dtype), xp.asarray(0), xp.asarray(0),
                   xp.zeros((h, 3), dtype), xp.zeros((h, 3, 3), dtype),
                   xp.zeros((h, 3, 3), dtype), xp.asarray(0), xp.asarray(0))


def rotation(attitude, xp=np):
    """Body to station frame of the AHRS ``attitude`` (roll, pitch, yaw), a (3, 3) array
    (:func:`auv_envs.core.frames.rotation_rows`)."""
    from auv_envs.core.frames import rotation_rows

    ops = _Trig(xp)
    rows = rotation_rows(attitude[0], attitude[1], attitude[2], ops)
    return xp.stack([xp.stack(row) for row in rows])


class _Trig:
    """The two functions :func:`rotation_rows` asks its ``ops`` for."""

    def __init__(self, xp):
        self.cos, self.sin = xp.cos, xp.sin


def step(params: FilterParams, state: FilterState, obs, xp=np) -> FilterState:
    """Take one ``nav_features`` observation (after the step it describes)."""
    dtype = state.position.dtype
    R = rotation(xp.asarray(obs["attitude"], dtype), xp)
    # dead reckoning (NavigationFilter.predict)
    locked = xp.asarray(obs["dvl_valid"])[0] > 0
    velocity = xp.where(locked, xp.asarray(obs["dvl_velocity"], dtype), state.velocity)
    noise = params.dvl_var + xp.where(locked, 0.0, params.held_dvl_var)
    position = state.position + R @ velocity * params.dt
    P = (state.covariance + params.dt**2 * noise * (R @ R.T)
         + params.random_walk * xp.eye(3, dtype=dtype))
    # depth d = surface_z - z: H = [0, 0, -1], written so that float32 cancels nothing
    s = P[2, 2] + params.depth_var
    column = P[:, 2]
    innovation = xp.asarray(obs["depth"], dtype)[0] - (params.surface_z - position[2])
    position = position - column * innovation / s
    kept = params.depth_var / s
    P = _depth_corner(xp, P - xp.outer(column, column) / s, column, kept)
    # a late USBL fix (NavigationFilter.update_usbl), through the state at its ping
    valid = xp.asarray(obs["usbl_valid"])[0] > 0
    age = xp.asarray(obs["usbl_age"], dtype)[0]
    new_fix = valid & (age < state.last_age)
    back = xp.round(age / params.dt).astype(np.int32)
    taken = xp.minimum(back, state.length)
    from_past = (back > 0) & (state.length > 0)
    index = (state.head - taken) % params.history
    p_then = xp.where(from_past, state.past_position[index], position)
    P_then = xp.where(from_past, state.past_covariance[index], P)
    R_then = xp.where(from_past, state.past_rotation[index], R)
    fix = xp.asarray(obs["usbl"], dtype)
    # the fix as a position at the ping, with an isotropic noise: the same update as
    # NavigationFilter's (H = -R_ping^T is orthogonal), in station axes, where the float32
    # inverse stays accurate
    noise = params.usbl_sigma0**2 + (params.usbl_k * xp.linalg.norm(fix))**2
    residual = xp.asarray(params.transponder, dtype) - R_then @ fix - p_then
    inverse = xp.linalg.inv(P_then + noise * xp.eye(3, dtype=dtype))
    accepted = new_fix & (residual @ inverse @ residual <= USBL_GATE)
    P_fixed = P - P_then + noise * P_then @ inverse
    position = xp.where(accepted, position + P_then @ inverse @ residual, position)
    P = xp.where(accepted, 0.5 * (P_fixed + P_fixed.T), P)
    last_age = xp.where(valid, age, NO_FIX_AGE).astype(dtype)
    # this step's state, for later fixes
    head = state.head
    past = (_put(xp, state.past_position, head, position),
            _put(xp, state.past_covariance, head, P), _put(xp, state.past_rotation, head, R))
    return FilterState(position, P, velocity, last_age, state.fixes + accepted,
                       state.rejected + (new_fix & ~accepted), *past,
                       xp.minimum(state.length + 1, params.history),
                       (head + 1) % params.history)


def _row_or_column(xp, k):
    eye = xp.arange(3)
    return (eye[:, None] == k) | (eye[None, :] == k)


def _depth_corner(xp, P, column, kept):
    """Row and column 2 of the depth update's covariance: ``P_i2 R / (P_22 + R)``."""
    mask = _row_or_column(xp, 2)
    fixed = xp.where(xp.arange(3)[:, None] == 2, column[None, :], column[:, None]) * kept
    return xp.where(mask, fixed, P)


def _put(xp, buffer, index, value):
    if xp is np:
        buffer = buffer.copy()
        buffer[index] = value
        return buffer
    return buffer.at[index].set(value)


def observe(state: FilterState, obs, xp=np) -> dict:
    """``obs`` with the entries of :data:`ADDED` from the filter ``state``."""
    R = rotation(xp.asarray(obs["attitude"], state.position.dtype), xp)
    std = xp.sqrt(xp.maximum(xp.diagonal(state.covariance), 1e-12))
    added = {"nav_entrance": R.T @ -state.position, "nav_log_std": xp.log(std),
             "nav_position": state.position}
    return {**obs, **{k: v.astype(xp.float32) for k, v in added.items()}}


class NavFilter(gym.ObservationWrapper):
    """The ``nav_features`` observation with the navigation filter's estimate added (the
    module docstring), on the CPU with NumPy.

    ``nav_filter: true`` in a training config or a policy manifest applies it
    (:data:`baselines.rl.config.FRONT_ENDS`). The filter keeps the episode's state, so
    each observation must be passed once and in order; :meth:`reset` (and :meth:`clear`,
    which the policy agent calls at each episode's start) start afresh.

    Raises:
        ConfigError: the environment is not ``DockingMission-v0`` in ``nav_features`` mode.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.params = FilterParams.of(env)
        self.observation_space = self.params.observation_space(env.observation_space)
        self.clear()

    def clear(self) -> None:
        """Forget the episode: the filter starts afresh at the next observation."""
        self.state = FilterState.start(self.params)

    def reset(self, **kwargs):
        self.clear()
        return super().reset(**kwargs)

    def observation(self, observation):
        self.state = step(self.params, self.state, observation)
        return observe(self.state, observation)


class NavFilterMJX(BatchedFrontEnd):
    """A batched ``DockingMission-v0`` (``nav_features``) whose observation is
    :class:`NavFilter`'s, computed in JAX by the same functions. The filter's state rides
    in ``state.info["nav_filter"]`` and starts afresh where an episode restarted
    (:class:`~baselines.rl.batched_front_end.BatchedFrontEnd`)."""

    INFO_KEY = "nav_filter"

    def __init__(self, env):
        super().__init__(env)
        self.params = FilterParams.of(env.cpu_env)
        self.observation_space = self.around(
            self.params.observation_space(env.cpu_env.observation_space))

    def start(self) -> FilterState:
        return FilterState.start(self.params, self._jnp)

    def advance(self, carry: FilterState, obs) -> tuple:
        carry = step(self.params, carry, obs, self._jnp)
        return carry, observe(carry, obs, self._jnp)
