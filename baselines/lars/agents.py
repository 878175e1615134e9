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

The parts live by role: :mod:`baselines.lars.perception`,
:mod:`baselines.lars.estimation`, :mod:`baselines.lars.control`; this module
only wires them; :mod:`baselines.catalogue` declares the agents.
"""

from __future__ import annotations

import math

import numpy as np

from baselines.lars.control.arm import (
    FOLLOW,
    STRIKE,
    CaptureStrategy,
    ComputedTorquePD,
    SampledTrajectory,
    joint_reference,
)
from baselines.lars.estimation.ckf import (
    CubatureKalmanFilter,
    HeaveSurgeModel,
    fit_heave,
    position_measurement,
    white_acceleration_noise,
)
from baselines.lars.perception.marker import MarkerLocaliser, attitude_rotation

ENV_IDS = ("auv_envs/LARSCapture-v0",)
FEATURE_KEYS = ("pixels", "visible", "joint_position", "joint_velocity")
#: 99.9 % point of the chi-square distribution with 3 degrees of freedom: the
#: innovation gate against mismatched corners.
GATE_3DOF = 16.27
#: Heave prior before the first fit: a 7 s swell (the paper's "C is
#: determined by the sine wave period") about the level the AUV floats at.
PRIOR_HEAVE_PERIOD = 7.0


def _check_env(env):
    cal = getattr(env, "calibration", None)
    if cal is None or not hasattr(cal, "stereo") or not hasattr(cal, "arm"):
        raise ValueError("ckf-pd needs a LARSCaptureEnv (with a stereo/arm calibration)")
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

    Args:
        env: an unwrapped ``LARSCaptureEnv`` with ``control="torque"``.
        pixel_std: pixel noise (px) the fixes assume at the start (default: the
            calibration's; raised to the noise measured in the observations,
            see :class:`~baselines.lars.perception.marker.MarkerLocaliser`).
        accel_std: (3,) white-acceleration process noise of the CKF, m/s^2.
        gate: chi-square gate on the fixes' innovation (``None``: no gate).
        hover_height, strike_duration, follow_timeout: see
            :class:`~baselines.lars.control.arm.CaptureStrategy`.
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
        kp, kd: eq. 30's gains (default: ``calibration.position_gains``).
    """

    def __init__(self, env, pixel_std: float | None = None, accel_std=(0.02, 0.02, 0.05),
                 gate: float | None = GATE_3DOF, hover_height: float = 0.8,
                 strike_duration: float = 1.5, follow_timeout: float = 2.0,
                 sample_period: float = 0.2, lookahead: float = 0.4,
                 heave_window: float = 15.0, heave_min_span: float = 3.0,
                 heave_refit_period: float = 0.5,
                 heave_omega_bounds=(0.5, 1.6), attitude_memory: int = 50,
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
        self.strategy = CaptureStrategy(hover_height, strike_duration, follow_timeout)
        self.trajectory = SampledTrajectory()
        self.strike_enabled = bool(strike)
        self.gate = gate
        self._accel_std = np.broadcast_to(np.asarray(accel_std, dtype=float), (3,)).copy()
        self._replan_every = max(1, round(sample_period / self.dt))
        self._lookahead = float(lookahead)
        self._heave_window = float(heave_window)
        self._heave_min_span = float(heave_min_span)
        self._refit_every = max(1, round(heave_refit_period / self.dt))
        self._omega_bounds = tuple(float(b) for b in heave_omega_bounds)
        self._attitude_memory = int(attitude_memory)
        self._relock_after = max(1, round(relock_after / self.dt))
        self._settle_fixes = max(1, round(settle_time / self.dt))
        # geometry (end frame, calibration): cameras' midpoint and capture tip
        self._camera_in_end = 0.5 * (cal.left_in_end[:3, 3] + cal.right_in_end[:3, 3])
        self._tip_in_end = np.asarray(cal.capture_tip_in_end, dtype=float)
        self._radius = cal.auv_diameter / 2.0
        self._prior_model = HeaveSurgeModel(
            self.dt, 2.0 * math.pi / PRIOR_HEAVE_PERIOD, cal.auv_freeboard - self._radius)
        self.reset()

    # ------------------------------------------------------------------ protocol
    def reset(self, seed: int | None = None) -> None:
        del seed  # deterministic
        self.model = self._prior_model
        self.filter = CubatureKalmanFilter(
            self.model, position_measurement, white_acceleration_noise(self.dt, self._accel_std),
            np.eye(3))
        self.localiser.reset()
        self.strategy.reset()
        self.trajectory.reset()
        self._step = 0
        self._hold: np.ndarray | None = None
        self._pitch = self._yaw = math.nan
        self._attitude_fixes = 0
        self._rotation: np.ndarray | None = None
        self._heights: list[tuple[float, float]] = []
        self._heave = None
        self._gated_run = self._settling = 0
        self._last_ref = None
        self.last_measurement: np.ndarray | None = None
        self._stats = dict.fromkeys(
            ("fixes", "partial_fixes", "bridged", "gated", "reinitialised",
             "mismatched_corners", "ik_failures", "heave_fits"), 0)

    def act(self, observation, info: dict) -> np.ndarray:
        del info  # never read: the agent sees only the observation and the calibration
        pixels, visible, q, qd = _features(observation)
        t = self._step * self.dt
        self._step += 1
        self._estimate(t, pixels, visible, q)
        if self._settling < self._settle_fixes:
            # no (or a fresh) estimate: hold the arm where it is until the filter settles
            if self._hold is None:
                self._hold = q.copy()
            self.trajectory.reset()
            return self.controller.action(q, qd, self._hold, np.zeros(3), np.zeros(3))
        self._hold = None
        return self._control(t, q, qd)

    # ------------------------------------------------------------------ queries
    def position_estimate(self) -> np.ndarray | None:
        """The AUV's CG in the world (3,), the CKF's estimate; ``None`` before the first fix.

        It is the estimate at the time of the last observation given to
        :meth:`act`: compare it with the ``info["true_position"]`` that came
        with that observation.
        """
        return None if not self.filter.initialised else self.filter.mean[:3].copy()

    def attitude_estimate(self) -> tuple[float, float] | None:
        """``(pitch, yaw)`` in radians (running mean of the fixes), ``None`` before one."""
        return None if self._rotation is None else (self._pitch, self._yaw)

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
        out = dict(self._stats)
        out.update(
            phase=self.strategy.phase,
            strikes=self.strategy.strikes,
            heave_period=(2.0 * math.pi / self._heave.omega) if self._heave else math.nan,
            pixel_std=self.localiser.pixel_std,
            pitch_deg=math.degrees(self._pitch),
            yaw_deg=math.degrees(self._yaw),
        )
        return out

    # ------------------------------------------------------------------ estimation
    def _estimate(self, t: float, pixels, visible, q) -> None:
        fix = self.localiser.locate(pixels, visible, q)
        self._stats["mismatched_corners"] += fix.rejected
        if self.filter.initialised:
            self.filter.predict()
        self.last_measurement = None
        first_attitude = self._rotation is None and fix.pitch is not None
        if first_attitude:
            self._update_attitude(fix.pitch, fix.yaw)
        if fix.count == 0 or self._rotation is None:
            self._stats["bridged"] += self.filter.initialised
            return
        cg, cov = self.localiser.auv_position(fix, self._rotation)
        if not self.filter.initialised or self._gated_run >= self._relock_after:
            # first fix, or the filter lost lock (every fix gated for a while)
            self._stats["reinitialised"] += self.filter.initialised
            p0 = np.diag(np.concatenate((np.diag(cov), np.full(3, 0.2**2))))
            self.filter.initialise(np.concatenate((cg, np.zeros(3))), p0)
            self._gated_run = self._settling = 0
        elif not self.filter.update(
                cg, cov, self.gate if self._settling >= self._settle_fixes else None):
            # (a settling filter has no basis yet to call a fix an outlier)
            self._stats["gated"] += 1
            self._gated_run += 1
            self._stats["bridged"] += 1
            return
        self._gated_run = 0
        self._settling += 1
        self.last_measurement = cg
        self._stats["fixes" if fix.count == 3 else "partial_fixes"] += 1
        if fix.pitch is not None and not first_attitude:  # only from fixes that passed the gate
            self._update_attitude(fix.pitch, fix.yaw)
        self._heights.append((t, float(cg[2])))
        if self._step % self._refit_every == 0:
            self._refit_heave(t)

    def _update_attitude(self, pitch: float, yaw: float) -> None:
        self._attitude_fixes += 1
        w = 1.0 / min(self._attitude_fixes, self._attitude_memory)
        if self._rotation is None:
            self._pitch, self._yaw = pitch, yaw
        else:
            self._pitch += w * (pitch - self._pitch)
            self._yaw += w * (yaw - self._yaw)
        self._rotation = attitude_rotation(self._pitch, self._yaw)

    def _refit_heave(self, t: float) -> None:
        while self._heights and self._heights[0][0] < t - self._heave_window:
            self._heights.pop(0)
        if not self._heights or t - self._heights[0][0] < self._heave_min_span:
            return
        times, z = np.array(self._heights).T
        fit = fit_heave(times, z, self._omega_bounds)
        self._heave = fit
        self._stats["heave_fits"] += 1
        self.model = self.model.with_heave(fit.omega, fit.mean)
        self.filter.transition = self.model

    # ------------------------------------------------------------------ control
    def _control(self, t: float, q, qd) -> np.ndarray:
        state = self.filter.mean
        ready = self._heave is not None and self.strike_enabled
        before = self.strategy.phase
        phase = self.strategy.update(t, float(state[5]), ready)
        sample = self._step % self._replan_every == 0
        if self.trajectory.segment is None or phase != before or sample:
            self._replan(t, phase, q, qd)
        p, v, a = self.trajectory.reference(t)
        try:
            self._last_ref = joint_reference(self.calibration.arm, p, v, a)
        except ValueError:
            self._stats["ik_failures"] += 1
            if self._last_ref is None:
                self._last_ref = (self._hold, np.zeros(3), np.zeros(3))
        q_ref, qd_ref, qdd_ref = self._last_ref
        limits = self.calibration.joint_limits
        q_ref = np.clip(q_ref, limits[:, 0], limits[:, 1])
        return self.controller.action(q, qd, q_ref, qd_ref, qdd_ref)

    def _replan(self, t: float, phase: str, q, qd) -> None:
        arm = self.calibration.arm
        start = (arm.forward_kinematics(q), arm.jacobian(q) @ qd, np.zeros(3))
        if phase == STRIKE:
            t_target = max(self.strategy.strike_end, t + self.dt)
        else:
            t_target = t + self._lookahead
        goal = self._goal(phase, t_target - t)
        self.trajectory.replan(t, start, t_target, goal)

    def _goal(self, phase: str, horizon: float):
        """The arm end's target ``(p, v, a)`` ``horizon`` s from now."""
        pos, vel, acc = self.model.kinematics(self.filter.mean, horizon)
        rot = self._rotation
        if phase in (STRIKE, FOLLOW):
            # the capture tip on the capture point (the tip hangs straight below the end)
            return self.localiser.capture_point(pos, rot) - self._tip_in_end, vel, acc
        top = pos[2] + self._radius
        marker = self.localiser.marker_centre(pos, rot)
        end = np.array([marker[0], marker[1], top + self.strategy.hover_height])
        for _ in range(3):  # the cameras sit off the end, turned with the slew angle
            try:
                slew = self.calibration.arm.inverse_kinematics(end)[0]
            except ValueError:
                break
            c, s = math.cos(slew), math.sin(slew)
            ox, oy = self._camera_in_end[:2]
            end[:2] = marker[:2] - (c * ox - s * oy, s * ox + c * oy)
        return end, vel, acc


class TrueStateCKFPDAgent(CKFPDAgent):
    """Privileged reference: ``ckf-pd``'s capture strategy, heave fit, quintic, IK
    and PD fed the true AUV state from the ``state`` observation.

    What it measures is how much of the task the arm controller alone can
    solve: the filter's state is the true centre of gravity and velocity every
    step (no marker, no triangulation, no noise), the attitude the true pitch
    and yaw. Positions are taken in the arm's (ship's) frame as ``ckf-pd``'s
    fixes are: the forward kinematics of the joint angles plus the observed
    AUV-minus-arm-end offset, velocities likewise (the ship's small roll and
    pitch rotate the offset by a few degrees at most; ``ckf-pd`` makes the
    same approximation through its levelled head). The strike still predicts
    with the fitted eq. 8 model, as ``ckf-pd`` does.
    """

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
        self.filter.initialise(np.concatenate((position, velocity)), np.eye(6) * 1e-8)
        self._pitch, self._yaw = float(obs[21]), float(obs[22])
        self._rotation = attitude_rotation(self._pitch, self._yaw)
        self._heights.append((t, float(position[2])))
        if self._step % self._refit_every == 0:
            self._refit_heave(t)
        if self._hold is None:
            self._hold = q.copy()
        return self._control(t, q, qd)


def make_front_end(env):
    """LTAT front end from the env's documented calibration (weights: the shipped ones)."""
    if getattr(env, "obs_mode", None) != "stereo":
        raise ValueError(f"ltat-ckf-pd needs obs_mode='stereo', got "
                         f"{getattr(env, 'obs_mode', None)!r}")
    # Imported here: torch and the weights load only when the agent is built.
    from baselines.lars.perception.front_end import LTATFrontEnd

    return LTATFrontEnd(env.calibration)
