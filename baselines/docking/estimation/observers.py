"""State and disturbance observers of [OFNMPC] that read the guide lights' pixels directly.

[OFNMPC] §3.3: the observers of the offset-free NMPC estimate the vehicle state
*and* the generalized disturbance from the light pixel coordinates through a
visual observation model (eqs. 33-36), plus DVL/INS velocities; no separate
visual pose estimation.

* :class:`VisualObservationModel` — pinhole projection of the DS lights seen
  from a 4-DOF state ``(x, y, z, psi, u, v, w, r)``, with roll and pitch taken
  from the INS (the 4-DOF prediction model assumes them zero; the camera does
  not). Jacobians by CasADi's automatic differentiation.
* :class:`ExtendedKalmanFilter` — generic EKF ([OFNMPC] eqs. 17-28), Joseph
  form update; on a linear-Gaussian model it is the Kalman filter.
* :class:`DockingEKF` — that EKF on the disturbance-augmented state
  ``(pose, velocity, d)`` ([OFNMPC] eq. 12: ``d`` a constant generalized force).
* :class:`DockingMHE` — moving horizon estimation with the *original* model
  ([OFNMPC] eqs. 29-32): states and the real input (nominal input plus a
  generalized-force deviation ``w``) over the last N measurements are the
  decision variables. [OFNMPC]'s MHE diverged in 2 of 5 runs; ours adds an
  arrival cost whose weight is the EKF covariance recursion run along the MHE
  estimates (Rao, Rawlings & Mayne 2003, "filtering" arrival cost) and a
  random-walk penalty on ``w``, which keeps the estimate as well-behaved as the
  EKF's.

Only visible lights enter an update: the measurement rows of lights that are
not visible are dropped (EKF) or get zero weight (MHE).

Equations (what the code below implements; ``Delta t`` = ``calibration.control_period``).

Process model ([OFNMPC] eqs. 7-8, 11): state ``x = (eta, nu)``, pose
``eta = (x, y, z, psi)`` in the DS frame, body velocities ``nu = (u, v, w, r)``,
input ``tau = (X, Y, Z, N)``; ``calibration.nominal_model``
(:class:`~auv_envs.core.hydrodynamics.NominalModel`)::

    eta_dot = (u cos psi - v sin psi,  u sin psi + v cos psi,  w,  r)
    m_k nu_dot_k = tau_k + d_k + f_h,k(nu) - c_RB,k(nu)        k = X, Y, Z, N
    x_{k+1} = F(x_k, tau_k, d)                                  one RK4 step over Delta t

with ``m_k`` the rigid-body plus added inertia, ``f_h = -C_A(nu) nu - D(nu) nu - g``
(added-mass Coriolis, damping, restoring), ``c_RB = C_RB(nu) nu``, roll and pitch zero.

Augmented disturbance state ([OFNMPC] eq. 12), the EKF's process model and the
MHE's arrival-cost recursion (:func:`augmented_transition`)::

    z = (x, d) in R^12,   z_{k+1} = f(z_k, tau_k) + q_k = (F(x_k, tau_k, d_k), d_k) + q_k
    q_k ~ N(0, Q),   Q = diag(sigma_pose^2, sigma_nu^2, sigma_d^2)     (ObserverNoise)

Measurement model ([OFNMPC] eqs. 33-36; :class:`VisualObservationModel`), with
roll ``phi`` and pitch ``theta`` from the INS, light ``p_i`` in the DS frame,
camera extrinsics ``(R_bc, r_c)``::

    c_i = R_bc^T (R(phi, theta, psi)^T (p_i - (x, y, z)) - r_c) = (X_i, Y_i, Z_i)
    h(x) = (f_x X_1/Z_1 + c_x, f_y Y_1/Z_1 + c_y, ..., u, v, w, r, psi)
    y_k = h(x_k) + v_k,   v_k ~ N(0, R),   R = diag(sigma_px^2 .., sigma_nu^2 .., sigma_psi^2)

(the rows of lights not visible are dropped; the measured yaw is unwrapped to
within pi of the estimate's heading).

EKF ([OFNMPC] eqs. 17-28; :class:`ExtendedKalmanFilter`, :class:`DockingEKF`),
each control step with the input ``tau_{k-1}`` applied during the last period::

    prediction   z_k|k-1 = f(z_{k-1}, tau_{k-1}),   A = df/dz (z_{k-1}, tau_{k-1})
                 P_k|k-1 = A P_{k-1} A^T + Q                           (eqs. 22-23)
    update       H = [dh/dx, 0],   K = P_k|k-1 H^T (H P_k|k-1 H^T + R)^-1
                 z_k = z_k|k-1 + K (y_k - h(z_k|k-1))
                 P_k = (I - K H) P_k|k-1 (I - K H)^T + K R K^T         (eqs. 26-28, Joseph)

initialised from a least-squares pose fit to the first
measurement with two visible lights (:func:`initial_state`), ``d_0 = 0`` with
covariance ``diag(initial_disturbance_std^2)``.

MHE ([OFNMPC] eqs. 29-32; :class:`DockingMHE`) over the window of the last
``M`` measurements: decision variables the states ``X_0..X_{M-1}`` and the input
deviations ``W_0..W_{M-2}`` (the real input is ``tau_j + W_j``; no augmented
state), subject to the original model ``X_{j+1} = F(X_j, tau_j + W_j, 0)``::

    min  1/2 ||L ((X_0, W_0) - (x_bar, w_bar))||^2                      arrival cost
       + 1/2 sum_{j=0}^{M-1} ||Omega_j (y_j - h(X_j))||^2                 measurements
       + 1/2 sum_{j=0}^{M-3} ||(W_{j+1} - W_j) / sigma_w||^2               input random walk

with ``Omega_j = diag(1/sigma)`` on the rows that carry data and 0 elsewhere,
and ``L^T L = P^-1``. Arrival cost ("filtering", Rao, Rawlings & Mayne 2003):
when the window slides, ``P`` takes the EKF update with the dropped slot's data
and the prediction to the next slot, both linearised at the MHE estimate
``(X_0, W_0)``, with ``Q``'s disturbance block set to ``sigma_w^2``; the prior
mean becomes ``(x_bar, w_bar) = (X_1, W_min(1, M-2))``. The estimate handed on is the
state at the latest measurement and ``d = W`` on the last transition.
"""

