"""The AUV's state for the LARS capture: CG position and velocity, heave, pitch and yaw ([LTAT]).

[LTAT], §2.2-2.3. Components, each with one role:

* :class:`HeaveRefit`: eq. 8's heave frequency ``C`` and mean level
  ``z_mean``, refitted from the measured heights
  (:func:`~baselines.lars.estimation.ckf.fit_heave`), starting from a prior
  model.
* :class:`PitchYawMean`: the running mean of the per-fix pitch and yaw of
  eqs. 4-6 and the body-to-world rotation it gives.
* :class:`MarkerAUVEstimator`: the state estimator of ``ckf-pd``: stereo
  marker fixes (:class:`~baselines.lars.perception.marker.MarkerLocaliser`)
  -> the AUV's CG -> cubature Kalman filter on eq. 8's motion model, with
  the heave refit, an innovation gate, relock and attitude averaging.
* :class:`TrueStateAUVEstimator`: the same outputs from the true AUV state
  (``ckf-pd-state``'s privileged stand-in for the estimator).

Both estimators expose what the capture planner
(:class:`~baselines.lars.control.capture.CapturePlanner`) reads: ``mean``
(the state ``(x, y, z, vx, vy, vz)``), ``rotation``, ``heave`` (the last
fit, ``None`` before one), ``settled`` and :meth:`kinematics`.
"""

from __future__ import annotations

import math

import numpy as np

from baselines.lars.estimation.ckf import (
    CubatureKalmanFilter,
    HeaveFit,
    HeaveSurgeModel,
    fit_heave,
    position_measurement,
    white_acceleration_noise,
)
from baselines.lars.perception.marker import MarkerLocaliser, attitude_rotation

#: 99.9 % point of the chi-square distribution with 3 degrees of freedom: the
#: innovation gate against mismatched corners.
GATE_3DOF = 16.27
#: Heave prior before the first fit: a 7 s swell (the paper's "C is
#: determined by the sine wave period") about the level the AUV floats at.
PRIOR_HEAVE_PERIOD = 7.0
#: Attitude fixes :class:`PitchYawMean`'s running mean spans by default.
ATTITUDE_MEMORY = 50
#: The counts :attr:`MarkerAUVEstimator.counts` keeps, in this order.
COUNTS = ("fixes", "partial_fixes", "bridged", "gated", "reinitialised",
          "mismatched_corners", "heave_fits")


def prior_heave_model(dt: float, floating_level: float) -> HeaveSurgeModel:
    """Eq. 8's model before any fit: a :data:`PRIOR_HEAVE_PERIOD` swell about ``floating_level``."""
    return HeaveSurgeModel(dt, 2.0 * math.pi / PRIOR_HEAVE_PERIOD, floating_level)


class HeaveRefit:
    """Eq. 8's heave frequency ``C`` and mean level, fitted to the measured heights.

    The model starts as ``prior``; each :meth:`refit` fits
    ``z(t) = z_mean + A sin(C t + phi)`` by least squares
    (:func:`~baselines.lars.estimation.ckf.fit_heave`) to the heights of the
    last ``window`` s recorded with :meth:`record`, once they span
    ``min_span`` s, and replaces ``C`` and ``z_mean`` of the model
    (:meth:`~baselines.lars.estimation.ckf.HeaveSurgeModel.with_heave`).

    Args:
        prior: the model before the first fit (its ``dt`` is the control period).
        window: s of past heights a fit uses.
        min_span: s of heights needed before the first fit.
        omega_bounds: rad/s searched by the fit.

    Attributes:
        model: the current :class:`~baselines.lars.estimation.ckf.HeaveSurgeModel`.
        fit: the last :class:`~baselines.lars.estimation.ckf.HeaveFit` (``None`` before one).
    """

    def __init__(self, prior: HeaveSurgeModel, window: float = 15.0, min_span: float = 3.0,
                 omega_bounds=(0.5, 1.6)):
        if min_span <= 0 or window < min_span:
            raise ValueError(f"need 0 < min_span <= window, got {min_span}, {window}")
        self.prior = prior
        self.window = float(window)
        self.min_span = float(min_span)
        self.omega_bounds = tuple(float(b) for b in omega_bounds)
        self.reset()

    def reset(self) -> None:
        self.model = self.prior
        self.fit: HeaveFit | None = None
        self._heights: list[tuple[float, float]] = []

    def record(self, t: float, z: float) -> None:
        """A measured height ``z`` (m) of the AUV's CG at time ``t`` (s)."""
        self._heights.append((t, float(z)))

    def refit(self, t: float) -> bool:
        """Fit the heights of the last ``window`` s before ``t``; whether a fit was made."""
        while self._heights and self._heights[0][0] < t - self.window:
            self._heights.pop(0)
        if not self._heights or t - self._heights[0][0] < self.min_span:
            return False
        times, z = np.array(self._heights).T
        fit = fit_heave(times, z, self.omega_bounds)
        self.fit = fit
        self.model = self.model.with_heave(fit.omega, fit.mean)
        return True


