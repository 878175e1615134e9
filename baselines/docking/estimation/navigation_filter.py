"""Where the vehicle is, from its navigation sensors: an error-state Kalman filter.

The ``nav`` observation (:mod:`auv_envs.core.navigation`) gives an AHRS attitude and
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
"""

from __future__ import annotations

import collections
import math

import numpy as np
from scipy import stats

from auv_envs.core import frames

#: Squared Mahalanobis distance beyond which a USBL fix is rejected: chi-square, 3 dof,
#: 99.9 % point (16.27).
USBL_GATE = float(stats.chi2.ppf(0.999, 3))


class NavigationFilter:
    """The error-state filter of the module docstring.

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
        self.transponder = np.asarray(transponder, dtype=float)
        self.surface_z = float(surface_z)
        self.dt = float(dt)
        self.dvl_var = dvl_std**2
        self.depth_var = depth_std**2
        self.usbl_std = usbl_std
        self.random_walk = random_walk
        self.initial_std = initial_std
        self.history_steps = history
        self.reset()

    def reset(self) -> None:
        self.p = np.zeros(3)
        self.P = np.eye(3) * self.initial_std**2
        self.velocity = np.zeros(3)
        self.time = 0.0
        self.fixes = self.rejected = 0
        #: (time, nominal position, covariance, attitude) of the last steps, for late fixes.
        self.history: collections.deque = collections.deque(maxlen=self.history_steps)
        self._last_age = math.inf

    # ------------------------------------------------------------------ the filter
    def predict(self, rotation: np.ndarray, velocity, valid: bool) -> None:
        """Dead-reckon one step: ``rotation`` body to station frame, ``velocity`` the DVL's
        (body, m/s), ``valid`` its bottom lock (else the last locked velocity is held)."""
        noise = self.dvl_var
        if valid:
            self.velocity = np.asarray(velocity, dtype=float)
        else:
            noise = noise + 0.1**2  # held velocity: far less sure
        self.p = self.p + rotation @ self.velocity * self.dt
        self.P = self.P + self.dt**2 * noise * (rotation @ rotation.T) \
            + self.random_walk * np.eye(3)
        self.time += self.dt

    def update(self, H: np.ndarray, innovation: np.ndarray, R: np.ndarray,
               P_then: np.ndarray | None = None, gate: float | None = None) -> bool:
        """One update of the error state (``P_then``: the covariance at a late measurement's
        time, :meth:`update_usbl`), injected into the nominal state; False if gated out."""
        P_then = self.P if P_then is None else P_then
        S = H @ P_then @ H.T + R
        if gate is not None and float(innovation @ np.linalg.solve(S, innovation)) > gate:
            return False
        K = P_then @ H.T @ np.linalg.inv(S)
        self.p = self.p + K @ innovation  # inject dp, reset it to zero
        self.P = self.P - K @ H @ P_then
        self.P = 0.5 * (self.P + self.P.T)
        return True

    def update_depth(self, depth: float) -> None:
        H = np.array([[0.0, 0.0, -1.0]])
        self.update(H, np.array([depth - (self.surface_z - self.p[2])]),
                    np.array([[self.depth_var]]))

    def update_usbl(self, fix, age: float, rotation: np.ndarray) -> bool:
        """A USBL fix (body axes at the ping) measured ``age`` seconds ago (``rotation``
        the attitude now); False if rejected by the gate."""
        back = int(round(age / self.dt))
        if back == 0 or not self.history:
            p_then, P_then, rotation_then = self.p, self.P, rotation
        else:
            _, p_then, P_then, rotation_then = self.history[-min(back, len(self.history))]
        fix = np.asarray(fix, dtype=float)
        predicted = rotation_then.T @ (self.transponder - p_then)
        sigma0, k = self.usbl_std
        R = (sigma0**2 + (k * np.linalg.norm(fix))**2) * np.eye(3)
        accepted = self.update(-rotation_then.T, fix - predicted, R, P_then, gate=USBL_GATE)
        self.fixes += accepted
        self.rejected += not accepted
        return accepted

    # ------------------------------------------------------------------ observations
    def step(self, observation: dict) -> np.ndarray:
        """Take one ``nav`` observation (after the step it describes); the position
        estimate."""
        roll, pitch, yaw = (float(a) for a in observation["attitude"])
        rotation = np.array(frames.rotation_rows(roll, pitch, yaw))
        self.predict(rotation, observation["dvl_velocity"], bool(observation["dvl_valid"][0]))
        self.update_depth(float(observation["depth"][0]))
        valid = bool(observation["usbl_valid"][0])
        age = float(observation["usbl_age"][0])
        if valid and age < self._last_age:  # a new fix arrived
            self.update_usbl(observation["usbl"], age, rotation)
        self._last_age = age if valid else math.inf
        self.history.append((self.time, self.p.copy(), self.P.copy(), rotation))
        return self.p.copy()
