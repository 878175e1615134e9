"""Fossen-style hydrodynamics: one definition for the plant and the nominal model.

The equations of motion (Fossen 2021, eq. 10.1, body frame, origin at the CG)::

    M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r
        + D(nu_r) nu_r + g(eta) = tau

with ``nu_r = nu - nu_c`` the velocity relative to an irrotational current.
MuJoCo integrates the rigid body (``M_RB``, ``C_RB``) itself. Everything else
is computed here and added as a generalized force, including the added-mass
*acceleration* term ``-M_A nu_r_dot``, which MuJoCo never applies: because
``M_A`` is diagonal and constant, the body acceleration that the full equation
implies can be solved in closed form from the state before the wrench is
applied (:meth:`HullForceModel.wrench`), so the acceleration term is exact
rather than lagged.

Integration: the plant steps with MuJoCo's classical RK4 and the wrench is
re-evaluated at every stage (:meth:`HullForceModel.passive_force`, added by
:class:`auv_envs.core.plant.StagedIntegrator`, which runs MuJoCo's stages
itself; no process-global callback). ``docs/physics.md`` gives the step, the order
of convergence and the measured error against an independent reference.

:func:`hydrodynamic_force` and :func:`rigid_body_coriolis` are written with
scalar arithmetic and an ``ops`` module (``math``, ``numpy`` or ``casadi``)
supplying ``sin``/``cos``, so the very same code evaluates the plant in
floats and builds the controllers' symbolic CasADi model
(:class:`NominalModel`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from auv_envs.core.vehicle import VehicleParams


def hydrodynamic_force(params: VehicleParams, nu_r: Sequence, gravity_body: Sequence) -> tuple:
    """Applied hydrodynamic + restoring wrench, without the added-mass acceleration term.

    Returns ``-C_A(nu_r) nu_r - D(nu_r) nu_r - g(eta)`` in the body frame.

    Args:
        params: vehicle parameters.
        nu_r: relative velocity ``(u, v, w, p, q, r)`` (body frame).
        gravity_body: unit vector of gravity in the body frame,
            ``R^T (0, 0, -1)``.

    Returns:
        A 6-tuple of scalars (whatever type ``nu_r`` holds: floats, NumPy or
        CasADi scalars).
    """
    u, v, w, p, q, r = nu_r
    a1, a2, a3, a4, a5, a6 = params.added_mass
    # C_A(nu) nu = [w x (A11 v); v x (A11 v) + w x (A22 w)]  (Fossen 2021, eq. 6.43),
    # written out for diagonal M_A.
    au, av, aw, ap, aq, ar = a1 * u, a2 * v, a3 * w, a4 * p, a5 * q, a6 * r
    coriolis = (
        q * aw - r * av,
        r * au - p * aw,
        p * av - q * au,
        (v * aw - w * av) + (q * ar - r * aq),
        (w * au - u * aw) + (r * ap - p * ar),
        (u * av - v * au) + (p * aq - q * ap),
    )
    dl0, dl1, dl2, dl3, dl4, dl5 = params.linear_damping
    dq0, dq1, dq2, dq3, dq4, dq5 = params.quadratic_damping
    # Restoring: weight at the CG, buoyancy at the CB, both along gravity.
    weight, buoyancy = params.weight, params.buoyancy
    gx, gy, gz = gravity_body
    bx, by, bz = -buoyancy * gx, -buoyancy * gy, -buoyancy * gz
    xb, yb, zb = params.cb_offset
    w_minus_b = weight - buoyancy
    # restoring - coriolis - damping, written out per DOF (a loop over the six
    # costs more than the arithmetic when this runs four times per env step).
    return (
        w_minus_b * gx - coriolis[0] - (dl0 + dq0 * abs(u)) * u,
        w_minus_b * gy - coriolis[1] - (dl1 + dq1 * abs(v)) * v,
        w_minus_b * gz - coriolis[2] - (dl2 + dq2 * abs(w)) * w,
        (yb * bz - zb * by) - coriolis[3] - (dl3 + dq3 * abs(p)) * p,
        (zb * bx - xb * bz) - coriolis[4] - (dl4 + dq4 * abs(q)) * q,
        (xb * by - yb * bx) - coriolis[5] - (dl5 + dq5 * abs(r)) * r,
    )


def rigid_body_coriolis(params: VehicleParams, nu: Sequence) -> tuple:
    """``C_RB(nu) nu`` with the origin at the CG: ``[m w x v; w x (I w)]``.

    The cross products are written out: this runs at every integrator stage.
    """
    u, v, w, p, q, r = nu
    m = params.mass
    ix, iy, iz = params.inertia
    return (
        m * (q * w - r * v),
        m * (r * u - p * w),
        m * (p * v - q * u),
        (iz - iy) * q * r,
        (ix - iz) * r * p,
        (iy - ix) * p * q,
    )


class HullForceModel:
    """Computes and applies the hydrodynamic wrench on one free MuJoCo body.

    The body must carry a free joint (its own or its parent's, with the body's
    frame at the joint's frame), its inertial frame at the body origin,
    ``gravcomp="1"`` (weight and buoyancy are applied here as restoring
    forces) and mass/inertia equal to ``params``.
    """

    def __init__(self, params: VehicleParams, body_id: int, qvel_adr: int):
        self.params = params
        self.body_id = body_id
        self.qvel_adr = qvel_adr
        total = params.inertia_with_added_mass
        self._rigid = (total[:3], total[3:])
        # Views into the last MjData seen by passive_force() (MjData's array properties
        # build a new view on every access, which costs more than the arithmetic).
        self._views: tuple | None = None
        self._tau: Sequence = (0.0,) * 6
        self._current: Sequence = (0.0,) * 3

    def wrench(
        self, rotation: Sequence, qvel6: Sequence, tau_body: Sequence, current_world: Sequence
    ) -> tuple:
        """Total body-frame wrench (thrust + hydrodynamics incl. acceleration term).

        Pure-Python float arithmetic, written out per axis: at this size it is
        several times faster than NumPy or a loop, and it runs at every stage of
        the integrator (four times per env step).

        With ``f = tau + f_h`` (:func:`hydrodynamic_force`) and ``nu_c_dot =
        -w x nu_c`` (a constant world current seen from the rotating body), the
        translational equation ``(m + A) u_dot = f - m w x v + A nu_c_dot`` gives
        the acceleration, and the applied force is ``f - A (u_dot - nu_c_dot)``;
        rotationally ``(I + A) w_dot = t - w x I w``, applied torque
        ``t - A w_dot`` (Fossen 2021, eq. 10.1 with ``M_A`` diagonal).

        Args:
            rotation: body-to-world rotation, row-major flat (9).
            qvel6: free-joint velocity (world linear, body angular) (6).
            tau_body: commanded generalized force in the body frame (6).
            current_world: uniform current velocity in the world frame (3).
        """
        p = self.params
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation
        vx, vy, vz, wx, wy, wz = qvel6
        cx, cy, cz = current_world
        # World -> body: R^T.
        v0 = r00 * vx + r10 * vy + r20 * vz
        v1 = r01 * vx + r11 * vy + r21 * vz
        v2 = r02 * vx + r12 * vy + r22 * vz
        c0 = r00 * cx + r10 * cy + r20 * cz
        c1 = r01 * cx + r11 * cy + r21 * cz
        c2 = r02 * cx + r12 * cy + r22 * cz
        nu_r = (v0 - c0, v1 - c1, v2 - c2, wx, wy, wz)
        f0, f1, f2, f3, f4, f5 = hydrodynamic_force(p, nu_r, (-r20, -r21, -r22))
        t0, t1, t2, t3, t4, t5 = tau_body
        f0, f1, f2, f3, f4, f5 = t0 + f0, t1 + f1, t2 + f2, t3 + f3, t4 + f4, t5 + f5
        a0, a1, a2, a3, a4, a5 = p.added_mass
        (ml0, ml1, ml2), (ma0, ma1, ma2) = self._rigid
        # C_RB(nu) nu = [m w x v; w x (I w)] on the ground-relative velocity.
        k0, k1, k2, k3, k4, k5 = rigid_body_coriolis(p, (v0, v1, v2, wx, wy, wz))
        # nu_c_dot = -w x vc
        cd0 = -(wy * c2 - wz * c1)
        cd1 = -(wz * c0 - wx * c2)
        cd2 = -(wx * c1 - wy * c0)
        acc0 = (f0 - k0 + a0 * cd0) / ml0
        acc1 = (f1 - k1 + a1 * cd1) / ml1
        acc2 = (f2 - k2 + a2 * cd2) / ml2
        return (
            f0 - a0 * (acc0 - cd0),
            f1 - a1 * (acc1 - cd1),
            f2 - a2 * (acc2 - cd2),
            f3 - a3 * (f3 - k3) / ma0,
            f4 - a4 * (f4 - k4) / ma1,
            f5 - a5 * (f5 - k5) / ma2,
        )

    def command(self, tau_body: Sequence, current_world: Sequence) -> None:
        """Hold a commanded generalized force and a current for the next step(s).

        Args:
            tau_body: commanded generalized force in the body frame (6 floats).
            current_world: uniform current velocity in the world frame (3 floats).
        """
        self._tau = tau_body
        self._current = current_world

    def passive_force(self, model, data) -> None:
        """Add the wrench at the state in ``data`` to ``data.qfrc_passive``.

        The stage force of :class:`auv_envs.core.plant.StagedIntegrator`: called
        after ``mj_fwdVelocity`` at every evaluation of the dynamics, so with
        ``integrator="RK4"`` the hull wrench is re-evaluated at each of the four
        stages. For the
        free joint the generalized force is the world-frame force at the CG
        (translational dofs) and the body-frame torque (rotational dofs).
        """
        del model
        views = self._views
        if views is None or views[0] is not data:
            adr, body = self.qvel_adr, self.body_id
            views = (data, data.xmat[body], data.qvel[adr : adr + 6],
                     data.qfrc_passive[adr : adr + 6])
            self._views = views
        _, xmat, qvel, qfrc = views
        rot = xmat.tolist()
        f0, f1, f2, m0, m1, m2 = self.wrench(rot, qvel.tolist(), self._tau, self._current)
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot
        g0, g1, g2, g3, g4, g5 = qfrc.tolist()
        qfrc[:] = (
            g0 + r00 * f0 + r01 * f1 + r02 * f2,
            g1 + r10 * f0 + r11 * f1 + r12 * f2,
            g2 + r20 * f0 + r21 * f1 + r22 * f2,
            g3 + m0,
            g4 + m1,
            g5 + m2,
        )


def free_body_acceleration(hull: HullForceModel, rotation: Sequence, qvel6: Sequence,
                           tau_body: Sequence, current_world: Sequence) -> tuple:
    """The free joint's acceleration ``qacc`` (world linear, body angular; 6 scalars) of the
    hull under the wrench of :meth:`HullForceModel.wrench`: what MuJoCo's free body
    computes with the body's inertia at its origin (the CG), principal axes along the
    body's and ``gravcomp="1"``: ``m a = R f`` and ``I w_dot = t - w x I w``.

    Scalar arithmetic: floats, JAX arrays elementwise or CasADi symbols (the
    compiled plant, :class:`auv_envs.core.plant.FreeBodyPlant`).
    """
    f0, f1, f2, m0, m1, m2 = hull.wrench(rotation, qvel6, tau_body, current_world)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation
    params = hull.params
    mass = params.mass
    ix, iy, iz = params.inertia
    _, _, _, k3, k4, k5 = rigid_body_coriolis(params, (0.0, 0.0, 0.0, *qvel6[3:]))
    return (
        (r00 * f0 + r01 * f1 + r02 * f2) / mass,
        (r10 * f0 + r11 * f1 + r12 * f2) / mass,
        (r20 * f0 + r21 * f1 + r22 * f2) / mass,
        (m0 - k3) / ix,
        (m1 - k4) / iy,
        (m2 - k5) / iz,
    )


#: Indices of the controlled degrees of freedom (surge, sway, heave, yaw) in a 6-vector.
DOF4 = (0, 1, 2, 5)


class NominalModel:
    """The 4-DOF (surge, sway, heave, yaw) prediction model of [OFNMPC].

    State ``x = (x, y, z, psi, u, v, w, r)`` (world position, yaw, body
    velocities), input ``tau = (X, Y, Z, N)``, optional additive generalized
    disturbance ``d`` (4) as in [OFNMPC]'s offset-free formulation (eq. 12).
    Roll and pitch are taken as zero ([OFNMPC]: stabilised by conventional
    controllers). The dynamics reuse :func:`hydrodynamic_force` and
    :func:`rigid_body_coriolis`, so the model is the plant's model restricted
    to 4 DOF, with whatever mismatch ``params`` carries.

    Works on floats, NumPy arrays and CasADi ``SX``/``MX`` symbols: pass the
    matching ``ops`` module (``math``, ``numpy`` or ``casadi``) for ``sin``/``cos``
    (:meth:`step` takes ``numpy`` or ``casadi``).
    """

    state_names = ("x", "y", "z", "psi", "u", "v", "w", "r")
    input_names = ("X", "Y", "Z", "N")

    def __init__(self, params: VehicleParams):
        self.params = params
        total = params.inertia_with_added_mass
        self.inertia_diag = tuple(total[i] for i in DOF4)

    def derivatives(self, x, tau, d=None, *, ops) -> list:
        """Continuous-time ``x_dot`` as a list of 8 scalars."""
        psi, u, v, w, r = x[3], x[4], x[5], x[6], x[7]
        zero = 0.0 * u
        nu = (u, v, w, zero, zero, r)
        f_h = hydrodynamic_force(self.params, nu, (zero, zero, zero - 1.0))
        c_rb = rigid_body_coriolis(self.params, nu)
        acc = []
        for k, i in enumerate(DOF4):
            force = tau[k] + f_h[i] - c_rb[i]
            if d is not None:
                force = force + d[k]
            acc.append(force / self.inertia_diag[k])
        c, s = ops.cos(psi), ops.sin(psi)
        return [u * c - v * s, u * s + v * c, w, r, *acc]

    def step(self, x, tau, dt: float, d=None, *, ops):
        """One RK4 step of length ``dt``; returns the same container kind as NumPy/CasADi."""
        stack = _stacker(ops)

        def f(state):
            return stack(self.derivatives(state, tau, d, ops=ops))

        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def _stacker(ops):
    if ops is np:
        return lambda items: np.array(items, dtype=float)
    return lambda items: ops.vertcat(*items)