class PitchYawMean:
    """The AUV's pitch and yaw: the running mean of the per-fix angles of eqs. 4-6.

    With ``k`` the number of angles so far and ``m = memory``,
    ``pitch_k = pitch_(k-1) + (pitch_fix - pitch_(k-1)) / min(k, m)`` (the
    first fix taken as it is; yaw likewise): the plain mean of the first
    ``m`` fixes, then an exponential mean over about ``m`` fixes.

    Attributes:
        pitch, yaw: radians (NaN before a fix).
        rotation: body-to-world rotation (3, 3) of the mean
            (:func:`~baselines.lars.perception.marker.attitude_rotation`),
            ``None`` before a fix.
        count: angles taken in so far.
    """

    def __init__(self, memory: int = ATTITUDE_MEMORY):
        if memory < 1:
            raise ValueError(f"need memory >= 1, got {memory}")
        self.memory = int(memory)
        self.reset()

    def reset(self) -> None:
        self.pitch = self.yaw = math.nan
        self.count = 0
        self.rotation: np.ndarray | None = None

    def update(self, pitch: float, yaw: float) -> None:
        self.count += 1
        w = 1.0 / min(self.count, self.memory)
        if self.rotation is None:
            self.pitch, self.yaw = pitch, yaw
        else:
            self.pitch += w * (pitch - self.pitch)
            self.yaw += w * (yaw - self.yaw)
        self.rotation = attitude_rotation(self.pitch, self.yaw)


