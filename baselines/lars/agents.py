"""[LTAT]'s LARS capture agents (declared in :mod:`baselines.catalogue`).

``ckf-pd``, ``ckf-pd-state`` and ``ltat-ckf-pd`` on ``auv_envs/LARSCapture-v0``. ``ckf-pd``:

``features`` observation (marker corners in both images, joint states)
-> stereo triangulation and hand-eye transform (eqs. 2-3) -> pitch and yaw
from the marker (eqs. 4-6) -> AUV centre of gravity -> cubature Kalman filter
on ``(x, y, z, vx, vy, vz)`` with eq. 8's motion model (eqs. 13-28), which
predicts alone while the marker is hidden -> capture strategy (hover 0.8 m
above, strike when the AUV starts to sink) -> quintic trajectory between
sampled targets -> inverse kinematics -> eq. 30's PD through eq. 29's model,
as normalised joint torques.

Eq. 8's heave frequency ``C`` and mean level are not given to the agent: it
starts from the documented scene (a 7 s swell about the floating AUV's level)
and refits both from its own measured heights
(:func:`~baselines.lars.estimation.ckf.fit_heave`).

The agent acts on any dict with the ``features`` layout (``pixels``,
``visible``, ``joint_position``, ``joint_velocity``), so a perception front
end ([LTAT]'s LTAT on ``stereo`` images) can stand in front of it through
:mod:`baselines.frontend`. It reads only the observation and the documented
calibration, never ``info``.

``ckf-pd-state`` (:class:`TrueStateCKFPDAgent`) is its privileged reference:
the same strategy, trajectory and control fed the true AUV state of the
``state`` observation, the bar the ``difficulty`` levels are calibrated
against (``docs/difficulty.md``).

``ltat-ckf-pd``: [LTAT]'s LTAT perception
(:class:`baselines.lars.perception.front_end.LTATFrontEnd`) turns the
``stereo`` observation into the ``features`` one, and ``ckf-pd`` acts on
that.

The parts live by role and this module only wires them from
``env.calibration``; :mod:`baselines.catalogue` declares the agents:

* perception: :class:`~baselines.lars.perception.marker.MarkerLocaliser`
  (marker fixes, eqs. 2-6);
* estimation: :class:`~baselines.lars.estimation.auv_state.MarkerAUVEstimator`
  (CKF, heave refit, relock, attitude mean; ``ckf-pd-state``:
  :class:`~baselines.lars.estimation.auv_state.TrueStateAUVEstimator`);
* control: :class:`~baselines.lars.control.capture.CapturePlanner` (phases,
  capture goal, quintic re-planning, IK) and
  :class:`~baselines.lars.control.arm.ComputedTorquePD` (eqs. 29-30).
"""

from __future__ import annotations

import math

import numpy as np

from baselines.lars.control.arm import CaptureStrategy, ComputedTorquePD, SampledTrajectory
from baselines.lars.control.capture import CapturePlanner
from baselines.lars.estimation.auv_state import (
    ATTITUDE_MEMORY,
    GATE_3DOF,
    HeaveRefit,
    MarkerAUVEstimator,
    PitchYawMean,
    TrueStateAUVEstimator,
    prior_heave_model,
)
from baselines.lars.perception.marker import MarkerLocaliser

ENV_IDS = ("auv_envs/LARSCapture-v0",)
FEATURE_KEYS = ("pixels", "visible", "joint_position", "joint_velocity")
#: The counts :meth:`CKFPDAgent.stats` reports first, in this order.
COUNT_KEYS = ("fixes", "partial_fixes", "bridged", "gated", "reinitialised",
              "mismatched_corners", "ik_failures", "heave_fits")


def heave_refit(calibration, window: float = 15.0, min_span: float = 3.0,
                omega_bounds=(0.5, 1.6)) -> HeaveRefit:
    """Eq. 8's heave refit from the documented scene: a 7 s swell prior about the level
    the AUV floats at (``ckf-pd``'s ``heave_*`` arguments)."""
    level = calibration.auv_freeboard - calibration.auv_diameter / 2.0
    return HeaveRefit(prior_heave_model(float(calibration.control_period), level),
                      window, min_span, omega_bounds)