from __future__ import annotations

import dataclasses
import math
import time

import casadi as ca
import numpy as np
from scipy.optimize import least_squares

from auv_envs.core.frames import rotation_from_euler, wrap_angle
from auv_envs.core.hydrodynamics import NominalModel
from baselines.kalman import joseph_covariance, kalman_gain

N_STATE = 8
N_INPUT = 4
N_AUG = N_STATE + N_INPUT
PSI = 3
#: Sensor rows after the pixels: u, v, w, r (DVL/INS) and yaw (INS).
N_SENSOR = 5


class VisualObservationModel:
    """Pixel coordinates of the DS lights as a function of the 4-DOF state ([OFNMPC] eq. 33).

    A light at ``p_i`` (DS frame) is seen in the OpenCV camera frame at
    ``R_bc^T (R(phi, theta, psi)^T (p_i - eta) - r_c)`` and projected with the
    pinhole intrinsics; ``R_bc`` and ``r_c`` are the camera extrinsics of the
    calibration. The same convention as :func:`auv_envs.core.camera.project`.

    Args:
        calibration: the docking env's ``calibration``.
    """

    def __init__(self, calibration):
        self.intrinsics = calibration.intrinsics
        self.lights = np.asarray(calibration.light_positions, dtype=float)
        self.n_lights = len(self.lights)
        self.camera_rotation = np.asarray(calibration.extrinsics.rotation_matrix, dtype=float)
        self.camera_position = np.asarray(calibration.extrinsics.position, dtype=float)
        x = ca.SX.sym("x", N_STATE)
        attitude = ca.SX.sym("attitude", 2)
        pixels = self.pixels_expr(x, attitude[0], attitude[1])
        h = ca.vertcat(pixels, x[4], x[5], x[6], x[7], x[PSI])
        #: ``(x, [roll, pitch]) -> (h, dh/dx)``, ``h`` = pixels (u0, v0, u1, ...), u, v, w, r, psi.
        self.measurement = ca.Function(
            "visual_measurement", [x, attitude], [h, ca.jacobian(h, x)], ["x", "rp"], ["h", "H"]
        )

    @property
    def n_measurements(self) -> int:
        return 2 * self.n_lights + N_SENSOR

    def camera_points_expr(self, x, roll, pitch):
        """(3, n) CasADi expression: the lights in the OpenCV camera frame."""
        rot_wb = rotation_from_euler(roll, pitch, x[PSI], ops=ca)
        rel = ca.DM(self.lights.T) - ca.repmat(x[0:3], 1, self.n_lights)
        in_body = rot_wb.T @ rel - ca.repmat(ca.DM(self.camera_position), 1, self.n_lights)
        return ca.DM(self.camera_rotation.T) @ in_body

    def pixels_expr(self, x, roll, pitch):
        """(2n,) CasADi expression of the pixel coordinates, light by light."""
        pts = self.camera_points_expr(x, roll, pitch)
        k = self.intrinsics
        u = k.fx * pts[0, :] / pts[2, :] + k.cx
        v = k.fy * pts[1, :] / pts[2, :] + k.cy
        return ca.reshape(ca.vertcat(u, v), 2 * self.n_lights, 1)

    def evaluate(self, x, attitude) -> tuple[np.ndarray, np.ndarray]:
        """Predicted measurement (2n + 5,) and its Jacobian (2n + 5, 8) at ``x``."""
        h, jac = self.measurement(np.asarray(x, dtype=float)[:N_STATE], attitude[:2])
        return np.asarray(h).ravel(), np.asarray(jac)


