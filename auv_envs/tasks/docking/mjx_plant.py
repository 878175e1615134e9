"""The docking plant on JAX: a batch of vehicles stepped in one compiled call.

The hull is :func:`auv_envs.core.plant.free_body_rk4` under
:func:`auv_envs.core.hydrodynamics.free_body_acceleration`, the very scalar
code the CPU environment compiles with CasADi (:class:`auv_envs.core.plant.FreeBodyPlant`),
here evaluated on JAX arrays: MuJoCo's classical RK4 (its Butcher tableau, the
free joint's position update) with the hull wrench re-evaluated at every stage.
The model kept beside it is the docking environment's own (its MJCF, masses
and camera included) on MuJoCo MJX with contacts switched off (MJX has no
ellipsoid-box collision; the CPU environment handles the seabed and the
station as failure checks and rarely touches them before an episode ends):
Playground's ``mj_model``/``mjx_model`` (:class:`auv_envs.batched.functional.FunctionalEnv`).
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from auv_envs.core.hydrodynamics import HullForceModel
from auv_envs.core.ops import jax_ops
from auv_envs.core.plant import hull_advance
from auv_envs.tasks.docking.station import DockingPhysics


class DockingPlantMJX:
    """The plant of a docking environment, batched on JAX (its model on MJX beside it).

    Args:
        setup: the docking task's parameters
            (:func:`auv_envs.tasks.docking.config.params`); its model, its simulated
            vehicle and its ``physics_substeps`` are used. Its ``integrator`` must be
            ``"rk4"``.

    The state is ``(qpos (B, 7), qvel (B, 6))``: the hull's free joint (world
    position, unit quaternion; world linear velocity, body angular velocity),
    as in ``env.physics.data``. :meth:`step` advances it one control period
    under body-frame generalized forces ``tau (B, 6)`` and world currents
    ``current (B, 3)``, held over the period.
    """

    def __init__(self, setup):
        model = copy.deepcopy(setup.model)
        if model.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4:
            raise ValueError("the MJX plant integrates with RK4: build the env with "
                             "integrator='rk4' (the -v1 and -v2 ids)")
        if (model.nq, model.nv) != (7, 6):
            raise ValueError(f"expected one free joint (nq 7, nv 6), got nq {model.nq}, "
                             f"nv {model.nv}")
        model.geom_contype[:] = 0
        model.geom_conaffinity[:] = 0
        self.model = mjx.put_model(model)
        #: An MJX data of the model at rest (the template each evaluation fills).
        self.rest_data = mjx.make_data(model)
        physics = DockingPhysics(setup.model, len(setup.layout.light_labels))  # its names
        self.hull = HullForceModel(setup.vehicle, physics.hull_body, physics.qvel_adr)
        self.timestep = float(model.opt.timestep)
        self.substeps = round(setup.dt / self.timestep)
        self._ops = jax_ops()
        self.step = jax.jit(jax.vmap(self.advance))

    def advance(self, qpos, qvel, tau, current, vehicle=None):
        """One vehicle one control period on (``physics_substeps`` RK4 steps); :meth:`step`
        is this batched and compiled.

        ``vehicle``: the simulated vehicle's parameters when they differ from the
        env's (:meth:`auv_envs.core.vehicle.PlantPerturbation.apply` on JAX
        scalars): its mass, inertia and hydrodynamics, as the CPU env's for a
        perturbed episode.
        """
        hull = self.hull if vehicle is None else HullForceModel(vehicle, 0, 0)
        q, v = hull_advance(hull, tuple(qpos[k] for k in range(7)),
                            tuple(qvel[k] for k in range(6)), tuple(tau[k] for k in range(6)),
                            tuple(current[k] for k in range(3)), self.timestep, self.substeps,
                            self._ops)
        return jnp.stack(q), jnp.stack(v)