class _HeaveModelEstimate:
    """What both estimators report through their heave model: the model, its last fit,
    and the CG's kinematics ahead (from ``self.heave`` and ``self.mean``)."""

    @property
    def model(self) -> HeaveSurgeModel:
        return self.heave.model

    @property
    def fit(self) -> HeaveFit | None:
        """The last heave fit (``None`` before one)."""
        return self.heave.fit

    def kinematics(self, horizon: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The CG's position, velocity and acceleration ``horizon`` s ahead (the model's)."""
        return self.heave.model.kinematics(self.mean, horizon)


class MarkerAUVEstimator(_HeaveModelEstimate):
    """The AUV's CG position and velocity, heave and attitude from stereo marker fixes [LTAT].

    Estimates the state of eq. 7, ``X = (x, y, z, vx, vy, vz)`` (the AUV's
    centre of gravity in the arm's base frame and its velocity), eq. 8's
    heave frequency ``C`` and level, and the AUV's pitch and yaw. Each
    :meth:`update` (one per control period ``T``):

    1. the marker fix (:meth:`MarkerLocaliser.locate`): the corners
       triangulated by eq. 2 and carried to the world by eq. 3, with their
       covariances from the pixel noise;
    2. the CKF's time update (eqs. 13-19) on eq. 8's
       ``X_k = F X_(k-1) + (I - F) z_mean e_z + n_k``
       (:class:`~baselines.lars.estimation.ckf.HeaveSurgeModel`), with white
       acceleration noise ``Q`` of std ``accel_std`` per axis;
    3. the attitude: pitch and yaw of eqs. 4-6 from each fix with all three
       corners, averaged by :class:`PitchYawMean` (the first one at once,
       later ones only from fixes that pass the gate);
    4. the measurement ``z = mean_i (A_i - R a_i)`` over the triangulated
       corners ``A_i`` (``a_i`` their place on the hull, ``R`` the mean
       attitude), ``R_k`` the mean of their covariances over ``n``
       (:meth:`MarkerLocaliser.auv_position`), and the CKF's measurement
       update (eqs. 20-28, ``H = [I_3 0]``, eq. 9), rejected when the
       normalised innovation squared exceeds ``gate``;
    5. every ``refit_period`` s, eq. 8's ``C`` and ``z_mean`` refitted from the
       measured heights (:class:`HeaveRefit`).

    With the marker hidden (or its fix gated) the filter only predicts
    ("bridged"). The first fix initialises the filter at ``z`` with the
    fix's covariance and a velocity std of 0.2 m/s; after ``relock_after`` s
    of consecutive gated fixes the filter has lost lock and restarts from
    the latest fix the same way. A fresh filter is ``settled`` after
    ``settle_time`` s of fixes; until then no fix is gated (it has no basis
    yet to call one an outlier).

    Args:
        localiser: marker fixes and the AUV points (reset with the estimator).
        heave: the motion model and its refit.
        attitude: the pitch/yaw mean.
        accel_std: (3,) white-acceleration process noise, m/s^2.
        gate: chi-square gate on the fixes' innovation (``None``: no gate).
        refit_period: s between heave fits.
        relock_after: s of consecutive gated fixes before the filter restarts.
        settle_time: s of fixes a fresh filter takes in before it is ``settled``.

    Attributes:
        filter: the :class:`~baselines.lars.estimation.ckf.CubatureKalmanFilter`.
        last_measurement: the CG ``z`` of the last update (``None`` when it had none).
        counts: ``fixes``/``partial_fixes`` (updates with 3 / 1-2 triangulated
            corners), ``bridged``, ``gated``, ``reinitialised``,
            ``mismatched_corners`` and ``heave_fits`` of this episode.
    """

    def __init__(self, localiser: MarkerLocaliser, heave: HeaveRefit, attitude: PitchYawMean,
                 accel_std=(0.02, 0.02, 0.05), gate: float | None = GATE_3DOF,
                 refit_period: float = 0.5, relock_after: float = 1.0,
                 settle_time: float = 0.5):
        self.localiser = localiser
        self.heave = heave
        self.attitude = attitude
        self.dt = heave.prior.dt
        self.gate = gate
        self._accel_std = np.broadcast_to(np.asarray(accel_std, dtype=float), (3,)).copy()
        self._refit_every = max(1, round(refit_period / self.dt))
        self._relock_after = max(1, round(relock_after / self.dt))
        self._settle_fixes = max(1, round(settle_time / self.dt))
        self.reset()

    def reset(self) -> None:
        self.heave.reset()
        self.filter = CubatureKalmanFilter(
            self.heave.model, position_measurement,
            white_acceleration_noise(self.dt, self._accel_std), np.eye(3))
        self.localiser.reset()
        self.attitude.reset()
        self._updates = 0
        self._gated_run = self._settling = 0
        self.last_measurement: np.ndarray | None = None
        self.counts = dict.fromkeys(COUNTS, 0)

    # ------------------------------------------------------------------ outputs
    @property
    def mean(self) -> np.ndarray | None:
        """The state estimate ``(x, y, z, vx, vy, vz)`` (``None`` before the first fix)."""
        return self.filter.mean

    @property
    def initialised(self) -> bool:
        return self.filter.initialised

    @property
    def settled(self) -> bool:
        """Whether the filter has taken in ``settle_time`` s of fixes since it (re)started."""
        return self._settling >= self._settle_fixes

    @property
    def rotation(self) -> np.ndarray | None:
        return self.attitude.rotation

    @property
    def pitch(self) -> float:
        return self.attitude.pitch

    @property
    def yaw(self) -> float:
        return self.attitude.yaw

    # ------------------------------------------------------------------ update
    def update(self, t: float, pixels, visible, joint_position) -> None:
        """Take in one observation at time ``t`` (s); call once per control period.

        Args:
            pixels: (2, 3, 2) marker corner pixels (left, right) x (A1, A2, A3).
            visible: (2, 3) which are valid.
            joint_position: (3,) arm joint angles at the time of the images.
        """
        self._updates += 1
        counts = self.counts
        fix = self.localiser.locate(pixels, visible, joint_position)
        counts["mismatched_corners"] += fix.rejected
        if self.filter.initialised:
            self.filter.predict()
        self.last_measurement = None
        first_attitude = self.attitude.rotation is None and fix.pitch is not None
        if first_attitude:
            self.attitude.update(fix.pitch, fix.yaw)
        if fix.count == 0 or self.attitude.rotation is None:
            counts["bridged"] += self.filter.initialised
            return
        cg, cov = self.localiser.auv_position(fix, self.attitude.rotation)
        if not self.filter.initialised or self._gated_run >= self._relock_after:
            # first fix, or the filter lost lock (every fix gated for a while)
            counts["reinitialised"] += self.filter.initialised
            p0 = np.diag(np.concatenate((np.diag(cov), np.full(3, 0.2**2))))
            self.filter.initialise(np.concatenate((cg, np.zeros(3))), p0)
            self._gated_run = self._settling = 0
        elif not self.filter.update(
                cg, cov, self.gate if self._settling >= self._settle_fixes else None):
            # (a settling filter has no basis yet to call a fix an outlier)
            counts["gated"] += 1
            self._gated_run += 1
            counts["bridged"] += 1
            return
        self._gated_run = 0
        self._settling += 1
        self.last_measurement = cg
        counts["fixes" if fix.count == 3 else "partial_fixes"] += 1
        if fix.pitch is not None and not first_attitude:  # only from fixes that passed the gate
            self.attitude.update(fix.pitch, fix.yaw)
        self.heave.record(t, cg[2])
        if self._updates % self._refit_every == 0 and self.heave.refit(t):
            counts["heave_fits"] += 1
            self.filter.transition = self.heave.model


class TrueStateAUVEstimator(_HeaveModelEstimate):
    """The estimator's outputs from the true AUV state (``ckf-pd-state``'s privileged stand-in).

    Each :meth:`update` takes the true CG position and velocity and the true
    pitch and yaw as the estimate (no marker, no filter, no noise); the heave
    is still refitted from the heights every ``refit_period`` s
    (:class:`HeaveRefit`), so a strike predicts with the fitted eq. 8 model
    as :class:`MarkerAUVEstimator`'s does. It is always ``settled``.

    Args:
        heave: the motion model and its refit.
        refit_period: s between heave fits.
    """

    settled = True
    last_measurement = None

    def __init__(self, heave: HeaveRefit, refit_period: float = 0.5):
        self.heave = heave
        self.dt = heave.prior.dt
        self._refit_every = max(1, round(refit_period / self.dt))
        self.reset()

    def reset(self) -> None:
        self.heave.reset()
        self.mean: np.ndarray | None = None
        self.pitch = self.yaw = math.nan
        self.rotation: np.ndarray | None = None
        self._updates = 0
        self.counts = dict.fromkeys(COUNTS, 0)

    @property
    def initialised(self) -> bool:
        return self.mean is not None

    def update(self, t: float, position, velocity, pitch: float, yaw: float) -> None:
        """The true CG position and velocity (3 each) and attitude (rad) at time ``t`` (s)."""
        self._updates += 1
        self.mean = np.array(np.concatenate((position, velocity)), dtype=float)
        self.pitch, self.yaw = float(pitch), float(yaw)
        self.rotation = attitude_rotation(self.pitch, self.yaw)
        self.heave.record(t, position[2])
        if self._updates % self._refit_every == 0 and self.heave.refit(t):
            self.counts["heave_fits"] += 1
