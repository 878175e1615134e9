"""Where the vehicle is, from its navigation sensors: an error-state Kalman filter.

The ``nav`` observation (:mod:`auv_envs.tasks.docking.navigation`) gives an AHRS attitude and
gyro rates, a DVL velocity over the seabed, a pressure depth and, every second or so,
a USBL fix of the station's transponder, late by its two-way travel time and
processing. The filter follows the error-state formulation (Solà 2017, *Quaternion
kinematics for the error-state Kalman filter*, §5 and §7; Groves 2013, *Principles of
GNSS, Inertial, and Multisensor Integrated Navigation Systems*, §14.2 and §16.2 on
DVL dead reckoning and §14.3.4 on delayed measurements):

* **Nominal state**: the position ``p`` (station frame), dead-reckoned with the AHRS
  attitude ``R(phi, theta, psi)`` and the DVL velocity ``v``::

      p_k = p_{k-1} + R_k v_k dt

  (without bottom lock the last locked velocity is held, with a larger process noise).
* **Error state** ``dp`` with covariance ``P``: ``dp_k = dp_{k-1} + w_k``, ``F = I``,
  ``Q = dt^2 R diag(s_v^2) R^T + q I`` (the DVL's noise carried by the attitude, and a
  random walk ``q`` for what the model leaves out: the scale-factor and heading errors).
* **Depth** ``d = z_s - p_z + n``: ``H = [0, 0, -1]``.
* **USBL** fix ``y = R_ping^T (t - p_ping) + n`` (``t`` the transponder, ``R_ping`` the
  attitude at the ping): ``H = -R_ping^T`` on the error at the ping. The fix arrives
  ``a`` seconds late (``usbl_age``); since ``F = I``, the error now is the error at the
  ping plus the process noise since, and the delayed update is taken through the state
  and covariance kept at the ping (Groves §14.3.4; exact for a fix on time, approximate
  by the depth updates made in between)::

      S = H P_ping H^T + R_y,  K = P_ping H^T S^-1
      p += K (y - h(p_ping)),  P -= K H P_ping

  with the measurement noise ``R_y = (sigma_0^2 + (k r)^2) I`` growing with range ``r``.
  A fix whose squared Mahalanobis distance exceeds the 99.9 % point of chi-square with
  three degrees of freedom (16.27) is rejected: the mirror-path and spurious fixes.
* The error is injected into the nominal state after each update and reset to zero
  (``P`` kept), as the error-state filter does.

The filter is pure functions of arrays (:class:`FilterParams`, :class:`FilterState`,
:func:`step`) over an array namespace: NumPy for :class:`NavigationFilter`, the stateful
object ``nav-homing-ofnmpc-ekf`` holds, and ``jax.numpy`` under ``jit`` and ``vmap`` for
the learners' front end (:mod:`baselines.rl.nav_filter`). So that it holds in float32 the
updates are written in forms that cancel nothing: the depth's covariance as
``P_zz R / (P_zz + R)``, and the USBL fix, whose ``H = -R_ping^T`` is orthogonal and whose
noise ``r I`` is isotropic, as the same measurement of the position ``t - R_ping y`` with
``H = I``; the last steps' states are a ring buffer of fixed length.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import stats

from auv_envs.core.frames import rotation_rows

#: Squared Mahalanobis distance beyond which a USBL fix is rejected: chi-square, 3 dof,
#: 99.9 % point (16.27).
USBL_GATE = float(stats.chi2.ppf(0.999, 3))
#: The ``usbl_age`` the filter remembers when no fix is valid.
NO_FIX_AGE = 1.0e9


class FilterParams(NamedTuple):
    """What the filter knows: the navigation suite's nominal figures (variances, m and
    m/s squared) and the step (s); :class:`NavigationFilter`'s arguments give them."""

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
    # dead reckoning (the prediction)
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
    # a late USBL fix, through the state at its ping
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
    # the fix as a position at the ping, with an isotropic noise (the module docstring)
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


def turned(state: FilterState, angle, centre, xp=np) -> FilterState:
    """``state`` with its world turned by ``angle`` (rad) about the vertical through
    ``centre`` (station frame): the estimate, its covariance, the kept states and the
    attitudes. A heading read off the station's frame by ``b`` turns the filter's whole
    world by ``b`` about the transponder (dead reckoning and fixes alike); learning ``b``
    later, the filter is turned back by it
    (:mod:`~baselines.docking.estimation.light_heading`)."""
    dtype = state.position.dtype
    angle = xp.asarray(angle, dtype)
    Rz = rotation(xp.stack([xp.zeros_like(angle), xp.zeros_like(angle), angle]), xp)
    centre = xp.asarray(centre, dtype)
    return state._replace(
        position=centre + Rz @ (state.position - centre),
        covariance=Rz @ state.covariance @ Rz.T,
        past_position=centre + (state.past_position - centre) @ Rz.T,
        past_covariance=Rz @ state.past_covariance @ Rz.T,
        past_rotation=Rz @ state.past_rotation)


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


class NavigationFilter:
    """The error-state filter of the module docstring, as an object that keeps its state.

    Args:
        transponder: the USBL transponder's position, station frame (m).
        surface_z: the surface's height in the station frame (m): depth = surface_z - z.
        dt: the step (s).
        dvl_std: the DVL's velocity noise (m/s).
        depth_std: the depth noise (m).
        usbl_std: ``(sigma_0, k)``: the fix's noise, ``sigma_0`` m plus ``k`` times the
            range.
        random_walk: the position random walk ``q`` (m^2 a step).
        initial_std: the position's standard deviation before the first fix (m).
        history: steps of nominal states and covariances kept for late fixes.
    """

    def __init__(self, transponder, surface_z: float, dt: float, dvl_std: float = 0.02,
                 depth_std: float = 0.014, usbl_std: tuple = (0.1, 0.015),
                 random_walk: float = 1e-4, initial_std: float = 1000.0, history: int = 50):
        self.params = FilterParams(
            tuple(float(v) for v in transponder), float(surface_z), float(dt),
            dvl_var=dvl_std**2, depth_var=depth_std**2, usbl_sigma0=usbl_std[0],
            usbl_k=usbl_std[1], random_walk=random_walk, initial_var=initial_std**2,
            history=history)
        self.reset()

    @classmethod
    def for_suite(cls, navigation, dt: float) -> NavigationFilter:
        """The filter for a navigation suite
        (``auv_envs.tasks.docking.navigation.NavigationSensors``) at step ``dt``: its
        transponder and station depth, its DVL's and depth sensor's data-sheet noise (the
        depth's at least 1 mm)."""
        return cls(navigation.transponder, navigation.station_depth, dt,
                   dvl_std=navigation.dvl.noise_std,
                   depth_std=max(navigation.depth.noise_std, 1e-3))

    def reset(self) -> None:
        self.state = FilterState.start(self.params)

    def step(self, observation: dict) -> np.ndarray:
        """Take one ``nav`` observation (after the step it describes); the position
        estimate."""
        self.state = step(self.params, self.state, observation)
        return self.state.position.copy()

    @property
    def p(self) -> np.ndarray:
        """The position estimate, station frame (m)."""
        return self.state.position

    @property
    def P(self) -> np.ndarray:
        """Its covariance (m^2)."""
        return self.state.covariance

    @property
    def fixes(self) -> int:
        """USBL fixes accepted this episode."""
        return int(self.state.fixes)

    @property
    def rejected(self) -> int:
        """USBL fixes the gate rejected this episode."""
        return int(self.state.rejected)