@dataclasses.dataclass(frozen=True)
class Measurement:
    """One features observation as a measurement vector over all lights.

    ``z`` has the layout of :attr:`VisualObservationModel.measurement`; ``mask``
    says which rows carry data (the pixels of lights that are not visible do
    not; a light whose pixels are not finite counts as not visible);
    ``attitude`` is the INS (roll, pitch, yaw). Non-finite velocities or
    attitude raise ``ValueError``.
    """

    z: np.ndarray
    mask: np.ndarray
    attitude: np.ndarray

    @classmethod
    def from_features(cls, observation: dict, n_lights: int) -> Measurement:
        pixels = np.asarray(observation["pixels"], dtype=float)
        visible = np.asarray(observation["visible"]).astype(bool)
        velocity = np.asarray(observation["velocity"], dtype=float)
        attitude = np.asarray(observation["attitude"], dtype=float)
        if pixels.shape != (n_lights, 2) or visible.shape != (n_lights,):
            raise ValueError(
                f"features observation needs pixels ({n_lights}, 2) and visible ({n_lights},), "
                f"got {pixels.shape} and {visible.shape}"
            )
        if velocity.shape != (4,) or attitude.shape != (3,):
            raise ValueError("features observation needs velocity (4,) and attitude (3,)")
        if not (np.isfinite(velocity).all() and np.isfinite(attitude).all()):
            raise ValueError("non-finite velocity or attitude in the observation")
        visible &= np.isfinite(pixels).all(axis=1)
        z = np.concatenate([pixels.ravel(), velocity, attitude[2:3]])
        mask = np.concatenate([np.repeat(visible, 2), np.ones(N_SENSOR, dtype=bool)])
        z[~mask] = 0.0
        return cls(z=z, mask=mask, attitude=attitude)

    @property
    def n_visible(self) -> int:
        return int(np.count_nonzero(self.mask[:-N_SENSOR])) // 2


@dataclasses.dataclass(frozen=True)
class ObserverNoise:
    """Noise standard deviations the observers assume.

    Measurement noise comes from the calibration (the scenario's sensor noise)
    with floors, so that the noise-free scenario does not make the filters
    overconfident in a model that is not exact (roll/pitch coupling, RK4).
    Process noise per control period: pose and velocity for the unmodelled
    dynamics, ``disturbance`` for the random walk of ``d`` ([OFNMPC] eq. 12).
    """

    pixel: float
    velocity: float
    yaw_rate: float
    yaw: float
    position: float = 0.002
    heading: float = 0.001
    linear_velocity: float = 0.004
    angular_velocity: float = 0.002
    disturbance: tuple[float, float, float, float] = (1.5, 1.5, 1.5, 0.5)

    @classmethod
    def from_calibration(cls, calibration, **overrides) -> ObserverNoise:
        base = dict(
            pixel=max(calibration.pixel_noise_std, 1.0),
            velocity=max(calibration.velocity_noise_std, 0.005),
            yaw_rate=max(calibration.yaw_rate_noise_std, 0.002),
            yaw=max(calibration.attitude_noise_std, math.radians(0.2)),
        )
        base.update(overrides)
        return cls(**base)

    def measurement_std(self, n_lights: int) -> np.ndarray:
        sensors = [self.velocity] * 3 + [self.yaw_rate, self.yaw]
        return np.array([self.pixel] * (2 * n_lights) + sensors)

    def state_std(self) -> np.ndarray:
        return np.array(
            [self.position] * 3
            + [self.heading]
            + [self.linear_velocity] * 3
            + [self.angular_velocity]
        )

    def process_cov(self) -> np.ndarray:
        """Process noise covariance of the augmented state (pose, velocity, d)."""
        return np.diag(np.concatenate([self.state_std(), self.disturbance]) ** 2)


