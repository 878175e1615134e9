"""Per-lamp tracking state of [LAMP] (§2.2.3): one EKF per lamp on its blob features.

* :class:`BlobEKF` - the EKF on one lamp's blob ([LAMP] §2.2.3 1)).
* :class:`LampTrackerParams` - the tracker's noise, gates and thresholds.
* :class:`LampTracks` - every lamp's track after a frame, with a status code
  (:data:`UNINITIALISED`, :data:`DETECTED`, :data:`MERGED`, :data:`PREDICTED`).

The front end that drives them frame by frame (assignment, rigid-array prediction, identity)
is :class:`baselines.docking.perception.front_end.LampArrayFrontEnd`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from baselines.kalman import constant_velocity_blocks, joseph_covariance, kalman_gain

#: Track status codes (:attr:`LampTracks.status`).
UNINITIALISED, DETECTED, MERGED, PREDICTED = 0, 1, 2, 3
STATUS_NAMES = ("uninitialised", "detected", "merged", "predicted")


class BlobEKF:
    """EKF on one lamp's blob features ([LAMP] §2.2.3 1)).

    State ``x = (u, v, du, dv, s, ds)``: blob centre (px), its velocity (px/s), the lamp's
    apparent radius ``s`` (px) and its rate, each pair a constant-velocity model. Measurement
    ``z = (u, v, area, w, h)``: the blob's centre, area and bounding-box sides. A lamp is a
    sphere, so its blob is a disc: ``area = pi s^2`` and ``w = h = 2 s`` -- the nonlinear
    measurement function whose Jacobian the update linearises.

    Process model: each pair ``(u, du)``, ``(v, dv)``, ``(s, ds)`` is a constant-velocity
    model with white-noise acceleration (``accel_sigma`` for the centre, ``size_accel_sigma``
    for the radius; :meth:`transition`)::

        F_1 = [[1, dt], [0, 1]],   Q_1 = sigma_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]

    Measurement model and update (:meth:`measure`, :meth:`update`)::

        h(x) = (u, v, pi s^2, 2 s, 2 s),   H = dh/dx
        x_k|k-1 = F x_{k-1},   P_k|k-1 = F P_{k-1} F^T + Q
        K = P H^T (H P H^T + R)^-1,   x = x + K (z - h(x)),
        P = (I - K H) P (I - K H)^T + K R K^T,   then s = max(s, 0.5)

    :meth:`update_position` is the same correction with ``H`` the rows of ``(u, v)``
    (a position pseudo-measurement, e.g. the rigid array's prediction).
    """

    def __init__(self, x0: np.ndarray, p0: np.ndarray):
        self.x = np.asarray(x0, dtype=float).copy()
        self.P = np.asarray(p0, dtype=float).copy()

    @property
    def position(self) -> np.ndarray:
        return self.x[0:2].copy()

    @property
    def position_cov(self) -> np.ndarray:
        return self.P[0:2, 0:2].copy()

    @staticmethod
    def transition(dt: float, accel_sigma: float,
                   size_accel_sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """Transition matrix F and process noise Q over ``dt`` s (accelerations in px/s^2)."""
        f_pos, q_pos = constant_velocity_blocks(dt, accel_sigma)
        f_size, q_size = constant_velocity_blocks(dt, size_accel_sigma)
        F = np.zeros((6, 6))
        Q = np.zeros((6, 6))
        for idx, (f, q) in zip(((0, 2), (1, 3), (4, 5)), ((f_pos, q_pos), (f_pos, q_pos),
                                                           (f_size, q_size)), strict=True):
            F[np.ix_(idx, idx)] = f
            Q[np.ix_(idx, idx)] = q
        return F, Q

    def predict(self, F: np.ndarray, Q: np.ndarray) -> None:
        """Prediction with :meth:`transition`'s matrices."""
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q

    @staticmethod
    def measure(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``h(x)`` and its Jacobian."""
        s = x[4]
        h = np.array([x[0], x[1], math.pi * s * s, 2.0 * s, 2.0 * s])
        H = np.zeros((5, 6))
        H[0, 0] = H[1, 1] = 1.0
        H[2, 4] = 2.0 * math.pi * s
        H[3, 4] = H[4, 4] = 2.0
        return h, H

    def update(self, z: np.ndarray, R: np.ndarray, rows=slice(None)) -> None:
        """EKF update with the measurement rows ``rows`` of ``(u, v, area, w, h)``."""
        h, H = self.measure(self.x)
        self._correct(np.asarray(z)[rows] - h[rows], H[rows], np.asarray(R)[rows][:, rows])

    def update_position(self, uv: np.ndarray, cov: np.ndarray) -> None:
        """Linear update with a position-only (pseudo-)measurement."""
        H = np.zeros((2, 6))
        H[0, 0] = H[1, 1] = 1.0
        self._correct(np.asarray(uv) - self.x[0:2], H, cov)

    def _correct(self, innovation: np.ndarray, H: np.ndarray, R: np.ndarray) -> None:
        K = kalman_gain(self.P, H, R)
        self.x = self.x + K @ innovation
        self.P = joseph_covariance(self.P, K, H, R)
        self.x[4] = max(self.x[4], 0.5)


@dataclasses.dataclass(frozen=True)
class LampTrackerParams:
    """Lamp-tracking parameters (our defaults, tuned on seeded renders, not on test data).

    Attributes:
        pixel_sigma: noise of a blob centre, px.
        accel_sigma: white-noise acceleration of a lamp in the image, px/s^2.
        size_accel_sigma: same for the apparent radius, px/s^2.
        rigid_sigma: floor on the rigid-array prediction's noise, px (attitude noise, model).
        velocity_sigma: error of the camera displacement per step from the DVL, m/s.
        gate_chi2: Mahalanobis^2 gate of a lamp-detection pair (2 dof).
        gate_px: largest distance of a pair, px.
        merge_margin: an unmatched lamp predicted this close to a blob's circle is inside it, px.
        init_max_residual: largest RMS reprojection error of the array at initialisation, px.
        lost_after: frames without any detection after which the tracks are dropped and the
            array must be initialised again.
        centre_halo: a lamp is seen when the (2 halo + 1)^2 pixels around the array's
            prediction of its centre are all lamp-bright.
        ring_init_min: lights of a ring that must be detected to initialise (the L-shaped
            array needs all four, as in [LAMP]).
    """

    pixel_sigma: float = 0.7
    accel_sigma: float = 150.0
    size_accel_sigma: float = 20.0
    rigid_sigma: float = 2.0
    velocity_sigma: float = 0.05
    gate_chi2: float = 16.0
    gate_px: float = 40.0
    merge_margin: float = 2.0
    init_max_residual: float = 8.0
    lost_after: int = 300
    centre_halo: int = 1
    ring_init_min: int = 4

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.type in (int, "int"):
                low = {"centre_halo": 0, "ring_init_min": 3}.get(field.name, 1)
                if not (isinstance(value, int) and value >= low):
                    raise ValueError(f"{field.name} must be an integer >= {low}, got {value!r}")
            elif not (math.isfinite(value) and value > 0):
                raise ValueError(f"{field.name} must be finite and > 0, got {value}")


@dataclasses.dataclass(frozen=True)
class LampTracks:
    """Every lamp's track after a frame.

    Attributes:
        labels: lamp names in calibration order.
        pixels: (n, 2) corrected position of each lamp (a prediction unless detected), px;
            NaN before initialisation or behind the camera.
        radii: (n,) apparent radius, px (NaN before initialisation).
        status: (n,) one of UNINITIALISED, DETECTED, MERGED, PREDICTED.
    """

    labels: tuple[str, ...]
    pixels: np.ndarray
    radii: np.ndarray
    status: np.ndarray

    @property
    def reported(self) -> np.ndarray:
        """Lamps reported visible (detected alone or inside a merged blob)."""
        return (self.status == DETECTED) | (self.status == MERGED)


__all__ = [
    "DETECTED",
    "MERGED",
    "PREDICTED",
    "STATUS_NAMES",
    "UNINITIALISED",
    "BlobEKF",
    "LampTrackerParams",
    "LampTracks",
]