def marker_estimator(calibration) -> MarkerAUVEstimator:
    """``ckf-pd``'s state estimator at its default settings, from the documented
    calibration: marker fixes (adapting the assumed pixel noise), heave refit,
    pitch/yaw mean and the gated CKF. It reads only ``features`` observations
    (:meth:`~baselines.lars.estimation.auv_state.MarkerAUVEstimator.update`)."""
    return MarkerAUVEstimator(MarkerLocaliser(calibration, None, adapt=True),
                              heave_refit(calibration), PitchYawMean())


def _check_env(env):
    cal = getattr(env, "calibration", None)
    if cal is None or not hasattr(cal, "stereo") or not hasattr(cal, "arm"):
        raise ValueError("ckf-pd needs a LARSCapture env (with a stereo/arm calibration)")
    if getattr(env, "control", "torque") != "torque":
        raise ValueError(f"ckf-pd outputs joint torques: it needs control='torque', "
                         f"got {env.control!r}")
    return cal


def _features(observation) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    if not isinstance(observation, dict) or any(k not in observation for k in FEATURE_KEYS):
        raise ValueError(f"ckf-pd expects the 'features' observation dict with keys {FEATURE_KEYS}")
    q = np.asarray(observation["joint_position"], dtype=float)
    qd = np.asarray(observation["joint_velocity"], dtype=float)
    if q.shape != (3,) or qd.shape != (3,) or not (np.all(np.isfinite(q))
                                                   and np.all(np.isfinite(qd))):
        raise ValueError("joint_position and joint_velocity must be finite (3,) vectors")
    return observation["pixels"], observation["visible"], q, qd