def augmented_transition(model: NominalModel, dt: float) -> ca.Function:
    """``(z, tau) -> (z_next, dz_next/dz)`` of the disturbance-augmented model ([OFNMPC] eq. 12).

    ``z = (x, d)``: the nominal model's RK4 step over ``dt`` driven by
    ``tau + d``; ``d`` constant.
    """
    z = ca.SX.sym("z", N_AUG)
    tau = ca.SX.sym("tau", N_INPUT)
    x, d = z[:N_STATE], z[N_STATE:]
    z_next = ca.vertcat(model.step(x, tau, dt, d=d, ops=ca), d)
    return ca.Function(
        "augmented_step", [z, tau], [z_next, ca.jacobian(z_next, z)], ["z", "tau"], ["z_next", "A"]
    )


class ExtendedKalmanFilter:
    """Extended Kalman filter ([OFNMPC] eqs. 17-28).

    Args:
        transition: ``(x, u) -> (f(x, u), df/dx)`` (a CasADi ``Function`` or
            any callable returning two array-likes).
        process_cov: process noise covariance Q.
    """

    def __init__(self, transition, process_cov: np.ndarray):
        self._transition = transition
        self.process_cov = np.asarray(process_cov, dtype=float)
        n = self.process_cov.shape[0]
        self.mean = np.zeros(n)
        self.cov = np.eye(n)

    def initialise(self, mean, cov) -> None:
        self.mean = np.array(mean, dtype=float)
        self.cov = np.array(cov, dtype=float)

    def predict(self, u) -> None:
        """``x = f(x, u)``, ``P = F P F^T + Q`` (eqs. 22-23)."""
        x_next, jac = self._transition(self.mean, u)
        jac = np.asarray(jac)
        self.mean = np.asarray(x_next, dtype=float).ravel()
        self.cov = jac @ self.cov @ jac.T + self.process_cov
        self.cov = 0.5 * (self.cov + self.cov.T)

    def update(self, innovation, jacobian, noise_cov) -> None:
        """Correct with innovation ``z - h(x)``, Jacobian H and noise R (eqs. 26-28).

        The covariance update uses the Joseph form, which is the same as
        ``(I - K H) P`` in exact arithmetic and stays symmetric positive
        definite in floating point.
        """
        h = np.asarray(jacobian, dtype=float)
        gain = kalman_gain(self.cov, h, noise_cov)
        self.mean = self.mean + gain @ np.asarray(innovation, dtype=float)
        self.cov = joseph_covariance(self.cov, gain, h, noise_cov)


@dataclasses.dataclass(frozen=True)
class Estimate:
    """What an observer hands the NMPC: state ``(x, y, z, psi, u, v, w, r)`` and ``d``."""

    state: np.ndarray
    disturbance: np.ndarray


#: Farthest camera-to-lights range (m) an initial pose fit may claim. At 30 m the
#: six-light ring (radius 0.45 m) still spans about 17 px at f = 579 px, so a real
#: sighting is nearer; a fit beyond it is the range running off along the bearing.
MAX_LIGHT_RANGE = 30.0


