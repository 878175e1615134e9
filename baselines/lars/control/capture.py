"""The LARS capture planner: phase, arm-end goal, quintic re-planning, joint reference ([LTAT]).

[LTAT], §3.4: "we kept the LARS end approximately 0.8 m above the AUV ...
when the AUV began to sink ..., we controlled the LARS to quickly approach the
AUV on the Z-axis and complete the capture", with "fifth-order polynomial
interpolation trajectory planning between the sampling points".
:class:`CapturePlanner` turns the AUV's estimate into the arm's joint
reference each control period; :class:`~baselines.lars.control.arm.ComputedTorquePD`
turns that into torques.
"""

from __future__ import annotations

import math

import numpy as np

from baselines.lars.control.arm import (
    FOLLOW,
    STRIKE,
    CaptureStrategy,
    SampledTrajectory,
    joint_reference,
)


class CapturePlanner:
    """The arm's joint reference for the capture, from the AUV's state estimate [LTAT].

    Each :meth:`reference` (one per control period ``T``):

    * while the estimate is not ``settled``: hold the joint angles the arm had
      when the hold began (so the marker stays in view), no trajectory;
    * else advance the phase (:class:`~baselines.lars.control.arm.CaptureStrategy`,
      on the estimated heave rate ``vz``; a strike only once the heave has
      been fitted and ``strike`` is on), and re-plan the quintic
      (:class:`~baselines.lars.control.arm.SampledTrajectory`) from the current
      reference when there is none, when the phase changes, and every
      ``sample_period`` s. The target, with ``h`` its horizon and
      ``(p, v, a)`` the AUV's CG ``h`` s ahead under eq. 8's model
      (``estimate.kinematics(h)``):

      - ``track`` (``h = lookahead``): the arm end ``hover_height`` above the
        AUV's top line (``p_z + auv_radius``), placed so that the cameras'
        midpoint (``camera_in_end``, turned with the slew angle ``psi``:
        ``(c ox - s oy, s ox + c oy)``, ``c = cos psi``, ``s = sin psi``) is
        over the marker's centroid; ``psi`` from the inverse kinematics,
        iterated three times;
      - ``strike``/``follow`` (``h`` to the strike's contact time, at least
        ``T``): the capture tip (``tip_in_end`` below the end) on the
        capture point, matching the AUV's ``v`` and ``a``.

      The Cartesian reference at ``t`` is turned into joint angle, rate and
      acceleration by :func:`~baselines.lars.control.arm.joint_reference`; a
      reference out of reach keeps the last one (counted in
      ``ik_failures``); angles are clipped to the joint limits.

    Args:
        arm: the ``ArmModel`` (kinematics).
        joint_limits: (3, 2) joint angle limits, rad.
        geometry: the AUV points, ``capture_point(cg, rotation)`` and
            ``marker_centre(cg, rotation)``
            (:class:`~baselines.lars.perception.marker.MarkerLocaliser`).
        camera_in_end: (3,) the cameras' midpoint in the arm-end frame, m.
        tip_in_end: (3,) the capture tip in the arm-end frame, m.
        auv_radius: m (the hull's top line above the CG).
        dt: the control period ``T``, s.
        strategy: the phases (default: ``CaptureStrategy()``).
        trajectory: the quintic reference (default: a new one).
        sample_period: s between re-plans.
        lookahead: s ahead of the present the tracking targets are sampled.
        strike: ``False`` tracks only.

    The estimate passed to :meth:`reference` has ``settled``, ``mean``
    (``(x, y, z, vx, vy, vz)``), ``rotation`` (body to world), ``fit`` (the
    heave fit, ``None`` before one) and ``kinematics(horizon)``
    (:class:`~baselines.lars.estimation.auv_state.MarkerAUVEstimator`).

    Attributes:
        ik_failures: references out of reach this episode.
    """

    def __init__(self, arm, joint_limits, geometry, camera_in_end, tip_in_end,
                 auv_radius: float, dt: float, strategy: CaptureStrategy | None = None,
                 trajectory: SampledTrajectory | None = None, sample_period: float = 0.2,
                 lookahead: float = 0.4, strike: bool = True):
        if not (sample_period >= dt and lookahead >= sample_period):
            raise ValueError("need control_period <= sample_period <= lookahead, got "
                             f"{dt}, {sample_period}, {lookahead}")
        self.arm = arm
        self.joint_limits = np.asarray(joint_limits)
        self.geometry = geometry
        self.camera_in_end = np.asarray(camera_in_end, dtype=float)
        self.tip_in_end = np.asarray(tip_in_end, dtype=float)
        self.auv_radius = auv_radius
        self.strategy = CaptureStrategy() if strategy is None else strategy
        self.trajectory = SampledTrajectory() if trajectory is None else trajectory
        self.dt = dt
        self.strike_enabled = bool(strike)
        self._replan_every = max(1, round(sample_period / self.dt))
        self._lookahead = float(lookahead)
        self.reset()

    def reset(self) -> None:
        self.strategy.reset()
        self.trajectory.reset()
        self._ticks = 0
        self._hold: np.ndarray | None = None
        self._last_ref: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.ik_failures = 0

    @property
    def phase(self) -> str:
        return self.strategy.phase

    def reference(self, t: float, q, qd, estimate):
        """Joint angle, rate and acceleration references (3 each) at time ``t`` (s).

        Call once per control period, with the arm's joint angles ``q`` and
        rates ``qd`` and the AUV's ``estimate`` of the same time.
        """
        self._ticks += 1
        if not estimate.settled:
            # no (or a fresh) estimate: hold the arm where it is until the filter settles
            if self._hold is None:
                self._hold = q.copy()
            self.trajectory.reset()
            return self._hold, np.zeros(3), np.zeros(3)
        self._hold = None
        state = estimate.mean
        ready = estimate.fit is not None and self.strike_enabled
        before = self.strategy.phase
        phase = self.strategy.update(t, float(state[5]), ready)
        sample = self._ticks % self._replan_every == 0
        if self.trajectory.segment is None or phase != before or sample:
            self._replan(t, phase, q, qd, estimate)
        p, v, a = self.trajectory.reference(t)
        try:
            self._last_ref = joint_reference(self.arm, p, v, a)
        except ValueError:
            self.ik_failures += 1
            if self._last_ref is None:  # nothing reached yet: hold the present angles
                self._last_ref = (q.copy(), np.zeros(3), np.zeros(3))
        q_ref, qd_ref, qdd_ref = self._last_ref
        limits = self.joint_limits
        q_ref = np.clip(q_ref, limits[:, 0], limits[:, 1])
        return q_ref, qd_ref, qdd_ref

    def _replan(self, t: float, phase: str, q, qd, estimate) -> None:
        arm = self.arm
        start = (arm.forward_kinematics(q), arm.jacobian(q) @ qd, np.zeros(3))
        if phase == STRIKE:
            t_target = max(self.strategy.strike_end, t + self.dt)
        else:
            t_target = t + self._lookahead
        goal = self.goal(phase, t_target - t, estimate)
        self.trajectory.replan(t, start, t_target, goal)

    def goal(self, phase: str, horizon: float, estimate):
        """The arm end's target ``(p, v, a)`` ``horizon`` s from now in ``phase``."""
        pos, vel, acc = estimate.kinematics(horizon)
        rot = estimate.rotation
        if phase in (STRIKE, FOLLOW):
            # the capture tip on the capture point (the tip hangs straight below the end)
            return self.geometry.capture_point(pos, rot) - self.tip_in_end, vel, acc
        top = pos[2] + self.auv_radius
        marker = self.geometry.marker_centre(pos, rot)
        end = np.array([marker[0], marker[1], top + self.strategy.hover_height])
        for _ in range(3):  # the cameras sit off the end, turned with the slew angle
            try:
                slew = self.arm.inverse_kinematics(end)[0]
            except ValueError:
                break
            c, s = math.cos(slew), math.sin(slew)
            ox, oy = self.camera_in_end[:2]
            end[:2] = marker[:2] - (c * ox - s * oy, s * ox + c * oy)
        return end, vel, acc
