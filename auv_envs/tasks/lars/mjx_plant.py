"""The LARS arm on MuJoCo MJX: a batch of arms stepped in one compiled call.

The task's arm model (:func:`auv_envs.tasks.lars.config.params`, what the CPU
environment simulates) on MJX, with contacts off (the CPU model has them disabled too), stepped
``FRAME_SKIP`` physics steps a control period; the joint limits' forces are the exact
minimiser of MuJoCo's constraint problem (:meth:`ArmPlantMJX.constrain`), where MuJoCo
iterates to a tolerance. The batched environment
(:class:`auv_envs.tasks.lars.jax_task.LARSJax`) runs the LARS transition on it.
"""

from __future__ import annotations

import copy
import itertools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from auv_envs.tasks.lars.config import FRAME_SKIP, LARSSetup


def _spd_solve(matrix, rhs):
    """``matrix^-1 rhs`` for a small symmetric positive definite ``matrix`` (n, n), by a
    Cholesky factorisation written out entry by entry (under ``vmap`` on the CPU, JAX's
    ``cho_factor`` is a LAPACK call per lane)."""
    n = rhs.shape[0]
    lower = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            rest = matrix[i, j] - sum(lower[i][k] * lower[j][k] for k in range(j))
            lower[i][j] = jnp.sqrt(rest) if i == j else rest / lower[j][j]
    y = []
    for i in range(n):
        y.append((rhs[i] - sum(lower[i][k] * y[k] for k in range(i))) / lower[i][i])
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(lower[k][i] * x[k] for k in range(i + 1, n))) / lower[i][i]
    return jnp.stack(x)