def initial_state(model: VisualObservationModel, meas: Measurement, noise: ObserverNoise,
                  max_range: float = MAX_LIGHT_RANGE):
    """Least-squares pose from the first measurement ([OFNMPC] eq. 33 inverted).

    Solves for ``(x, y, z, psi)`` with the visual model and the INS heading
    (``scipy.optimize.least_squares``, Jacobian from CasADi), velocities from
    the DVL. Starts from a few ranges along the bearing of the lights' mean
    pixel and keeps the best fit that puts the lights' centre in front of
    the camera within ``max_range``. Two close lights far away can pull the
    range off along the bearing (a fit at 10^8 m once made the NMPC hang);
    such a frame is skipped and the observer waits for the next.

    Returns:
        ``(state (8,), covariance (8, 8))`` or ``None`` with fewer than two
        visible lights or no plausible fit (the pose is not determined).
    """
    if meas.n_visible < 2:
        return None
    rows = np.flatnonzero(meas.mask)
    pose_rows = rows[rows < 2 * model.n_lights].tolist() + [model.n_measurements - 1]
    std = noise.measurement_std(model.n_lights)[pose_rows]
    velocity = meas.z[-N_SENSOR:-1]
    yaw = float(meas.z[-1])

    def state(p):
        return np.concatenate([p, velocity])

    def residual(p):
        h, _ = model.evaluate(state(p), meas.attitude)
        r = meas.z[pose_rows] - h[pose_rows]
        r[-1] = wrap_angle(r[-1])
        return r / std

    def jacobian(p):
        _, jac = model.evaluate(state(p), meas.attitude)
        return -jac[pose_rows][:, :4] / std[:, None]

    k = model.intrinsics
    pix = meas.z[: 2 * model.n_lights].reshape(-1, 2)[meas.mask[: 2 * model.n_lights : 2]]
    ray_cam = np.array([(pix[:, 0].mean() - k.cx) / k.fx, (pix[:, 1].mean() - k.cy) / k.fy, 1.0])
    rot = rotation_from_euler(meas.attitude[0], meas.attitude[1], yaw, np)
    ray = rot @ (model.camera_rotation @ ray_cam)
    ray /= np.linalg.norm(ray)
    centre = model.lights.mean(axis=0)
    best = None
    for rng in (4.0, 8.0, 12.0, 16.0):
        cam = centre - rng * ray
        guess = np.concatenate([cam - rot @ model.camera_position, [yaw]])
        fit = least_squares(residual, guess, jac=jacobian, method="lm")
        fit_rot = rotation_from_euler(meas.attitude[0], meas.attitude[1], fit.x[3], np)
        to_lights = centre - (fit.x[:3] + fit_rot @ model.camera_position)
        ahead = float(to_lights @ (fit_rot @ model.camera_rotation[:, 2]))
        plausible = 0.0 < ahead and np.linalg.norm(to_lights) <= max_range
        if plausible and (best is None or fit.cost < best.cost):
            best = fit
    if best is None:
        return None
    # Gauss-Newton covariance of the pose fit; velocities from the DVL noise.
    jac = jacobian(best.x)
    pose_cov = np.linalg.pinv(jac.T @ jac) * max(1.0, 2.0 * best.cost / max(1, len(std) - 4))
    cov = np.zeros((N_STATE, N_STATE))
    cov[:4, :4] = pose_cov + np.diag([0.05, 0.05, 0.05, 0.01]) ** 2
    cov[4:, 4:] = np.diag([noise.velocity] * 3 + [noise.yaw_rate]) ** 2
    return state(best.x), cov


def initial_augmented_state(
    model: VisualObservationModel, meas: Measurement, noise: ObserverNoise, d0_cov: np.ndarray
):
    """:func:`initial_state` extended by a zero disturbance with covariance ``d0_cov``.

    Returns:
        ``(augmented state (12,), covariance (12, 12))`` or ``None`` as
        :func:`initial_state`.
    """
    init = initial_state(model, meas, noise)
    if init is None:
        return None
    x0, p0 = init
    cov = np.zeros((N_AUG, N_AUG))
    cov[:N_STATE, :N_STATE] = p0
    cov[N_STATE:, N_STATE:] = d0_cov
    return np.concatenate([x0, np.zeros(N_INPUT)]), cov


def _unwrap_yaw(meas: Measurement, psi: float) -> np.ndarray:
    """The measurement with its yaw moved to within pi of the state's heading."""
    z = meas.z.copy()
    z[-1] = psi + wrap_angle(z[-1] - psi)
    return z


