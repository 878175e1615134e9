"""Line-of-sight homing to a docking station's axis, then the PD terminal controller.

The privileged reference of ``auv_envs/DockingMission-v0`` (agent ``homing-pd-state``,
:class:`baselines.docking.agents.HomingPDAgent`): it reads the true state and proves the
whole approach can be flown. Guidance (Fossen 2011, *Handbook of Marine Craft
Hydrodynamics and Motion Control*, §10.3: line-of-sight guidance to a waypoint):

* the waypoint is the staging point ``S`` on the docking axis, ``staging`` m in front of
  the entrance at the entrance's height; a vehicle beside or behind the station
  (``x > -staging`` and ``|y| < clearance``) first goes to ``(-staging, +-clearance)``
  on its own side, round the station;
* heading: the line of sight to the waypoint, ``psi_d = atan2(y_w - y, x_w - x)``;
* surge: ``X = k_u (u_d - u)`` with ``u_d = min(cruise, distance / time_to_go)``; sway
  ``Y = -k_v v``; heave ``Z = kp_z e_z - kd_z w - B`` (``e_z`` the height error, clipped
  to +-2 m, ``B`` the nominal net buoyancy fed forward); yaw ``N = kp_yaw (psi_d - psi) -
  kd_yaw r``;
* within ``capture`` m of ``S`` (heading within 0.5 rad of the axis) it hands over to
  the PD law (:func:`~baselines.docking.control.pd.pd_force`) for good.

The laws are pure, branch-free functions over an array namespace ``xp`` passed explicitly
(``numpy``, or ``jax.numpy`` under ``jit``/``vmap``): :func:`homing_force` takes the
hand-over latch and returns it updated, and :func:`homing_action` maps one ``state``
observation to the env's normalised action, so the same teacher labels thousands of batched
environments per compiled step (DAgger). :class:`HomingPDController` is the NumPy wrapper
that keeps the latch between calls.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from auv_envs.core.frames import wrap_angle
from baselines.docking.control.pd import PDGains, normalised_action, pd_force, read_state

#: Largest heading error (rad) from the docking axis at which homing hands over.
HANDOVER_HEADING = 0.5
#: The approach corridor's half-width (m; :func:`in_corridor`): twice the staging point's
#: capture distance.
CORRIDOR_WIDTH = 3.0
#: How far the approach corridor (:func:`in_corridor`) runs on past the docking point along
#: the axis (m): a hull whose nose is in the funnel is never handed back to homing.
CORRIDOR_BEYOND = 1.0
#: Within this distance of the docking point along the axis (m; about the hull's length,
#: 1.8 m, and the funnel's depth) the corridor holds at any heading: there homing's turn
#: towards its waypoint sweeps the hull into the funnel's petals, where it is held
#: (MuJoCo's contacts in the CPU environment).
STATION_ZONE = 2.0


class HomingGains(NamedTuple):
    """Parameters of the homing law (:func:`homing_force`), built once
    (:meth:`build`, :meth:`from_calibration`).

    A ``NamedTuple`` so that JAX takes it as a pytree (it may be passed through ``jit``
    and ``vmap``, ``in_axes=None``) without this module importing JAX.

    Attributes:
        target: CG position at the docking point, DS frame (3,), m.
        staging_point: the staging point ``S`` on the docking axis, DS frame (3,), m.
        buoyancy: the nominal model's net buoyancy ``B`` (N), fed forward in heave.
        terminal: the PD law's parameters, used from the hand-over on.
        thrust_limits: ``(X, Y, Z, N)`` at full command (4,), which scale the force to the
            env's action (:func:`homing_action`); None where only the force is wanted.
        clearance: lateral distance to pass the station at (m).
        cruise: homing speed (m/s).
        capture: distance from the staging point where the terminal law takes over (m).
        k_u: surge speed gain (N s/m).
        k_v: sway damping gain (N s/m).
        kp_z, kd_z: heave gains (N/m, N s/m).
        kp_yaw, kd_yaw: heading gains (N m/rad, N m s/rad).
        time_to_go: the speed command's horizon, ``u_d = distance / time_to_go`` near the
            waypoint (s).
    """

    target: Any
    staging_point: Any
    buoyancy: float
    terminal: PDGains
    thrust_limits: Any = None
    clearance: float = 12.0
    cruise: float = 1.0
    capture: float = 1.5
    k_u: float = 80.0
    k_v: float = 60.0
    kp_z: float = 40.0
    kd_z: float = 140.0
    kp_yaw: float = 30.0
    kd_yaw: float = 60.0
    time_to_go: float = 4.0

    @classmethod
    def build(cls, target_position, net_buoyancy: float, thrust_limits=None,
              staging: float = 10.0, **gains) -> HomingGains:
        """The gains from the station's geometry.

        Args:
            target_position: CG position at the docking point, DS frame (m).
            net_buoyancy: the nominal model's net buoyancy (N).
            thrust_limits: ``(X, Y, Z, N)`` at full command, or None (force only).
            staging: distance of the staging point in front of the entrance (m).
            **gains: any of the remaining fields (``clearance``, ``cruise``, ``capture``,
                ``k_u``, ...; ``terminal`` to replace the PD law's default gains).
        """
        target = np.asarray(target_position, dtype=float)
        limits = None if thrust_limits is None else np.asarray(thrust_limits, dtype=float)
        terminal = gains.pop("terminal", None) or PDGains(target, net_buoyancy,
                                                          thrust_limits=limits)
        return cls(target, np.array([target[0] - staging, 0.0, target[2]]), net_buoyancy,
                   terminal, limits, **gains)

    @classmethod
    def from_calibration(cls, calibration, **overrides) -> HomingGains:
        """The gains for a docking env: its documented calibration's target, nominal net
        buoyancy and thrust limits.

        Args:
            calibration: ``env.unwrapped.calibration``
                (:class:`auv_envs.tasks.docking.env.DockingCalibration`).
            **overrides: :meth:`build`'s keywords (``staging``, ``clearance``, ...).
        """
        return cls.build(calibration.target_position, calibration.nominal_params.net_buoyancy,
                         calibration.thrust_limits, **overrides)


def staging_waypoint(gains: HomingGains, position, xp):
    """Where homing steers now: the staging point, or, for a vehicle beside or behind the
    station, the point ``clearance`` m to its side first (round the station).

    Args:
        gains: the law's parameters.
        position: CG position, DS frame (3,).
        xp: the array namespace, ``numpy`` or ``jax.numpy``.

    Returns:
        The waypoint, DS frame (3,).
    """
    staging = xp.asarray(gains.staging_point)
    x, y = position[0], position[1]
    around = (x > staging[0] + 1.0) & (xp.abs(y) < gains.clearance)
    side = xp.where(y >= 0.0, 1.0, -1.0)
    return xp.stack([staging[0], xp.where(around, side * gains.clearance, staging[1]),
                     staging[2]])


def homing_force(gains: HomingGains, position, yaw, body_velocity, yaw_rate, docking, xp):
    """Generalized force ``(X, Y, Z, N)`` (N, N, N, N m) of homing then the terminal PD law,
    not clipped, and the hand-over latch.

    Both laws are evaluated and the latch selects one, so the function has no branch (it
    runs under ``jax.jit``). One vehicle: a batch is ``jax.vmap`` of this function.

    Args:
        gains: the law's parameters.
        position: CG position, DS frame (3,).
        yaw: heading psi, rad (scalar).
        body_velocity: ``(u, v, w)``, body frame (3,).
        yaw_rate: ``r``, rad/s (scalar).
        docking: the latch, a bool (scalar): the terminal law has taken over. False at an
            episode's start.
        xp: the array namespace, ``numpy`` or ``jax.numpy``.

    Returns:
        ``(force (4,), docking)``: the latch set once the vehicle is within ``capture`` of
        the staging point with its heading within :data:`HANDOVER_HEADING` of the axis,
        and never cleared.
    """
    offset = xp.asarray(gains.staging_point) - position
    docking = docking | ((xp.linalg.norm(offset) < gains.capture)
                         & (xp.abs(wrap_angle(yaw)) < HANDOVER_HEADING))
    terminal = pd_force(gains.terminal, position, yaw, body_velocity, yaw_rate, xp)
    to = staging_waypoint(gains, position, xp) - position
    distance = xp.hypot(to[0], to[1])
    # Near the staging point, turn to the docking axis (heading 0) instead of the LOS.
    heading = xp.where(distance > gains.capture, xp.arctan2(to[1], to[0]), 0.0)
    speed = xp.minimum(gains.cruise, distance / gains.time_to_go)
    heading_error = wrap_angle(heading - yaw)
    height = xp.clip(to[2], -2.0, 2.0)
    homing = xp.stack([
        gains.k_u * (speed * xp.maximum(0.0, xp.cos(heading_error)) - body_velocity[0]),
        -gains.k_v * body_velocity[1],
        gains.kp_z * height - gains.kd_z * body_velocity[2] - gains.buoyancy,
        gains.kp_yaw * heading_error - gains.kd_yaw * yaw_rate,
    ])
    return xp.where(docking, terminal, homing), docking


def in_corridor(gains: HomingGains, position, yaw, width: float, xp,
                beyond: float = CORRIDOR_BEYOND, zone: float = STATION_ZONE):
    """Whether the vehicle is in the approach corridor: along the docking axis from the
    staging point's capture distance to ``beyond`` past the docking point, within
    ``width`` m of the axis sideways and in height, and heading within
    :data:`HANDOVER_HEADING` of it except in the last ``zone`` m, where any heading is in.
    A hand-over decided by the state alone: the terminal law holds there, homing
    elsewhere, with no latch to remember (a student that imitates this law need not infer
    one). The corridor runs into the funnel, and holds there at any heading, because
    homing's turn to its waypoint from a hull at the entrance pins the hull on the funnel
    (the CPU environment's contacts; ``homing-pd-state``, whose latch never lets go, does
    not meet this).

    Args:
        gains: the law's parameters.
        position: CG position, DS frame (3,).
        yaw: heading psi, rad (scalar).
        width: the corridor's half-width, m (at least ``capture``, so that the latch's
            own condition lies inside it).
        xp: the array namespace.
        beyond: how far the corridor runs on past the docking point (m);
            :data:`CORRIDOR_BEYOND` (0: it ends at the docking point).
        zone: the distance before the docking point within which any heading is in (m);
            :data:`STATION_ZONE` (0: the heading counts everywhere).
    """
    staging, target = xp.asarray(gains.staging_point), xp.asarray(gains.target)
    aligned = ((xp.abs(wrap_angle(yaw)) < HANDOVER_HEADING)
               | (position[0] >= target[0] - zone))
    return ((position[0] >= staging[0] - gains.capture)
            & (position[0] <= target[0] + beyond)
            & (xp.abs(position[1] - target[1]) <= width)
            & (xp.abs(position[2] - target[2]) <= width)
            & aligned)


def corridor_action(gains: HomingGains, state_obs, xp, width: float = CORRIDOR_WIDTH,
                    beyond: float = CORRIDOR_BEYOND, zone: float = STATION_ZONE):
    """The corridor teacher's law (``homing-pd-corridor``): :func:`homing_action` on one
    ``state`` observation with the hand-over :func:`in_corridor` decides instead of a latch.
    One observation: a batch is ``jax.vmap`` of this function.

    Args:
        gains: the law's parameters, with ``thrust_limits``.
        state_obs: one ``state`` observation of ``auv_envs/DockingMission-v0``.
        xp: the array namespace.
        width, beyond, zone: :func:`in_corridor`'s.

    Returns:
        The action (4,) in ``[-1, 1]``.
    """
    position, yaw, _, _ = read_state(state_obs, xp)
    corridor = in_corridor(gains, position, yaw, width, xp, beyond=beyond, zone=zone)
    return homing_action(gains, state_obs, corridor, xp)[0]


def homing_action(gains: HomingGains, state_obs, docking, xp):
    """The privileged teacher: the normalised action of :func:`homing_force` on one
    ``state`` observation of ``auv_envs/DockingMission-v0``, and the updated latch.

    One observation and one latch (scalar): label a batch with ``jax.vmap``, e.g.
    ``jax.jit(jax.vmap(functools.partial(homing_action, gains, xp=jnp)))(obs, docking)``
    for observations ``(n, obs_dim)`` and latches ``(n,)``; reset a latch to False where
    its episode restarts.

    Args:
        gains: the law's parameters, with ``thrust_limits``
            (:meth:`HomingGains.from_calibration`).
        state_obs: one ``state`` observation (read by
            :func:`~baselines.docking.control.pd.read_state`).
        docking: the latch (bool scalar), False at an episode's start.
        xp: the array namespace, ``numpy`` or ``jax.numpy``.

    Returns:
        ``(action (4,) in [-1, 1], docking)``, the action in the namespace's default float.
    """
    force, docking = homing_force(gains, *read_state(state_obs, xp), docking, xp)
    return normalised_action(force, gains.thrust_limits, xp), docking


class HomingPDController:
    """Homing then terminal docking on the true state (module docstring): :func:`homing_force`
    on NumPy, keeping the latch between calls.

    Args:
        target_position: CG position at the docking point, DS frame (m).
        net_buoyancy: the nominal model's net buoyancy (N), fed forward in heave.
        staging: distance of the staging point in front of the entrance (m).
        clearance: lateral distance to pass the station at (m).
        cruise: homing speed (m/s).
        capture: distance from the staging point where the terminal controller takes
            over (m).
        k_u, k_v, kp_z, kd_z, kp_yaw, kd_yaw, time_to_go: the gains (:class:`HomingGains`).
    """

    def __init__(self, target_position, net_buoyancy: float, staging: float = 10.0,
                 clearance: float = 12.0, cruise: float = 1.0, capture: float = 1.5,
                 k_u: float = 80.0, k_v: float = 60.0, kp_z: float = 40.0, kd_z: float = 140.0,
                 kp_yaw: float = 30.0, kd_yaw: float = 60.0, time_to_go: float = 4.0):
        self.gains = HomingGains.build(
            target_position, net_buoyancy, staging=staging, clearance=clearance,
            cruise=cruise, capture=capture, k_u=k_u, k_v=k_v, kp_z=kp_z, kd_z=kd_z,
            kp_yaw=kp_yaw, kd_yaw=kd_yaw, time_to_go=time_to_go)
        self.docking = False

    def reset(self) -> None:
        self.docking = False

    def waypoint(self, position: np.ndarray) -> np.ndarray:
        """Where homing steers now: the staging point, or round the station first."""
        return staging_waypoint(self.gains, np.asarray(position, dtype=float), np)

    def force(self, position: np.ndarray, yaw: float, body_velocity: np.ndarray,
              yaw_rate: float) -> np.ndarray:
        """Generalized force ``(X, Y, Z, N)`` (N, N, N, N m), not clipped."""
        force, docking = homing_force(self.gains, np.asarray(position, dtype=float), yaw,
                                      np.asarray(body_velocity, dtype=float), yaw_rate,
                                      self.docking, np)
        self.docking = bool(docking)
        return force


__all__ = ["HANDOVER_HEADING", "HomingGains", "HomingPDController", "homing_action",
           "homing_force", "staging_waypoint"]
