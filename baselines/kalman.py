"""Kalman-filter pieces shared by the baselines' filters.

Used by the docking EKF and MHE arrival cost (:mod:`baselines.docking.estimation.observers`),
the lamp-array blob and camera filters (:mod:`baselines.docking.perception.lamp_tracking`,
:mod:`baselines.docking.estimation.camera_position`), and
the acoustic GM-PHD update and ``ls-kf`` filter (:mod:`baselines.acoustic`).
Everything broadcasts over leading axes, so one call can update a bank of filters.
"""

from __future__ import annotations

import numpy as np


def kalman_gain(cov: np.ndarray, jacobian: np.ndarray, noise_cov: np.ndarray) -> np.ndarray:
    """``K = P H^T (H P H^T + R)^-1`` ([OFNMPC] eqs. 26-28), by a linear solve.

    Args:
      cov: (..., n, n) predicted P; jacobian: (..., m, n) H; noise_cov: (..., m, m) R.
        Leading axes broadcast.

    Returns:
      (..., n, m) gains.
    """
    s = jacobian @ cov @ np.swapaxes(jacobian, -1, -2) + noise_cov
    return np.swapaxes(np.linalg.solve(s, jacobian @ cov), -1, -2)


def joseph_covariance(cov: np.ndarray, gain: np.ndarray, jacobian: np.ndarray,
                      noise_cov: np.ndarray) -> np.ndarray:
    """Updated covariance in Joseph form, ``(I - K H) P (I - K H)^T + K R K^T``.

    The same as ``(I - K H) P`` in exact arithmetic; stays symmetric positive
    definite in floating point (the short form lost that after ~23 s of an
    acoustic episode with centimetre-precise fixes).

    Args:
      cov: (..., n, n) predicted P; gain: (..., n, m) K; jacobian: (..., m, n) H;
        noise_cov: (..., m, m) R. Leading axes broadcast.

    Returns:
      (..., n, n) updated covariances.
    """
    i_kh = np.eye(cov.shape[-1]) - gain @ jacobian
    return i_kh @ cov @ np.swapaxes(i_kh, -1, -2) + gain @ noise_cov @ np.swapaxes(gain, -1, -2)


def constant_velocity_blocks(dt: float, accel_std: float) -> tuple[np.ndarray, np.ndarray]:
    """One axis of the constant-velocity model: transition ``[[1, dt], [0, 1]]`` and the
    white-noise-acceleration covariance ``accel_std^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]``."""
    f = np.array([[1.0, dt], [0.0, 1.0]])
    q = accel_std**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
    return f, q