class DockingEKF:
    """EKF on the augmented state ``(x, y, z, psi, u, v, w, r, dX, dY, dZ, dN)``.

    Args:
        calibration: the docking env's ``calibration`` (nominal model, camera,
            lights, control period, sensor noise).
        noise: noise settings (default: from the calibration).
        initial_disturbance_std: prior std of ``d`` (N, N, N, N m).
        nominal_model: process model (default ``calibration.nominal_model``).
    """

    def __init__(self, calibration, noise: ObserverNoise | None = None,
                 initial_disturbance_std=(20.0, 20.0, 20.0, 5.0), nominal_model=None):
        self.visual = VisualObservationModel(calibration)
        self.noise = noise or ObserverNoise.from_calibration(calibration)
        model = nominal_model or calibration.nominal_model
        self.filter = ExtendedKalmanFilter(
            augmented_transition(model, calibration.control_period), self.noise.process_cov()
        )
        self._meas_var = self.noise.measurement_std(self.visual.n_lights) ** 2
        self._d0_cov = np.diag(np.asarray(initial_disturbance_std, dtype=float) ** 2)
        self.initialised = False

    def reset(self) -> None:
        self.initialised = False

    def step(self, observation: dict, tau_applied) -> Estimate | None:
        """Predict with the input applied since the last call, update with ``observation``.

        Returns ``None`` until the first observation with two visible lights
        has initialised the filter.
        """
        meas = Measurement.from_features(observation, self.visual.n_lights)
        if not self.initialised:
            init = initial_augmented_state(self.visual, meas, self.noise, self._d0_cov)
            if init is None:
                return None
            self.filter.initialise(*init)
            self.initialised = True
        else:
            self.filter.predict(np.asarray(tau_applied, dtype=float))
        self._update(meas)
        return self.estimate()

    def _update(self, meas: Measurement) -> None:
        f = self.filter
        z = _unwrap_yaw(meas, f.mean[PSI])
        h, jac = self.visual.evaluate(f.mean, meas.attitude)
        rows = meas.mask
        jac_aug = np.zeros((int(rows.sum()), N_AUG))
        jac_aug[:, :N_STATE] = jac[rows]
        f.update(z[rows] - h[rows], jac_aug, np.diag(self._meas_var[rows]))

    def estimate(self) -> Estimate:
        m = self.filter.mean
        return Estimate(state=m[:N_STATE].copy(), disturbance=m[N_STATE:].copy())


# ---------------------------------------------------------------------- MHE
@dataclasses.dataclass(frozen=True)
class MHEConfig:
    """Moving horizon estimator settings.

    Attributes:
        horizon: number of measurements N in the window.
        input_change_std: random-walk std of the input deviation ``w`` per
            control period (N, N, N, N m): the smoothness that keeps ``w`` (the
            disturbance estimate) from chasing noise. ``None``: the observer
            noise's ``disturbance`` (:class:`ObserverNoise`), the random walk the
            EKF assumes for ``d``.
        max_iter: IPOPT iteration cap per solve.
    """

    horizon: int = 10
    input_change_std: tuple[float, float, float, float] | None = None
    max_iter: int = 30