class ArmPlantMJX:
    """The LARS arm on MJX: the CPU environment's model with contacts off (the CPU
    model has them disabled too) and MJX's sparse mass-matrix factorisation (MJX's own
    arithmetic: the dense one is a LAPACK call per arm on the CPU), stepped
    ``FRAME_SKIP`` physics steps a control period, the joint limits' forces solved
    exactly (:meth:`constrain`) instead of by MJX's iterative solver.

    ``control="torque"``: the action is the actuators' control. ``"position"``:
    [LTAT]'s computed-torque loop (eqs. 29-30) at the physics rate, as
    :class:`auv_envs.tasks.lars.env._MujocoArm` runs it on the CPU: the mass matrix
    and bias forces of each physics step's positions and velocities give its control.
    """

    def __init__(self, setup: LARSSetup):
        model = copy.deepcopy(setup.model)
        model.geom_contype[:] = 0
        model.geom_conaffinity[:] = 0
        if model.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER:
            raise ValueError("the batched arm steps MuJoCo's Euler integrator; the model "
                             f"has integrator {model.opt.integrator}")
        if model.nsensor:
            raise ValueError("the batched arm steps without MJX's sensor stages; the model "
                             f"has {model.nsensor} sensors")
        limited = np.isin(model.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE,
                                           mujoco.mjtJoint.mjJNT_SLIDE)) & model.jnt_limited
        if (model.neq or model.ntendon or np.any(model.dof_frictionloss)
                or not np.all(limited) or np.any(model.dof_damping)):
            raise ValueError("the batched arm's constraint solve takes hinge and slide joint "
                             "limits only (no equality, tendon, friction loss) and no joint "
                             "damping")
        model.opt.jacobian = mujoco.mjtJacobian.mjJAC_SPARSE
        # Without joint damping, MuJoCo's Euler step has nothing to integrate implicitly:
        # MJX's would factorise the mass matrix again to find the same accelerations.
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
        self._active_sets = tuple(itertools.product((0.0, 1.0), repeat=model.njnt))
        self.model = mjx.put_model(model)
        #: An MJX data of the model at rest (the template a reset fills).
        self.rest_data = mjx.make_data(model)
        if self.rest_data._impl.efc_J.shape[0] != model.njnt:
            raise ValueError("expected one MJX constraint row per joint limit")
        self.torque_mode = setup.config.control == "torque"
        self.dt = float(setup.dt)
        self.q_mid = jnp.asarray(setup.params.joint_mid, jnp.float32)
        self.q_half = jnp.asarray(setup.params.joint_half, jnp.float32)
        self.limits = jnp.asarray(setup.calibration.torque_limits, jnp.float32)
        self.kp, self.kd = setup.calibration.position_gains
        self.timestep = float(model.opt.timestep)

    def place(self, q) -> mjx.Data:
        """The arm at rest at joint angles ``q`` (three scalars)."""
        return self.rest_data.replace(qpos=jnp.stack([jnp.asarray(v, jnp.float32) for v in q]))

    def constrain(self, data: mjx.Data, model: mjx.Model) -> mjx.Data:
        """``mjx.solve`` for this arm (simulating ``model``): the accelerations, joint-limit
        forces and constraint force MuJoCo's solver converges to, computed exactly.

        MuJoCo's constraint problem here is convex and piecewise quadratic (the Gauss
        term ``(a - a0)^T M (a - a0) / 2`` and ``D jar^2 / 2`` for each limit row with
        ``jar = J a - aref < 0``). Its minimiser solves the quadratic of its own active
        set, so it is the cheapest of the solutions of all ``2^rows`` active sets (each
        a small linear system), which is what is computed: no iteration, no LAPACK call
        under ``vmap``. The rows (``efc_J``, ``efc_D``, ``efc_aref``) are MJX's, from
        ``mjx.make_constraint`` (a row away from its limit is zero).
        """
        impl = data._impl  # MJX keeps the constraint rows in its implementation's fields
        jac, stiffness, aref = impl.efc_J, impl.efc_D, impl.efc_aref
        mass = mjx.full_m(model, data)
        smooth = data.qacc_smooth
        pushed = mass @ smooth
        best = None
        for active in self._active_sets:
            weight = stiffness * jnp.asarray(active, stiffness.dtype)
            qacc = _spd_solve(mass + (jac.T * weight) @ jac, pushed + jac.T @ (weight * aref))
            jar = jac @ qacc - aref
            force = -stiffness * jar * (jar < 0.0)
            change = qacc - smooth
            cost = 0.5 * change @ (mass @ change) - 0.5 * jnp.sum(force * jar)
            if best is None:
                best = (cost, qacc, force)
            else:
                take = cost < best[0]
                best = tuple(jnp.where(take, new, old) for new, old in
                             zip((cost, qacc, force), best, strict=True))
        _, qacc, force = best
        return data.replace(qacc=qacc, qfrc_constraint=jac.T @ force).tree_replace(
            {"_impl.efc_force": force})

    def _physics_step(self, data: mjx.Data, model: mjx.Model, control=None) -> mjx.Data:
        """``mjx.step`` of ``model`` (which has no sensors) with :meth:`constrain` for MJX's
        iterative solver; ``control`` (a function of the position and velocity stages'
        data) sets ``ctrl`` after them."""
        data = mjx.fwd_velocity(model, mjx.fwd_position(model, data))
        if control is not None:
            data = data.replace(ctrl=control(data))
        data = mjx.fwd_acceleration(model, mjx.fwd_actuation(model, data))
        return mjx.euler(model, self.constrain(data, model))

    def advance(self, data: mjx.Data, action, effort, model: mjx.Model):
        """One control period under ``action`` (3,) of the arm simulated by ``model`` (the
        env's world's: :class:`~auv_envs.batched.functional.World`): ``(data, effort)``, the
        running control effort with the period's added. The computed-torque loop of
        ``control="position"`` reads the simulated arm's mass matrix and bias forces, as on
        the CPU; its commands reach the joints through the world's motors."""
        # The FRAME_SKIP physics steps as a loop, not unrolled: XLA compiles the step
        # once instead of FRAME_SKIP times (docs/speed.md).
        if self.torque_mode:
            data = jax.lax.fori_loop(0, FRAME_SKIP,
                                     lambda _, now: self._physics_step(now, model),
                                     data.replace(ctrl=action))
            return data, effort + jnp.sum(action * action) * self.dt
        target = self.q_mid + action * self.q_half

        def control(now):  # computed torque from this step's mass matrix and bias
            accel = self.kp * (target - now.qpos) - self.kd * now.qvel
            tau = mjx.mul_m(model, now, accel) + now.qfrc_bias
            return jnp.clip(tau / self.limits, -1.0, 1.0)

        def physics_step(_, carry):
            now, effort = carry
            now = self._physics_step(now, model, control)
            return now, effort + jnp.sum(now.ctrl * now.ctrl) * self.timestep

        return jax.lax.fori_loop(0, FRAME_SKIP, physics_step, (data, effort))
