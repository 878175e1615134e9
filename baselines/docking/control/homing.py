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
  :class:`~baselines.docking.control.pd.DockingPDController` for good.
"""

from __future__ import annotations

import math

import numpy as np

from auv_envs.core.frames import wrap_angle
from baselines.docking.control.pd import DockingPDController


class HomingPDController:
    """Homing then terminal docking on the true state (module docstring).

    Args:
        target_position: CG position at the docking point, DS frame (m).
        net_buoyancy: the nominal model's net buoyancy (N), fed forward in heave.
        staging: distance of the staging point in front of the entrance (m).
        clearance: lateral distance to pass the station at (m).
        cruise: homing speed (m/s).
        capture: distance from the staging point where the terminal controller takes
            over (m).
    """

    def __init__(self, target_position, net_buoyancy: float, staging: float = 10.0,
                 clearance: float = 12.0, cruise: float = 1.0, capture: float = 1.5,
                 k_u: float = 80.0, k_v: float = 60.0, kp_z: float = 40.0, kd_z: float = 140.0,
                 kp_yaw: float = 30.0, kd_yaw: float = 60.0, time_to_go: float = 4.0):
        self.target = np.asarray(target_position, dtype=float)
        self.buoyancy = net_buoyancy
        self.terminal = DockingPDController(self.target, net_buoyancy)
        self.staging = np.array([self.target[0] - staging, 0.0, self.target[2]])
        self.clearance, self.cruise, self.capture = clearance, cruise, capture
        self.gains = (k_u, k_v, kp_z, kd_z, kp_yaw, kd_yaw, time_to_go)
        self.docking = False

    def reset(self) -> None:
        self.docking = False

    def waypoint(self, position: np.ndarray) -> np.ndarray:
        """Where homing steers now: the staging point, or round the station first."""
        x, y, _ = position
        if x > self.staging[0] + 1.0 and abs(y) < self.clearance:
            side = 1.0 if y >= 0.0 else -1.0
            return np.array([self.staging[0], side * self.clearance, self.staging[2]])
        return self.staging

    def force(self, position: np.ndarray, yaw: float, body_velocity: np.ndarray,
              yaw_rate: float) -> np.ndarray:
        """Generalized force ``(X, Y, Z, N)`` (N, N, N, N m), not clipped."""
        position = np.asarray(position, dtype=float)
        offset = self.staging - position
        if not self.docking and np.linalg.norm(offset) < self.capture \
                and abs(wrap_angle(yaw)) < 0.5:
            self.docking = True
        if self.docking:
            return self.terminal.force(position, yaw, body_velocity, yaw_rate)
        k_u, k_v, kp_z, kd_z, kp_yaw, kd_yaw, time_to_go = self.gains
        to = self.waypoint(position) - position
        distance = math.hypot(to[0], to[1])
        # Near the staging point, turn to the docking axis (heading 0) instead of the LOS.
        heading = math.atan2(to[1], to[0]) if distance > self.capture else 0.0
        speed = min(self.cruise, distance / time_to_go)
        u, v, w = body_velocity
        height = float(np.clip(to[2], -2.0, 2.0))
        return np.array([
            k_u * (speed * max(0.0, math.cos(wrap_angle(heading - yaw))) - u),
            -k_v * v,
            kp_z * height - kd_z * w - self.buoyancy,
            kp_yaw * wrap_angle(heading - yaw) - kd_yaw * yaw_rate,
        ])


__all__ = ["HomingPDController"]