class CKFPDAgent:
    """Stereo marker fixes -> CKF -> quintic + IK + computed-torque PD [LTAT].

    Wiring, from ``env.calibration``: :class:`MarkerLocaliser` (perception)
    -> :class:`~baselines.lars.estimation.auv_state.MarkerAUVEstimator`
    (estimation, with :class:`~baselines.lars.estimation.auv_state.HeaveRefit`
    and :class:`~baselines.lars.estimation.auv_state.PitchYawMean`) ->
    :class:`~baselines.lars.control.capture.CapturePlanner` (capture
    strategy, quintic, IK) -> :class:`~baselines.lars.control.arm.ComputedTorquePD`.

    Args:
        env: an unwrapped ``LARSCapture`` env with ``control="torque"``.
        pixel_std: pixel noise (px) the fixes assume at the start (default: the
            calibration's; raised to the noise measured in the observations,
            see :class:`~baselines.lars.perception.marker.MarkerLocaliser`).
        accel_std: (3,) white-acceleration process noise of the CKF, m/s^2.
        gate: chi-square gate on the fixes' innovation (``None``: no gate).
        hover_height: arm end above the AUV's top line while tracking, m
            (:class:`~baselines.lars.control.arm.CaptureStrategy`).
        strike_duration: s from the strike decision to contact.
        follow_timeout: s of following before retreating to tracking.
        sample_period: s between sampled targets (quintic re-plans).
        lookahead: s ahead of the present the tracking targets are sampled.
        heave_window: s of past heights the heave fit uses.
        heave_min_span: s of heights needed before the first fit (and before
            a strike).
        heave_refit_period: s between heave fits.
        heave_omega_bounds: rad/s searched by the fit.
        attitude_memory: fixes the pitch/yaw running mean spans.
        relock_after: s of consecutive gated fixes after which the filter
            restarts from the latest fix (it has lost lock, not the fixes).
        settle_time: s of fixes a fresh filter takes in before the arm moves on
            it (until then the arm holds still, so the marker stays in view).
        adapt_pixel_noise: raise the assumed pixel noise to the one measured
            in the observations (``MarkerLocaliser(adapt=...)``).
        strike: ``False`` tracks only (for estimation experiments).
        kp: eq. 30's proportional gain (default: ``calibration.position_gains``).
        kd: eq. 30's derivative gain (default: ``calibration.position_gains``).
    """

    def __init__(self, env, pixel_std: float | None = None, accel_std=(0.02, 0.02, 0.05),
                 gate: float | None = GATE_3DOF, hover_height: float = 0.8,
                 strike_duration: float = 1.5, follow_timeout: float = 2.0,
                 sample_period: float = 0.2, lookahead: float = 0.4,
                 heave_window: float = 15.0, heave_min_span: float = 3.0,
                 heave_refit_period: float = 0.5,
                 heave_omega_bounds=(0.5, 1.6), attitude_memory: int = ATTITUDE_MEMORY,
                 relock_after: float = 1.0, settle_time: float = 0.5,
                 adapt_pixel_noise: bool = True, strike: bool = True,
                 kp: float | None = None, kd: float | None = None):
        cal = _check_env(env)
        self.calibration = cal
        self.dt = float(cal.control_period)
        if not (sample_period >= self.dt and lookahead >= sample_period):
            raise ValueError("need control_period <= sample_period <= lookahead, got "
                             f"{self.dt}, {sample_period}, {lookahead}")
        if attitude_memory < 1 or heave_min_span <= 0 or heave_window < heave_min_span:
            raise ValueError("need attitude_memory >= 1 and 0 < heave_min_span <= heave_window")
        self.localiser = MarkerLocaliser(cal, pixel_std, adapt=adapt_pixel_noise)
        default_kp, default_kd = cal.position_gains
        self.controller = ComputedTorquePD(
            cal.arm, cal.torque_limits, default_kp if kp is None else kp,
            default_kd if kd is None else kd)
        strategy = CaptureStrategy(hover_height, strike_duration, follow_timeout)
        radius = cal.auv_diameter / 2.0
        heave = heave_refit(cal, heave_window, heave_min_span, heave_omega_bounds)
        self.estimator = self._make_estimator(
            heave, PitchYawMean(attitude_memory), accel_std=accel_std, gate=gate,
            refit_period=heave_refit_period, relock_after=relock_after, settle_time=settle_time)
        self.planner = CapturePlanner(
            cal.arm, cal.joint_limits, self.localiser,
            camera_in_end=0.5 * (cal.left_in_end[:3, 3] + cal.right_in_end[:3, 3]),
            tip_in_end=np.asarray(cal.capture_tip_in_end, dtype=float), auv_radius=radius,
            dt=self.dt, strategy=strategy, trajectory=SampledTrajectory(),
            sample_period=sample_period, lookahead=lookahead, strike=strike)
        self.reset()

    def _make_estimator(self, heave: HeaveRefit, attitude: PitchYawMean, **filter_args):
        return MarkerAUVEstimator(self.localiser, heave, attitude, **filter_args)

    # ------------------------------------------------------------------ protocol
    def reset(self, seed: int | None = None) -> None:
        del seed  # deterministic
        self.estimator.reset()
        self.planner.reset()
        self._step = 0

    def act(self, observation, info: dict) -> np.ndarray:
        del info  # never read: the agent sees only the observation and the calibration
        pixels, visible, q, qd = _features(observation)
        t = self._step * self.dt
        self._step += 1
        self.estimator.update(t, pixels, visible, q)
        return self.controller.action(q, qd, *self.planner.reference(t, q, qd, self.estimator))

    # ------------------------------------------------------------------ queries
    @property
    def last_measurement(self) -> np.ndarray | None:
        """The AUV's CG measured from the last observation (``None`` when it gave none)."""
        return self.estimator.last_measurement

    def position_estimate(self) -> np.ndarray | None:
        """The AUV's CG in the world (3,), the CKF's estimate; ``None`` before the first fix.

        It is the estimate at the time of the last observation given to
        :meth:`act`: compare it with the ``info["true_position"]`` that came
        with that observation.
        """
        return None if not self.estimator.initialised else self.estimator.mean[:3].copy()

    def attitude_estimate(self) -> tuple[float, float] | None:
        """``(pitch, yaw)`` in radians (running mean of the fixes), ``None`` before one."""
        est = self.estimator
        return None if est.rotation is None else (est.pitch, est.yaw)

    def stats(self) -> dict:
        """Counts of this episode and the current estimates.

        ``fixes``/``partial_fixes``: frames whose 3/1-2 triangulated corners
        updated the filter; ``bridged``: frames the filter only predicted
        (marker hidden, or its fix gated); ``gated``: fixes the innovation
        gate rejected; ``reinitialised``: restarts after losing lock;
        ``mismatched_corners``: corners dropped for a non-positive disparity;
        ``ik_failures``: references out of reach (the last one held);
        ``heave_fits``; ``phase``, ``strikes``, ``heave_period`` (s),
        ``pixel_std`` (px, the noise the fixes assume now),
        ``pitch_deg``, ``yaw_deg``.
        """
        est, fit = self.estimator, self.estimator.fit
        counts = dict(est.counts, ik_failures=self.planner.ik_failures)
        out = {key: counts[key] for key in COUNT_KEYS}
        out.update(
            phase=self.planner.strategy.phase,
            strikes=self.planner.strategy.strikes,
            heave_period=(2.0 * math.pi / fit.omega) if fit else math.nan,
            pixel_std=self.localiser.pixel_std,
            pitch_deg=math.degrees(est.pitch),
            yaw_deg=math.degrees(est.yaw),
        )
        return out


