"""LARS arm control: quintic trajectory, inverse kinematics, PD, capture strategy [LTAT].

[LTAT], §2.4 (eqs. 29-30) and §3.4:

* :class:`QuinticSegment`: fifth-order polynomial between two sampled
  targets with position, velocity and acceleration given at both ends ("we
  performed fifth-order polynomial interpolation trajectory planning between
  the sampling points"). Over ``tau = t - t0`` in ``[0, T]``,
  ``p(tau) = sum_k c_k tau^k`` (k = 0..5) with ``c_0 = p0``, ``c_1 = v0``,
  ``c_2 = a0 / 2`` and, with ``dp = p1 - p0``::

      c_3 = (20 dp - (8 v1 + 12 v0) T - (3 a0 - a1) T^2) / (2 T^3)
      c_4 = (-30 dp + (14 v1 + 16 v0) T + (3 a0 - 2 a1) T^2) / (2 T^4)
      c_5 = (12 dp - 6 (v1 + v0) T + (a1 - a0) T^2) / (2 T^5)

  so that ``p, p', p''`` equal ``(p0, v0, a0)`` at ``tau = 0`` and
  ``(p1, v1, a1)`` at ``tau = T``.
* :class:`SampledTrajectory`: re-plans a quintic from the current reference
  to a new sampled target, so the reference stays continuous in position,
  velocity and acceleration.
* :func:`joint_reference`: inverse kinematics of a Cartesian reference
  (``ArmModel.inverse_kinematics`` and its Jacobian) to joint angle, rate and
  acceleration: ``q = IK(p)``, ``qd = J^-1 v``, ``qdd = J^-1 (a - Jdot qd)``.
* :class:`ComputedTorquePD`: eq. 30's PD law on the joint error
  ``e = q_ref - q``, ``qdd = qdd_ref + Kd e' + Kp e`` (``Kp = 160``,
  ``Kd = 20``), through eq. 29's model ``tau = M(q) qdd + C(q, qd) + G(q)``,
  as torques normalised by the actuator limits.
* :class:`CaptureStrategy`: "we kept the LARS end approximately 0.8 m above
  the AUV ... when the AUV began to sink ..., we controlled the LARS to quickly
  approach the AUV on the Z-axis and complete the capture" (§3.4).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

# Powers and derivative factors of the quintic, built once (evaluated every step).
_EXPONENTS = np.arange(6)
_RATE_FACTORS = np.arange(1, 6)
_ACCEL_FACTORS = np.array([2.0, 6.0, 12.0, 20.0])


@dataclasses.dataclass(frozen=True)
class QuinticSegment:
    """``p(t) = sum_k c_k (t - t0)^k``, k = 0..5, for ``t`` in ``[t0, t1]``.

    Attributes:
        t0, t1: start and end times, s.
        coefficients: (6, d) polynomial coefficients, lowest order first.
    """

    t0: float
    t1: float
    coefficients: np.ndarray

    @classmethod
    def between(cls, t0: float, t1: float, start, end) -> QuinticSegment:
        """The quintic with ``start = (p0, v0, a0)`` at ``t0`` and ``end = (p1, v1, a1)`` at ``t1``.

        Raises:
            ValueError: if ``t1 <= t0`` or a boundary value is non-finite.
        """
        duration = float(t1) - float(t0)
        if not duration > 0:
            raise ValueError(f"a quintic needs t1 > t0, got {t0}, {t1}")
        p0, v0, a0 = (np.atleast_1d(np.asarray(x, dtype=float)) for x in start)
        p1, v1, a1 = (np.atleast_1d(np.asarray(x, dtype=float)) for x in end)
        values = np.stack(np.broadcast_arrays(p0, v0, a0, p1, v1, a1))
        if not np.all(np.isfinite(values)):
            raise ValueError("quintic boundary values must be finite")
        p0, v0, a0, p1, v1, a1 = values
        t = duration
        dp = p1 - p0
        c3 = (20.0 * dp - (8.0 * v1 + 12.0 * v0) * t - (3.0 * a0 - a1) * t**2) / (2.0 * t**3)
        c4 = (-30.0 * dp + (14.0 * v1 + 16.0 * v0) * t + (3.0 * a0 - 2.0 * a1) * t**2) / (
            2.0 * t**4)
        c5 = (12.0 * dp - 6.0 * (v1 + v0) * t + (a1 - a0) * t**2) / (2.0 * t**5)
        return cls(float(t0), float(t1), np.stack((p0, v0, 0.5 * a0, c3, c4, c5)))

    def evaluate(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at ``t``, clamped to ``[t0, t1]``."""
        tau = min(max(float(t), self.t0), self.t1) - self.t0
        c = self.coefficients
        powers = tau**_EXPONENTS
        p = powers @ c
        v = (_RATE_FACTORS * powers[:5]) @ c[1:]
        a = (_ACCEL_FACTORS * powers[:4]) @ c[2:]
        return p, v, a


class SampledTrajectory:
    """A Cartesian reference made of quintics between sampled targets.

    Each :meth:`replan` starts a new segment at the current reference (so the
    reference stays C2-continuous) and ends at the new target.
    """

    def __init__(self):
        self.segment: QuinticSegment | None = None

    def reset(self) -> None:
        self.segment = None

    def replan(self, t: float, start, t_target: float, target) -> None:
        """Plan from ``start = (p, v, a)`` at ``t`` (used only before the first plan,
        else the current reference) to ``target = (p, v, a)`` at ``t_target``."""
        if self.segment is not None:
            start = self.segment.evaluate(t)
        self.segment = QuinticSegment.between(t, t_target, start, target)

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.segment is None:
            raise RuntimeError("replan() before reference()")
        return self.segment.evaluate(t)