class DockingMHE:
    """MHE with the original 4-DOF model, states and real inputs as decision variables.

    Window of ``M`` measurements at times ``t-M+1 .. t``: states ``X_0..X_{M-1}``
    and input deviations ``W_0..W_{M-2}`` with ``X_{j+1} = F(X_j, tau_j + W_j)``
    (exact dynamics; ``W`` is the generalized force the nominal model lacks).
    Cost ([OFNMPC] eq. 30, plus the terms that keep it convergent)::

        ||L (X_0 - x_bar, W_0 - w_bar)||^2                  arrival cost
        + sum_j ||(y_j - h(X_j)) / sigma||^2 over data rows  measurements
        + sum_j ||(W_{j+1} - W_j) / sigma_w||^2               input random walk

    ``L^T L = P^{-1}``, ``P`` the covariance of the EKF recursion on the
    augmented model run along the MHE's own estimates, one step behind the
    window start ("filtering" arrival cost). While the window fills (the first
    ``M-1`` steps) the data sit at its start and the unused slots get zero
    weight: the problem is then the full-information estimate. The output is
    the state at the latest measurement and ``d = W`` on the last transition.
    A failed solve (IPOPT not converged) falls back to the previous estimates
    shifted one step and propagated by the model, and is counted in
    ``failures``.

    Args:
        calibration: the docking env's ``calibration``.
        config: :class:`MHEConfig`.
        noise: noise settings (default: from the calibration).
        initial_disturbance_std: prior std of ``w`` at the start (N, N, N, N m).
        nominal_model: process model (default ``calibration.nominal_model``).
    """

    def __init__(self, calibration, config: MHEConfig | None = None,
                 noise: ObserverNoise | None = None,
                 initial_disturbance_std=(20.0, 20.0, 20.0, 5.0), nominal_model=None):
        self.config = config or MHEConfig()
        if self.config.horizon < 2:
            raise ValueError(f"MHE horizon must be >= 2, got {self.config.horizon}")
        self.noise = noise or ObserverNoise.from_calibration(calibration)
        self.visual = VisualObservationModel(calibration)
        self.model = nominal_model or calibration.nominal_model
        self.dt = calibration.control_period
        self._aug = augmented_transition(self.model, self.dt)
        change_std = self.config.input_change_std
        self._input_change_std = np.asarray(
            self.noise.disturbance if change_std is None else change_std, dtype=float
        )
        q = self.noise.process_cov().copy()
        q[N_STATE:, N_STATE:] = np.diag(self._input_change_std**2)
        self._arrival = ExtendedKalmanFilter(self._aug, q)
        self._meas_std = self.noise.measurement_std(self.visual.n_lights)
        self._d0_cov = np.diag(np.asarray(initial_disturbance_std, dtype=float) ** 2)
        self._build()
        self.reset()

    # The NLP is built once; data, weights and the arrival cost are parameters.
    def _build(self) -> None:
        m, ny = self.config.horizon, self.visual.n_measurements
        xs = ca.SX.sym("X", N_STATE, m)
        ws = ca.SX.sym("W", N_INPUT, m - 1)
        y = ca.SX.sym("y", ny, m)
        weight = ca.SX.sym("weight", ny, m)  # 1/sigma where data, 0 elsewhere
        rp = ca.SX.sym("rp", 2, m)
        tau = ca.SX.sym("tau", N_INPUT, m - 1)
        prior = ca.SX.sym("prior", N_AUG)
        chol = ca.SX.sym("L", N_AUG, N_AUG)
        xk, tk, wk = ca.SX.sym("xk", N_STATE), ca.SX.sym("tk", N_INPUT), ca.SX.sym("wk", N_INPUT)
        step = ca.Function("step", [xk, tk, wk], [self.model.step(xk, tk + wk, self.dt, ops=ca)])
        h = self.visual.measurement
        residuals = [chol @ (ca.vertcat(xs[:, 0], ws[:, 0]) - prior)]
        g = []
        w_scale = ca.DM(1.0 / self._input_change_std)
        for j in range(m):
            hj = h(xs[:, j], rp[:, j])[0]
            residuals.append(weight[:, j] * (y[:, j] - hj))
            if j < m - 1:
                g.append(xs[:, j + 1] - step(xs[:, j], tau[:, j], ws[:, j]))
            if j < m - 2:
                residuals.append(w_scale * (ws[:, j + 1] - ws[:, j]))
        res = ca.vertcat(*residuals)
        decision = ca.vertcat(ca.vec(xs), ca.vec(ws))
        params = ca.vertcat(ca.vec(y), ca.vec(weight), ca.vec(rp), ca.vec(tau), prior,
                            ca.vec(chol))
        nlp = {"x": decision, "p": params, "f": 0.5 * ca.dot(res, res), "g": ca.vertcat(*g)}
        opts = {
            "print_time": False,
            "ipopt": {
                "print_level": 0,
                "max_iter": self.config.max_iter,
                "tol": 1e-6,
                "acceptable_tol": 1e-4,
                "warm_start_init_point": "yes",
                "mu_init": 1e-3,
                "sb": "yes",
            },
        }
        self._solver = ca.nlpsol("mhe", "ipopt", nlp, opts)

    def reset(self) -> None:
        """New episode: empty window, counters zeroed."""
        self.failures = 0
        self.solves = 0
        self.solve_times: list[float] = []
        m, ny = self.config.horizon, self.visual.n_measurements
        self._y = np.zeros((ny, m))
        self._weight = np.zeros((ny, m))
        self._rp = np.zeros((2, m))
        self._tau = np.zeros((N_INPUT, m - 1))
        self._count = 0  # measurements received this episode
        self._guess = np.zeros(N_STATE * m + N_INPUT * (m - 1))
        self._lam_g = None

    def step(self, observation: dict, tau_applied) -> Estimate | None:
        """Add ``observation`` (after ``tau_applied`` acted for one period) and re-estimate.

        Returns ``None`` until the first observation with two visible lights.
        """
        m = self.config.horizon
        meas = Measurement.from_features(observation, self.visual.n_lights)
        tau_applied = np.asarray(tau_applied, dtype=float)
        if self._count == 0:
            init = initial_augmented_state(self.visual, meas, self.noise, self._d0_cov)
            if init is None:
                return None
            self._arrival.initialise(*init)
            self._guess[: N_STATE * m] = np.tile(init[0][:N_STATE], m)
        elif self._count < m:
            self._tau[:, self._count - 1] = tau_applied
        else:
            self._slide(tau_applied)
        slot = min(self._count, m - 1)
        self._store(slot, meas)
        self._count += 1
        return self._solve(slot)

    def _split(self) -> tuple[np.ndarray, np.ndarray]:
        m = self.config.horizon
        x_hat = self._guess[: N_STATE * m].reshape(m, N_STATE).T
        w_hat = self._guess[N_STATE * m :].reshape(m - 1, N_INPUT).T
        return x_hat, w_hat

    def _store(self, slot: int, meas: Measurement) -> None:
        self._y[:, slot] = _unwrap_yaw(meas, self._guess[slot * N_STATE + PSI])
        self._weight[:, slot] = np.where(meas.mask, 1.0 / self._meas_std, 0.0)
        self._rp[:, slot] = meas.attitude[:2]

    def _slide(self, tau_applied: np.ndarray) -> None:
        """Advance the window one step; the arrival cost takes in the dropped slot."""
        m = self.config.horizon
        x_hat, w_hat = self._split()
        # Arrival covariance: EKF covariance update with slot 0's data at the
        # MHE estimate, then prediction to slot 1 linearised at the same point.
        arr = self._arrival
        _, jac = self.visual.evaluate(x_hat[:, 0], self._rp[:, 0])
        rows = self._weight[:, 0] > 0
        jac_aug = np.zeros((int(rows.sum()), N_AUG))
        jac_aug[:, :N_STATE] = jac[rows]
        arr.update(np.zeros(len(jac_aug)), jac_aug, np.diag(self._meas_std[rows] ** 2))
        _, a = self._aug(np.concatenate([x_hat[:, 0], w_hat[:, 0]]), self._tau[:, 0])
        a = np.asarray(a)
        arr.cov = a @ arr.cov @ a.T + arr.process_cov
        arr.mean = np.concatenate([x_hat[:, 1], w_hat[:, min(1, m - 2)]])
        # Shift the data and the initial guess by one slot.
        for buf in (self._y, self._weight, self._rp, self._tau):
            buf[:, :-1] = buf[:, 1:]
        self._tau[:, -1] = tau_applied
        x_new = np.concatenate([x_hat[:, 1:], x_hat[:, -1:]], axis=1)
        x_new[:, -1] = self.model.step(x_hat[:, -1], tau_applied + w_hat[:, -1], self.dt, ops=np)
        w_new = np.concatenate([w_hat[:, 1:], w_hat[:, -1:]], axis=1)
        self._guess = np.concatenate([x_new.ravel("F"), w_new.ravel("F")])
        if self._lam_g is not None:
            lam = self._lam_g.reshape(m - 1, N_STATE).T
            self._lam_g = np.concatenate([lam[:, 1:], lam[:, -1:]], axis=1).ravel("F")

    def _solve(self, slot: int) -> Estimate:
        arr = self._arrival
        chol = np.linalg.cholesky(np.linalg.inv(arr.cov)).T
        p = np.concatenate([
            self._y.ravel("F"), self._weight.ravel("F"), self._rp.ravel("F"),
            self._tau.ravel("F"), arr.mean, chol.ravel("F"),
        ])
        args = {"x0": self._guess, "p": p, "lbg": 0.0, "ubg": 0.0}
        if self._lam_g is not None:
            args["lam_g0"] = self._lam_g
        start = time.perf_counter()
        sol = self._solver(**args)
        self.solve_times.append(time.perf_counter() - start)
        self.solves += 1
        if self._solver.stats()["success"]:
            self._guess = np.asarray(sol["x"]).ravel()
            self._lam_g = np.asarray(sol["lam_g"]).ravel()
        else:
            # Fallback: keep the warm start (the previous estimates shifted and
            # propagated by the model), drop the multipliers.
            self.failures += 1
            self._lam_g = None
        x_hat, w_hat = self._split()
        return Estimate(state=x_hat[:, slot].copy(), disturbance=w_hat[:, max(slot - 1, 0)].copy())
