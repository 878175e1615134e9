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

The law is one pure, branch-free function (:func:`pd_force`) over an array namespace ``xp``
passed explicitly: ``numpy`` for the agents on the CPU, ``jax.numpy`` under ``jit``/``vmap``
for batched labelling (a privileged teacher). :class:`DockingPDController` is its NumPy
wrapper with the original interface. :func:`read_state` and :func:`normalised_action` map
the ``state`` observation to the law's inputs and its force to the env's action; the homing
controller (:mod:`baselines.docking.control.homing`) shares them.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from auv_envs.core.frames import rotation_from_euler


class PDGains(NamedTuple):
    """Parameters of the PD law (:func:`pd_force`), built once.

    A ``NamedTuple`` so that JAX takes it as a pytree (it may be passed through ``jit``
    and ``vmap``, ``in_axes=None``) without this module importing JAX.

    Attributes:
        target: CG position at the docking point, DS frame (3,), m.
        buoyancy: the nominal model's net buoyancy ``B`` (N), fed forward in heave.
        kp: translational proportional gain (N/m).
        kd: translational derivative gain (N s/m).
        kp_yaw: heading proportional gain (N m/rad).
        kd_yaw: heading derivative gain (N m s/rad).
        max_axial_error: clip on the along-axis error (m; sets the approach speed).
        thrust_limits: ``(X, Y, Z, N)`` at full command (4,), which scale the force to the
            env's action (:func:`pd_action`); None where only the force is wanted.
    """

    target: Any
    buoyancy: float
    kp: float = 40.0
    kd: float = 140.0
    kp_yaw: float = 30.0
    kd_yaw: float = 60.0
    max_axial_error: float = 1.2
    thrust_limits: Any = None

    @classmethod
    def from_calibration(cls, calibration, **gains) -> PDGains:
        """The gains for a docking env: its documented calibration's target, nominal net
        buoyancy and thrust limits.

        Args:
            calibration: ``env.unwrapped.calibration``
                (:class:`auv_envs.tasks.docking.env.DockingCalibration`).
            **gains: ``kp``, ``kd``, ``kp_yaw``, ``kd_yaw``, ``max_axial_error``.
        """
        return cls(np.asarray(calibration.target_position, dtype=float),
                   calibration.nominal_params.net_buoyancy,
                   thrust_limits=np.asarray(calibration.thrust_limits, dtype=float), **gains)


def pd_force(gains: PDGains, position, yaw, body_velocity, yaw_rate, xp):
    """Generalized force ``(X, Y, Z, N)`` (N, N, N, N m) of the PD law, not clipped.

    One vehicle: a batch is ``jax.vmap`` of this function.

    Args:
        gains: the law's parameters.
        position: CG position, DS frame (3,).
        yaw: heading psi, rad (scalar).
        body_velocity: ``(u, v, w)``, body frame (3,).
        yaw_rate: ``r``, rad/s (scalar).
        xp: the array namespace, ``numpy`` or ``jax.numpy``.

    Returns:
        The force (4,).
    """
    # Heading-only rotation: the guidance treats the vehicle as level.
    rotation = rotation_from_euler(0.0, 0.0, yaw, xp)
    err = xp.asarray(gains.target) - position
    off_axis = xp.hypot(err[1], err[2])
    # Approach along the axis more slowly while far off it.
    axial_limit = gains.max_axial_error * xp.maximum(0.15, 1.0 - 2.0 * off_axis)
    err = xp.stack([xp.clip(err[0], -axial_limit, axial_limit), err[1], err[2]])
    force_world = gains.kp * err - gains.kd * (rotation @ body_velocity)
    force = rotation.T @ force_world
    torque = gains.kp_yaw * -yaw - gains.kd_yaw * yaw_rate
    return xp.stack([force[0], force[1], force[2] - gains.buoyancy, torque])


def read_state(state_obs, xp) -> tuple:
    """What the privileged controllers read of a docking env's ``state`` observation.

    Args:
        state_obs: one ``state`` observation: position ``[0:3]``, ``cos psi`` ``[5]``,
            ``sin psi`` ``[6]``, body velocity ``(u, v, w)`` ``[7:10]``, yaw rate ``r``
            ``[12]``.
        xp: the array namespace, ``numpy`` or ``jax.numpy``.

    Returns:
        ``(position (3,), yaw, body_velocity (3,), yaw_rate)``, in the namespace's default
        float (float64 for NumPy, float32 for JAX unless x64 is enabled).
    """
    obs = xp.asarray(state_obs, dtype=float)
    return obs[0:3], xp.arctan2(obs[6], obs[5]), obs[7:10], obs[12]


def normalised_action(force, thrust_limits, xp):
    """The env's action of a generalized force: ``force / thrust_limits`` clipped to
    ``[-1, 1]`` (the env scales its action by the thrust limits)."""
    return xp.clip(force / xp.asarray(thrust_limits), -1.0, 1.0)


def pd_action(gains: PDGains, state_obs, xp):
    """The PD law's normalised action on one ``state`` observation (:func:`read_state`).

    One observation: a batch is ``jax.vmap`` of this function.

    Args:
        gains: the law's parameters, with ``thrust_limits``
            (:meth:`PDGains.from_calibration`).
        state_obs: one ``state`` observation of a docking env.
        xp: the array namespace, ``numpy`` or ``jax.numpy``.

    Returns:
        The action (4,) in ``[-1, 1]``, in the namespace's default float.
    """
    force = pd_force(gains, *read_state(state_obs, xp), xp)
    return normalised_action(force, gains.thrust_limits, xp)


class DockingPDController:
    """PD position/heading controller in the DS frame, output in the body frame: :func:`pd_force`
    on NumPy.

    Args:
        target_position: CG position at the docking point, DS frame (m).
        net_buoyancy: the nominal model's net buoyancy ``B`` (N), fed forward in heave.
        kp, kd: translational gains (N/m, N s/m).
        kp_yaw, kd_yaw: heading gains (N m/rad, N m s/rad).
        max_axial_error: clip on the along-axis error (sets approach speed).
    """

    def __init__(self, target_position, net_buoyancy: float, kp=40.0, kd=140.0, kp_yaw=30.0,
                 kd_yaw=60.0, max_axial_error=1.2):
        self.gains = PDGains(np.asarray(target_position, dtype=float), net_buoyancy, kp=kp,
                             kd=kd, kp_yaw=kp_yaw, kd_yaw=kd_yaw,
                             max_axial_error=max_axial_error)

    def force(self, position: np.ndarray, yaw: float, body_velocity: np.ndarray,
              yaw_rate: float) -> np.ndarray:
        """Generalized force ``(X, Y, Z, N)`` (N, N, N, N m), not clipped.

        Args:
            position: CG position, DS frame (3,).
            yaw: heading psi, rad.
            body_velocity: ``(u, v, w)``, body frame (3,).
            yaw_rate: ``r``, rad/s.
        """
        return pd_force(self.gains, np.asarray(position, dtype=float), yaw,
                        np.asarray(body_velocity, dtype=float), yaw_rate, np)


__all__ = ["DockingPDController", "PDGains", "normalised_action", "pd_action", "pd_force",
           "read_state"]
