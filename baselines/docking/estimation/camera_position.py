"""The rigid-array observer of the lamp tracker: an EKF on the camera position [LAMP].

[LAMP] §2.2.3 2) weighs each lamp's own prediction with the lamp's position predicted by the
rigid array. [LAMP] does not say how that prediction is made; ours is
:class:`CameraPositionFilter`, a small EKF on the camera centre in the array's (DS) frame, fed
by the INS attitude and DVL velocity that the observation carries and by the tracked lamps.
Each update also estimates that frame's INS attitude error. It keeps out-of-view lamps
predicted where the array puts them, so they are re-acquired under the right label.
"""

from __future__ import annotations

import math

import numpy as np

from auv_envs.core.camera import CameraIntrinsics
from baselines.kalman import joseph_covariance, kalman_gain


def _skew(v: np.ndarray) -> np.ndarray:
    """Matrices [v]x of the rows of ``v`` (n, 3) -> (n, 3, 3), with [v]x w = v x w."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


class CameraPositionFilter:
    """EKF on the camera centre in the array's (DS) frame: the rigid-array observer.

    The camera rotation comes from the INS attitude of each observation (``set_rotation``), so
    the unknown of the array's rigid-body pose is the camera position ``t``. It is propagated
    with the DVL displacement and corrected with the pixel centres of the tracked lamps through
    the pinhole model; projecting the array from it predicts every lamp, in view or not.

    The INS attitude is noisy (``attitude_sigma``, white from frame to frame), and 0.2 deg is
    2 px at this camera's focal length; each update therefore also estimates that frame's
    small camera rotation error ``dtheta`` (prior N(0, attitude_sigma^2 I), forgotten at the
    next frame), and projections use it until then.

    Model (ours; [LAMP] §2.2.3 2) only asks for the array's rigid-body prediction).
    ``R_k`` is the measured camera-to-DS rotation of frame k (INS attitude times the
    extrinsics), ``p_i`` lamp i in the DS frame, ``K`` the pinhole intrinsics::

        process      t_k = t_{k-1} + Delta_k + q_k,       q_k ~ N(0, sigma_Delta^2 I)
                     (Delta_k: the DVL/INS camera displacement, given by the caller)
        camera pt    c_i = R_k^T (p_i - t),   c_i' = c_i + [c_i]x dtheta
        pixel        h_i(t, dtheta) = (f_x X'/Z' + c_x, f_y Y'/Z' + c_y),  (X', Y', Z') = c_i'
        measurement  z_g = (1/|g|) sum_{i in g} h_i(t, dtheta) + v_g,  v_g ~ N(0, sigma_g^2 I_2)
                     (g: the lamps in one blob; one, or several when merged)

    Prediction (:meth:`predict`)::

        t_k|k-1 = t_{k-1} + Delta_k,     P_k|k-1 = P_{k-1} + sigma_Delta^2 I

    Update (:meth:`update`), an iterated EKF on ``x = (t, dtheta)`` with prior
    ``x_bar = (t_k|k-1, 0)``, ``P_bar = diag(P_k|k-1, attitude_sigma^2 I)``, relinearised at
    each iterate ``x_j``::

        H_j = dh/dx (x_j),   K_j = P_bar H_j^T (H_j P_bar H_j^T + R)^-1
        x_{j+1} = x_bar + K_j (z - h(x_j) - H_j (x_bar - x_j))
        P = (I - K H) P_bar (I - K H)^T + K R K^T       (Joseph form, last K and H)

    ``t`` and ``dtheta`` take the last iterate; ``P`` keeps its ``t`` block. The lamps'
    predicted pixel covariance (:meth:`prediction_cov`) is
    ``J_t,i P J_t,i^T + attitude_sigma^2 J_theta,i J_theta,i^T``.

    Initialisation (:meth:`initialise`): each labelled pixel's ray passes through its lamp, so
    with ``m_1, m_2, m_3`` the rows of ``R_k^T`` and ``x_n = (u - c_x)/f_x``,
    ``y_n = (v - c_y)/f_y``, the collinearity equations
    ``(x_n m_3 - m_1)^T (p_i - t) = 0`` and ``(y_n m_3 - m_2)^T (p_i - t) = 0`` are linear in
    ``t`` (least squares); three Gauss-Newton steps on the pixel error follow, and
    ``P = (J^T J / sigma^2 + 1e-6 I)^-1``.

    Args:
        intrinsics: camera intrinsics.
        points: (n, 3) lamp positions in the DS frame.
    """

    def __init__(self, intrinsics: CameraIntrinsics, points: np.ndarray):
        self.intrinsics = intrinsics
        self.points = np.asarray(points, dtype=float)
        self.t = np.zeros(3)
        self.P = np.eye(3)
        self.dtheta = np.zeros(3)
        self.attitude_sigma = 0.0
        self.world_to_cam = np.eye(3)

    def set_rotation(self, cam_to_world: np.ndarray, attitude_sigma: float = 0.0) -> None:
        """The new frame's measured camera rotation and its noise (rad); clears ``dtheta``."""
        self.world_to_cam = np.asarray(cam_to_world).T
        self.attitude_sigma = float(attitude_sigma)
        self.dtheta = np.zeros(3)

    def project(self, t: np.ndarray | None = None, dtheta: np.ndarray | None = None):
        """Pixels (n, 2), Jacobians d pixel / d t and d pixel / d dtheta (n, 2, 3 each) and
        the in-front mask (n,)."""
        k = self.intrinsics
        t = self.t if t is None else t
        dtheta = self.dtheta if dtheta is None else dtheta
        measured = (self.points - t) @ self.world_to_cam.T
        skew = _skew(measured)
        cam = measured + skew @ dtheta  # turned by the small rotation error dtheta
        z = np.maximum(cam[:, 2], 1e-6)
        pix = np.column_stack([k.fx * cam[:, 0] / z + k.cx, k.fy * cam[:, 1] / z + k.cy])
        d_pix_d_cam = np.zeros((len(cam), 2, 3))
        d_pix_d_cam[:, 0, 0] = k.fx / z
        d_pix_d_cam[:, 0, 2] = -k.fx * cam[:, 0] / z**2
        d_pix_d_cam[:, 1, 1] = k.fy / z
        d_pix_d_cam[:, 1, 2] = -k.fy * cam[:, 1] / z**2
        jac_t = -d_pix_d_cam @ self.world_to_cam
        jac_theta = d_pix_d_cam @ skew
        return pix, jac_t, jac_theta, cam[:, 2] > 0.05

    def prediction_cov(self, jac_t: np.ndarray, jac_theta: np.ndarray) -> np.ndarray:
        """(n, 2, 2) covariance of the projected lamps from ``P`` and the attitude noise."""
        cov = jac_t @ self.P @ jac_t.transpose(0, 2, 1)
        return cov + self.attitude_sigma**2 * jac_theta @ jac_theta.transpose(0, 2, 1)

    def _linear_position(self, lamp_ids: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """Least-squares camera position from the collinearity equations (each pixel's ray
        passes through its lamp), linear in the position once the rotation is known."""
        k = self.intrinsics
        m = self.world_to_cam
        x = (pixels[:, 0] - k.cx) / k.fx
        y = (pixels[:, 1] - k.cy) / k.fy
        rows = np.concatenate([x[:, None] * m[2] - m[0], y[:, None] * m[2] - m[1]])
        points = self.points[np.concatenate([lamp_ids, lamp_ids])]
        rhs = np.einsum("ij,ij->i", rows, points)
        return np.linalg.lstsq(rows, rhs, rcond=None)[0]

    def fit_residual(self, lamp_ids: np.ndarray, pixels: np.ndarray) -> float:
        """RMS pixel error (per axis) of the best linear fit of the camera position to
        labelled lamps; inf if a lamp lands behind the camera. Leaves the filter unchanged."""
        pix, _, _, front = self.project(self._linear_position(lamp_ids, pixels))
        if not front[lamp_ids].all():
            return math.inf
        return float(np.sqrt(np.mean((pixels - pix[lamp_ids]) ** 2)))

    def initialise(self, lamp_ids: np.ndarray, pixels: np.ndarray, sigma: float) -> float:
        """Camera position from >= 2 labelled lamps; returns the RMS reprojection error (px,
        per axis).

        The linear solve of :meth:`fit_residual` followed by three Gauss-Newton steps on the
        pixel error.
        """
        lamp_ids = np.asarray(lamp_ids, dtype=int)
        pixels = np.asarray(pixels, dtype=float)
        self.t = self._linear_position(lamp_ids, pixels)
        for _ in range(3):
            pix, jac, _, _ = self.project()
            J = jac[lamp_ids].reshape(-1, 3)
            r = (pixels - pix[lamp_ids]).ravel()
            self.t = self.t + np.linalg.lstsq(J, r, rcond=None)[0]
        pix, jac, _, front = self.project()
        J = jac[lamp_ids].reshape(-1, 3)
        self.P = np.linalg.inv(J.T @ J / sigma**2 + 1e-6 * np.eye(3))
        if not front[lamp_ids].all():
            return math.inf
        return float(np.sqrt(np.mean((pixels - pix[lamp_ids]) ** 2)))

    def predict(self, displacement: np.ndarray, sigma: float) -> None:
        self.t = self.t + displacement
        self.P = self.P + sigma**2 * np.eye(3)

    def snapshot(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.t.copy(), self.P.copy(), self.dtheta.copy()

    def restore(self, state: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        self.t, self.P, self.dtheta = (x.copy() for x in state)

    def update(self, groups: list[np.ndarray], pixels: np.ndarray, sigmas: np.ndarray,
               iterations: int = 2) -> None:
        """Iterated EKF update of ``(t, dtheta)``; measurement k is the mean projection of the
        lamps in ``groups[k]`` (one lamp, or the members of a merged blob)."""
        if not groups:
            return
        z = np.asarray(pixels, dtype=float).ravel()
        R = np.diag(np.repeat(np.asarray(sigmas, float) ** 2, 2))
        prior = np.concatenate([self.t, np.zeros(3)])
        P = np.zeros((6, 6))
        P[:3, :3] = self.P
        P[3:, 3:] = self.attitude_sigma**2 * np.eye(3)
        mean = np.zeros((len(groups), len(self.points)))  # row k averages groups[k]
        for k, g in enumerate(groups):
            mean[k, g] = 1.0 / len(g)
        x = prior
        for _ in range(iterations):
            pix, jac_t, jac_theta, _ = self.project(x[:3], x[3:])
            h = (mean @ pix).ravel()
            jac = np.concatenate([jac_t, jac_theta], axis=2).reshape(len(pix), 12)
            H = (mean @ jac).reshape(-1, 6)
            K = kalman_gain(P, H, R)
            x = prior + K @ (z - h - H @ (prior - x))
        P = joseph_covariance(P, K, H, R)
        self.t, self.dtheta = x[:3], x[3:]
        self.P = P[:3, :3]


__all__ = ["CameraPositionFilter"]
