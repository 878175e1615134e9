"""The 3-DOF launch-and-recovery arm (LARS) of the capture task ([LTAT], §2.4).

Kinematics: a slew joint ``q1`` about the vertical axis, then two luffing
joints, shoulder ``q2`` (boom elevation above the horizontal) and elbow ``q3``
(jib angle relative to the boom, negative folds the jib down). At ``q = 0``
the arm points outboard along world +y. The capture head at the jib tip is
held level by a gimbal, so the arm-end frame is the tip position with the
orientation ``Rz(q1)`` (x along the ship at ``q1 = 0``, y outboard, z up).

Dynamics ([LTAT], eq. 29): ``tau = M(q) qdd + C(q, qd) + G(q)``. The terms
come from the same MuJoCo model that drives the plant, evaluated on a private
``MjData`` so that calling them never disturbs the simulation.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from auv_envs.core.ops import FLOATS

JOINT_NAMES = ("slew", "shoulder", "elbow")


def _read_only(array) -> np.ndarray:
    out = np.array(array, dtype=float)
    out.setflags(write=False)
    return out


class ArmModel:
    """Kinematics and rigid-body dynamics of the LARS arm.

    Attributes:
        shoulder: (3,) world position of the shoulder (on the slew axis), m.
        link_lengths: (boom, jib) lengths, m.
        joint_limits: (3, 2) lower/upper joint angles, rad.
        torque_limits: (3,) actuator torque limits, N m.
    """

    def __init__(self, model: mujoco.MjModel):
        self._model = model
        self._data = mujoco.MjData(model)
        ids = [model.joint(name).id for name in JOINT_NAMES]
        self._qadr = np.array([model.jnt_qposadr[i] for i in ids])
        self._dadr = np.array([model.jnt_dofadr[i] for i in ids])
        if model.nv != 3:
            raise ValueError(f"the LARS model must have exactly the 3 arm dofs, got nv={model.nv}")
        mujoco.mj_resetData(model, self._data)
        mujoco.mj_kinematics(model, self._data)
        boom = model.body("boom").id
        jib = model.body("jib").id
        self.shoulder = _read_only(self._data.xpos[boom])
        self._shoulder = tuple(self.shoulder.tolist())
        tip_local = model.site_pos[model.site("tip").id]
        self.link_lengths = (float(model.body_pos[jib][1]), float(tip_local[1]))
        self.joint_limits = _read_only(model.jnt_range[ids])
        gear = {model.actuator(n).trnid[0]: model.actuator_gear[model.actuator(n).id, 0]
                for n in JOINT_NAMES}
        self.torque_limits = _read_only([gear[i] for i in ids])

    # ----------------------------------------------------------- kinematics
    def end_state(self, q, qd, ops) -> tuple[float, ...]:
        """Arm-end position and velocity as six scalars ``(x, y, z, vx, vy, vz)``.

        Scalar arithmetic (the env calls this every step): Python floats, or
        any backend of :mod:`auv_envs.core.ops`.
        """
        q1, q2, q3 = q
        w1, w2, w3 = qd
        l1, l2 = self.link_lengths
        c1, s1 = ops.cos(q1), ops.sin(q1)
        a2, a23 = l1 * ops.cos(q2), l2 * ops.cos(q2 + q3)
        b2, b23 = l1 * ops.sin(q2), l2 * ops.sin(q2 + q3)
        reach, rise = a2 + a23, b2 + b23
        reach_rate = -b2 * w2 - b23 * (w2 + w3)
        sx, sy, sz = self._shoulder
        return (
            sx - reach * s1, sy + reach * c1, sz + rise,
            -reach_rate * s1 - reach * c1 * w1, reach_rate * c1 - reach * s1 * w1,
            a2 * w2 + a23 * (w2 + w3),
        )

    def forward_kinematics(self, q) -> np.ndarray:
        """World position (3,) of the arm end (jib tip) for joint angles ``q``."""
        return np.array(self.end_state([float(v) for v in q], (0.0, 0.0, 0.0), FLOATS)[:3])

    def end_rotation(self, q, ops) -> np.ndarray:
        """Rotation (3, 3) of the levelled arm-end frame: ``Rz(q1)``; ``ops``: Python floats
        (:data:`~auv_envs.core.ops.FLOATS`), or :func:`~auv_envs.core.ops.jax_ops` for traced
        angles."""
        c, s = ops.cos(q[0]), ops.sin(q[0])
        return ops.xp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def jacobian(self, q) -> np.ndarray:
        """Analytic (3, 3) Jacobian of :meth:`forward_kinematics`."""
        q1, q2, q3 = (float(v) for v in q)
        l1, l2 = self.link_lengths
        s1, c1 = math.sin(q1), math.cos(q1)
        reach = l1 * math.cos(q2) + l2 * math.cos(q2 + q3)
        dr2 = -l1 * math.sin(q2) - l2 * math.sin(q2 + q3)
        dr3 = -l2 * math.sin(q2 + q3)
        dz2 = l1 * math.cos(q2) + l2 * math.cos(q2 + q3)
        dz3 = l2 * math.cos(q2 + q3)
        return np.array(
            [[-reach * c1, -dr2 * s1, -dr3 * s1],
             [-reach * s1, dr2 * c1, dr3 * c1],
             [0.0, dz2, dz3]]
        )

    def inverse_kinematics(self, position) -> np.ndarray:
        """Joint angles (3,) that put the arm end at ``position`` (elbow up).

        Closed form: the slew angle from the horizontal bearing, then the
        planar two-link solution in the arm's vertical plane with the elbow
        above the shoulder-to-end line (``q3 <= 0``).

        Raises:
            ValueError: if the position is non-finite or out of reach.
        """
        p = np.asarray(position, dtype=float)
        if p.shape != (3,) or not all(map(math.isfinite, p.tolist())):
            raise ValueError(f"position must be a finite (3,) vector, got {position!r}")
        return np.array(self.joint_angles(p.tolist(), FLOATS))

    def joint_angles(self, position, ops) -> tuple:
        """:meth:`inverse_kinematics` in scalar arithmetic: the three angles for an end
        ``position`` (three scalars), in any backend of :mod:`auv_envs.core.ops`
        (:data:`~auv_envs.core.ops.FLOATS` for Python floats). Python floats out of reach raise
        ``ValueError``; arrays are not checked (NaN angles)."""
        sx, sy, sz = self._shoulder
        x, y, z = position
        dx, dy, dz = x - sx, y - sy, z - sz
        reach = ops.hypot(dx, dy)
        l1, l2 = self.link_lengths
        cos_elbow = (reach**2 + dz**2 - l1**2 - l2**2) / (2.0 * l1 * l2)
        if isinstance(cos_elbow, float) and not -1.0 <= cos_elbow <= 1.0:
            raise ValueError(
                f"position {[x, y, z]} is out of the arm's reach "
                f"({abs(l1 - l2):.2f} to {l1 + l2:.2f} m from the shoulder)"
            )
        q1 = ops.atan2(-dx, dy)
        q3 = -ops.acos(cos_elbow)
        q2 = ops.atan2(dz, reach) - ops.atan2(l2 * ops.sin(q3), l1 + l2 * ops.cos(q3))
        return q1, q2, q3

    def within_limits(self, q) -> bool:
        q = np.asarray(q, dtype=float)
        return bool(np.all(q >= self.joint_limits[:, 0]) and np.all(q <= self.joint_limits[:, 1]))

    # ----------------------------------------------------------- dynamics (eq. 29)
    def _set(self, q, qd) -> None:
        data = self._data
        data.qpos[self._qadr] = q
        data.qvel[self._dadr] = qd
        mujoco.mj_kinematics(self._model, data)
        mujoco.mj_comPos(self._model, data)

    def mass_matrix(self, q) -> np.ndarray:
        """Joint-space inertia M(q) (3, 3), including the drives' armature."""
        self._set(q, np.zeros(3))
        mujoco.mj_crb(self._model, self._data)
        full = np.zeros((self._model.nv, self._model.nv))
        mujoco.mj_fullM(self._model, self._data, full)
        return full[np.ix_(self._dadr, self._dadr)]

    def _bias(self, q, qd) -> np.ndarray:
        self._set(q, qd)
        mujoco.mj_comVel(self._model, self._data)
        out = np.zeros(self._model.nv)
        mujoco.mj_rne(self._model, self._data, 0, out)
        return out[self._dadr]

    def gravity(self, q) -> np.ndarray:
        """Gravity torque G(q) (3,), N m: the torque that holds the arm still at ``q``."""
        return self._bias(q, np.zeros(3))

    def coriolis(self, q, qd) -> np.ndarray:
        """Coriolis and centrifugal torque C(q, qd) (3,), N m (the vector C(q, qd) qd)."""
        return self._bias(q, qd) - self._bias(q, np.zeros(3))

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """Joint torque (3,) of eq. 29: ``M(q) qdd + C(q, qd) + G(q)``."""
        return self.mass_matrix(q) @ np.asarray(qdd, dtype=float) + self._bias(q, qd)

    def __repr__(self) -> str:
        l1, l2 = self.link_lengths
        return f"ArmModel(boom={l1} m, jib={l2} m, torque_limits={self.torque_limits.tolist()})"
