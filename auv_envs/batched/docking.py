"""The docking plant on MuJoCo MJX: a batch of vehicles stepped in one compiled call.

The model is the docking environment's own (its MJCF, masses and camera
included) with contacts switched off (MJX has no ellipsoid-box collision; the
CPU environment handles the seabed and the station as failure checks and
rarely touches them before an episode ends). The hull wrench is
:meth:`auv_envs.core.hydrodynamics.HullForceModel.wrench`, the very code the
CPU plant runs: written in scalar arithmetic, it evaluates a JAX batch
elementwise. MJX computes the rigid body's acceleration under that wrench
(``mjx.forward``), and the step integrates it with MuJoCo's classical RK4
(its Butcher tableau, the free joint's position update of
:func:`auv_envs.core.frames.quat_integrate`), the wrench re-evaluated at
every stage as the CPU plant does (:class:`auv_envs.core.plant.StagedIntegrator`).
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from auv_envs.core import frames
from auv_envs.core.hydrodynamics import HullForceModel
from auv_envs.core.plant import RK4_STAGES, RK4_WEIGHTS


class DockingPlantMJX:
    """The plant of a docking environment, batched on MJX.

    Args:
        env: an unwrapped docking environment (``DockingStation`` or
            ``LampArrayDocking``); its model, its simulated vehicle and its
            ``physics_substeps`` are used. Its ``integrator`` must be ``"rk4"``.

    The state is ``(qpos (B, 7), qvel (B, 6))``: the hull's free joint (world
    position, unit quaternion; world linear velocity, body angular velocity),
    as in ``env.physics.data``. :meth:`step` advances it one control period
    under body-frame generalized forces ``tau (B, 6)`` and world currents
    ``current (B, 3)``, held over the period.
    """

    def __init__(self, env):
        model = copy.deepcopy(env.physics.model)
        if model.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4:
            raise ValueError("the MJX plant integrates with RK4: build the env with "
                             "integrator='rk4' (the -v1 ids)")
        if (model.nq, model.nv) != (7, 6):
            raise ValueError(f"expected one free joint (nq 7, nv 6), got nq {model.nq}, "
                             f"nv {model.nv}")
        model.geom_contype[:] = 0
        model.geom_conaffinity[:] = 0
        self.model = mjx.put_model(model)
        #: An MJX data of the model at rest (the template each evaluation fills).
        self.rest_data = mjx.make_data(model)
        hull = env.hull
        self.hull = HullForceModel(hull.params, hull.body_id, hull.qvel_adr)
        self.timestep = float(model.opt.timestep)
        self.substeps = round(env.dt / self.timestep)
        self.step = jax.jit(jax.vmap(self.advance))

    def _acceleration(self, qpos, qvel, tau, current, hull, model):
        """``qacc (6,)`` of one vehicle under the hull wrench at ``(qpos, qvel)``."""
        rot = frames.rotation_rows_from_quat(qpos[3], qpos[4], qpos[5], qpos[6])
        f0, f1, f2, m0, m1, m2 = hull.wrench(
            rot, tuple(qvel[k] for k in range(6)), tuple(tau[k] for k in range(6)),
            tuple(current[k] for k in range(3)))
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot
        # The free joint's generalized force: world force at the CG, body torque.
        qfrc = jnp.stack([r00 * f0 + r01 * f1 + r02 * f2, r10 * f0 + r11 * f1 + r12 * f2,
                          r20 * f0 + r21 * f1 + r22 * f2, m0, m1, m2])
        data = self.rest_data.replace(qpos=qpos, qvel=qvel, qfrc_applied=qfrc)
        return mjx.forward(model, data).qacc

    def _integrate(self, qpos, velocity, h):
        """``qpos`` moved by the free-joint velocity ``velocity`` for ``h`` s."""
        return jnp.concatenate([qpos[:3] + h * velocity[:3],
                                frames.quat_integrate(qpos[3:], velocity[3:], h, ops=jnp)])

    def _rk4(self, qpos, qvel, tau, current, hull, model):
        """One MuJoCo RK4 step of ``timestep`` s."""
        h = self.timestep
        velocities = [qvel]
        accelerations = [self._acceleration(qpos, qvel, tau, current, hull, model)]
        for a in RK4_STAGES:
            stage_qvel = qvel + h * a * accelerations[-1]
            stage_qpos = self._integrate(qpos, a * velocities[-1], h)
            velocities.append(stage_qvel)
            accelerations.append(
                self._acceleration(stage_qpos, stage_qvel, tau, current, hull, model))
        velocity = sum(b * v for b, v in zip(RK4_WEIGHTS, velocities, strict=True))
        acceleration = sum(b * a for b, a in zip(RK4_WEIGHTS, accelerations, strict=True))
        return self._integrate(qpos, velocity, h), qvel + h * acceleration

    def advance(self, qpos, qvel, tau, current, vehicle=None):
        """One vehicle one control period on (``physics_substeps`` RK4 steps); :meth:`step`
        is this batched and compiled.

        ``vehicle``: the simulated vehicle's parameters when they differ from the
        env's (:meth:`auv_envs.core.vehicle.PlantPerturbation.apply` on JAX
        scalars): its mass and inertia go into the MJX model, its hydrodynamics
        into the hull wrench, as the CPU env does for a perturbed episode.
        """
        hull, model = self.hull, self.model
        if vehicle is not None:
            hull = HullForceModel(vehicle, hull.body_id, hull.qvel_adr)
            body = hull.body_id
            model = model.replace(
                body_mass=model.body_mass.at[body].set(vehicle.mass),
                body_inertia=model.body_inertia.at[body].set(jnp.stack(vehicle.inertia)))
        for _ in range(self.substeps):
            qpos, qvel = self._rk4(qpos, qvel, tau, current, hull, model)
        return qpos, qvel