def joint_reference(arm, p, v, a, eps: float = 1e-4):
    """Joint angle, rate and acceleration (3 each) that move the arm end along ``(p, v, a)``.

    ``q = IK(p)``, ``qd = J^-1 v`` and ``qdd = J^-1 (a - Jdot qd)``, with
    ``Jdot qd`` from a central difference of the Jacobian along ``qd``.

    Raises:
        ValueError: if ``p`` is out of reach or the Jacobian is singular there.
    """
    q = arm.inverse_kinematics(p)
    jac = arm.jacobian(q)
    try:
        qd = np.linalg.solve(jac, v)
        jdot_qd = (arm.jacobian(q + eps * qd) - arm.jacobian(q - eps * qd)) @ qd / (2.0 * eps)
        qdd = np.linalg.solve(jac, np.asarray(a, dtype=float) - jdot_qd)
    except np.linalg.LinAlgError as exc:
        raise ValueError(f"the arm's Jacobian is singular at q = {q.tolist()}") from exc
    return q, qd, qdd


class ComputedTorquePD:
    """Eq. 30's PD on the joint error through eq. 29's dynamics.

    ``tau = M(q) (qdd_ref + Kd (qd_ref - qd) + Kp (q_ref - q)) + C(q, qd) + G(q)``,
    so the joint error obeys ``e'' + Kd e' + Kp e = 0`` where the model is
    exact; the action is ``tau`` over the torque limits, clipped to [-1, 1].

    Args:
        arm: the ``ArmModel`` (M, C, G of eq. 29).
        torque_limits: (3,) N m, the env's action scale.
        kp: eq. 30's proportional gain (1/s^2); [LTAT] §3.4's Kp = 160 is in the
            env's ``calibration.position_gains``.
        kd: eq. 30's derivative gain (1/s); [LTAT] §3.4's Kd = 20.
    """

    def __init__(self, arm, torque_limits, kp: float, kd: float):
        if not (kp > 0 and kd > 0):
            raise ValueError(f"gains must be positive, got kp={kp}, kd={kd}")
        self.arm = arm
        self.limits = np.asarray(torque_limits, dtype=float)
        self.kp, self.kd = float(kp), float(kd)

    def torque(self, q, qd, q_ref, qd_ref, qdd_ref) -> np.ndarray:
        accel = (np.asarray(qdd_ref, dtype=float) + self.kd * (np.asarray(qd_ref) - qd)
                 + self.kp * (np.asarray(q_ref) - q))
        return self.arm.inverse_dynamics(q, qd, accel)

    def action(self, q, qd, q_ref, qd_ref, qdd_ref) -> np.ndarray:
        """Normalised torque action (3,) in [-1, 1]."""
        return np.clip(self.torque(q, qd, q_ref, qd_ref, qdd_ref) / self.limits, -1.0, 1.0)


# ---------------------------------------------------------------- strategy (§3.4)
TRACK, STRIKE, FOLLOW = "track", "strike", "follow"


@dataclasses.dataclass
class CaptureStrategy:
    """When to hover, strike and follow ([LTAT], §3.4).

    ``track``: hold the arm end ``hover_height`` above the AUV's top with the
    cameras over the marker. ``strike``: once the estimate is ready and the
    AUV "begins to sink" (its estimated heave rate turns from rising to
    sinking), plan one quintic that brings the capture tip onto the capture
    point ``strike_duration`` s later, matching the AUV's predicted velocity
    and acceleration there. ``follow``: keep the tip on the capture point;
    after ``follow_timeout`` s without the episode ending, retreat to
    ``track`` and wait for the next crest.

    Attributes:
        hover_height: arm end above the AUV's top line while tracking, m.
        strike_duration: s from the strike decision to contact.
        follow_timeout: s.
        phase: the current phase.
        strike_end: contact time of the current strike.
        strikes: strikes started this episode.
    """

    hover_height: float = 0.8
    strike_duration: float = 1.5
    follow_timeout: float = 2.0
    phase: str = TRACK
    strike_end: float = math.nan
    strikes: int = 0
    _last_rate: float = math.nan

    def __post_init__(self):
        for name in ("hover_height", "strike_duration", "follow_timeout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value}")

    def reset(self) -> None:
        self.phase, self.strike_end, self.strikes = TRACK, math.nan, 0
        self._last_rate = math.nan

    def update(self, t: float, heave_rate: float, ready: bool) -> str:
        """Advance the phase at time ``t`` given the AUV's estimated heave rate (m/s)."""
        sinking_starts = self._last_rate > 0.0 >= heave_rate
        self._last_rate = heave_rate
        if self.phase == TRACK and ready and sinking_starts:
            self.phase, self.strike_end = STRIKE, t + self.strike_duration
            self.strikes += 1
        elif self.phase == STRIKE and t >= self.strike_end:
            self.phase = FOLLOW
        elif self.phase == FOLLOW and t >= self.strike_end + self.follow_timeout:
            self.phase = TRACK
        return self.phase