class TrueStateCKFPDAgent(CKFPDAgent):
    """Privileged reference: ``ckf-pd``'s capture strategy, heave fit, quintic, IK
    and PD fed the true AUV state from the ``state`` observation.

    What it measures is how much of the task the arm controller alone can
    solve: the estimate (:class:`~baselines.lars.estimation.auv_state.TrueStateAUVEstimator`)
    is the true centre of gravity and velocity every step (no marker, no
    triangulation, no noise), the attitude the true pitch and yaw. Positions
    are taken in the arm's (ship's) frame as ``ckf-pd``'s fixes are: the
    forward kinematics of the joint angles plus the observed AUV-minus-arm-end
    offset, velocities likewise (the ship's small roll and pitch rotate the
    offset by a few degrees at most; ``ckf-pd`` makes the same approximation
    through its levelled head). The strike still predicts with the fitted
    eq. 8 model, as ``ckf-pd`` does.
    """

    def _make_estimator(self, heave: HeaveRefit, attitude: PitchYawMean, **filter_args):
        del attitude  # the true attitude, not a mean of fixes
        return TrueStateAUVEstimator(heave, filter_args["refit_period"])

    def act(self, observation, info: dict) -> np.ndarray:
        del info  # the privileged state is the observation itself
        obs = None if isinstance(observation, dict) else np.asarray(observation, dtype=float)
        if obs is None or obs.shape != (24,) or not np.all(np.isfinite(obs)):
            raise ValueError("ckf-pd-state expects the finite (24,) 'state' observation")
        q, qd = obs[0:3], obs[3:6]
        arm = self.calibration.arm
        end = arm.forward_kinematics(q)
        position = end + obs[12:15]
        velocity = arm.jacobian(q) @ qd + obs[15:18] - obs[9:12]
        t = self._step * self.dt
        self._step += 1
        self.estimator.update(t, position, velocity, float(obs[21]), float(obs[22]))
        return self.controller.action(q, qd, *self.planner.reference(t, q, qd, self.estimator))


def make_front_end(env):
    """LTAT front end from the env's documented calibration (weights: the shipped ones)."""
    if getattr(env, "obs_mode", None) != "stereo":
        raise ValueError(f"ltat-ckf-pd needs obs_mode='stereo', got "
                         f"{getattr(env, 'obs_mode', None)!r}")
    # Imported here: torch and the weights load only when the agent is built.
    from baselines.lars.perception.front_end import LTATFrontEnd

    return LTATFrontEnd(env.calibration)
