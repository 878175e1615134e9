"""Scripted PD reference controller for docking: the generalized force from the true state.

It proves the task is solvable and anchors the leaderboard between the random agent and the
paper baselines (agent ``pd-state``, :class:`baselines.docking.agents.DockingPDAgent`).

Guidance: hold heading 0 and drive the lateral/vertical errors to zero while closing the
distance along the docking axis at a speed that shrinks while the vehicle is off the axis;
the heave command feeds the nominal model's net buoyancy forward. With ``e = p_target - p``
(DS frame, ``e_x`` clipped to ``+-max_axial_error * max(0.15, 1 - 2 sqrt(e_y^2 + e_z^2))``)
and ``R(psi)`` the heading-only rotation::

    (X, Y, Z) = R(psi)^T (kp e - kd R(psi) (u, v, w)) - (0, 0, B)
    N = kp_yaw (0 - psi) - kd_yaw r
"""

from __future__ import annotations

import math

import numpy as np

from auv_envs.core.frames import rotation_from_euler


class DockingPDController:
    """PD position/heading controller in the DS frame, output in the body frame.

    Args:
        target_position: CG position at the docking point, DS frame (m).
        net_buoyancy: the nominal model's net buoyancy ``B`` (N), fed forward in heave.
        kp, kd: translational gains (N/m, N s/m).
        kp_yaw, kd_yaw: heading gains (N m/rad, N m s/rad).
        max_axial_error: clip on the along-axis error (sets approach speed).
    """

    def __init__(self, target_position, net_buoyancy: float, kp=40.0, kd=140.0, kp_yaw=30.0,
                 kd_yaw=60.0, max_axial_error=1.2):
        self._target = np.asarray(target_position, dtype=float)
        self._buoyancy = net_buoyancy
        self._gains = (kp, kd, kp_yaw, kd_yaw, max_axial_error)

    def force(self, position: np.ndarray, yaw: float, body_velocity: np.ndarray,
              yaw_rate: float) -> np.ndarray:
        """Generalized force ``(X, Y, Z, N)`` (N, N, N, N m), not clipped.

        Args:
            position: CG position, DS frame (3,).
            yaw: heading psi, rad.
            body_velocity: ``(u, v, w)``, body frame (3,).
            yaw_rate: ``r``, rad/s.
        """
        kp, kd, kp_yaw, kd_yaw, max_axial = self._gains
        # Heading-only rotation: the guidance treats the vehicle as level.
        rotation = rotation_from_euler(0.0, 0.0, yaw)
        err = self._target - position
        off_axis = math.hypot(err[1], err[2])
        # Approach along the axis more slowly while far off it.
        axial_limit = max_axial * max(0.15, 1.0 - 2.0 * off_axis)
        err[0] = float(np.clip(err[0], -axial_limit, axial_limit))
        vel_world = rotation @ body_velocity
        force_world = kp * err - kd * vel_world
        fx, fy, fz = rotation.T @ force_world
        fz -= self._buoyancy
        yaw_err = -yaw
        torque = kp_yaw * yaw_err - kd_yaw * yaw_rate
        return np.array([fx, fy, fz, torque])


__all__ = ["DockingPDController"]
