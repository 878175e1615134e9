"""The acoustic tracking rig on MJX: :class:`~auv_envs.tasks.acoustic.env.AcousticPhysics`
as pure JAX functions (``jit``, ``vmap``).

The model is the CPU plant's own (its MJCF, its timestep, its Euler integrator,
its substeps). MJX has no ellipsoid fluid model, so MJX's water is switched off
(``opt.density``, ``opt.viscosity`` and ``opt.wind`` zeroed in its copy) and
:class:`~auv_envs.tasks.acoustic.fluid.EllipsoidFluid` computes the rig's fluid
forces instead, in each physics step's current and from that step's positions
and velocities, as ``mj_fwdVelocity`` does. MJX's Euler step is MuJoCo's: the
joints' damping integrated implicitly (``M + h diag(dof_damping)``), the
servos' gains explicitly. (MuJoCo's Euler also integrates an actuator's own
``damping`` and polynomial damping implicitly; MJX does not, and the rig has
neither, which the plant checks.)

What differs from the CPU plant: in float32 (JAX's default) the source drifts
from the float64 one by millimetres over tens of seconds; MJX's constraint solver
is not MuJoCo's, which matters only with an arm joint at its limit (the plans
keep the arm well inside them).
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, constraint, smooth
from mujoco.mjx._src import math as mjx_math

from auv_envs.tasks.acoustic.fluid import EllipsoidFluid
from auv_envs.tasks.acoustic.plant import AcousticPhysics


class ChainKinematics:
    """MuJoCo's kinematics (``mj_kinematics``) of a tree of hinge and slide joints,
    written out body by body for MJX data.

    MJX's ``smooth.kinematics`` takes 0.82 s for the rig (nine bodies in one chain) at
    64 environments on the CPU: XLA fuses the chain's arithmetic into one expression per
    output and evaluates it as a tree. Here the same arithmetic (MJX's own quaternion
    functions) is materialised body by body.
    """

    def __init__(self, model: mujoco.MjModel):
        hinge, slide = mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE
        if not np.all(np.isin(model.jnt_type, (hinge, slide))):
            raise ValueError("ChainKinematics takes hinge and slide joints only")
        if model.nmocap:
            raise ValueError("ChainKinematics takes no mocap bodies")
        self.model = model
        self.joints = [np.nonzero(model.jnt_bodyid == b)[0].tolist() for b in range(model.nbody)]

    def __call__(self, data: mjx.Data) -> mjx.Data:
        m = self.model
        qpos = data.qpos
        positions = [jnp.zeros(3, qpos.dtype)]
        quats = [jnp.array([1.0, 0.0, 0.0, 0.0], qpos.dtype)]
        anchors, axes = [None] * m.njnt, [None] * m.njnt
        for body in range(1, m.nbody):
            parent = m.body_parentid[body]
            pos = positions[parent] + mjx_math.rotate(jnp.asarray(m.body_pos[body]),
                                                      quats[parent])
            quat = mjx_math.quat_mul(quats[parent], jnp.asarray(m.body_quat[body]))
            for j in self.joints[body]:
                adr = m.jnt_qposadr[j]
                local_anchor, local_axis = jnp.asarray(m.jnt_pos[j]), jnp.asarray(m.jnt_axis[j])
                anchor = mjx_math.rotate(local_anchor, quat) + pos
                axis = mjx_math.rotate(local_axis, quat)
                anchors[j], axes[j] = anchor, axis
                offset = qpos[adr] - m.qpos0[adr]
                if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
                    quat = mjx_math.quat_mul(quat, mjx_math.axis_angle_to_quat(local_axis,
                                                                               offset))
                    pos = anchor - mjx_math.rotate(local_anchor, quat)
                else:
                    pos = pos + axis * offset
            # Materialised per body: fused down the chain, XLA evaluates each output
            # as a tree of the whole chain's arithmetic (docs/speed.md).
            pos, quat = jax.lax.optimization_barrier((pos, quat))
            positions.append(pos)
            quats.append(quat)
        xpos, xquat = jnp.stack(positions), jnp.stack(quats)
        xmat = jax.vmap(mjx_math.quat_to_mat)(xquat)
        to_global = jax.vmap(smooth.support.local_to_global)
        xipos, ximat = to_global(xpos, xquat, m.body_ipos, m.body_iquat)
        geom_xpos, geom_xmat = to_global(xpos[m.geom_bodyid], xquat[m.geom_bodyid],
                                         m.geom_pos, m.geom_quat)
        site_xpos, site_xmat = to_global(xpos[m.site_bodyid], xquat[m.site_bodyid],
                                         m.site_pos, m.site_quat)
        return data.replace(xanchor=jnp.stack(anchors), xaxis=jnp.stack(axes), xpos=xpos,
                            xquat=xquat, xmat=xmat, xipos=xipos, ximat=ximat,
                            geom_xpos=geom_xpos, geom_xmat=geom_xmat, site_xpos=site_xpos,
                            site_xmat=site_xmat)


class RigPlantMJX:
    """The carrier and arm of the acoustic task on MJX, one sample period a call.

    Args:
        physics: the CPU plant (``env.physics`` of an ``AcousticTracking`` env); its
            model, ids and ``substeps`` are copied. Its integrator must be Euler (the
            ``-v1`` id).

    The state is an ``mjx.Data`` whose position stage is current (kinematics, mass
    matrix, constraint rows: ``mj_fwdPosition``'s). :meth:`place` makes one,
    :meth:`period` advances it. Build the plant in the precision it runs in (inside
    ``jax.enable_x64(True)`` for float64): its model and rest data take JAX's
    default float type when built.
    """

    def __init__(self, physics: AcousticPhysics):
        model = copy.deepcopy(physics.model)
        if model.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER:
            raise ValueError("the MJX rig integrates with Euler: build the env with "
                             "integrator='euler' (the -v1 id)")
        if np.any(model.actuator_damping) or np.any(model.dof_dampingpoly):
            raise NotImplementedError("MJX's Euler step integrates joint damping only")
        #: The ellipsoid fluid model of the CPU model's water.
        self.fluid = EllipsoidFluid.from_model(model)
        model.opt.density = 0.0  # the water is self.fluid's, not MJX's inertia-box model
        model.opt.viscosity = 0.0
        model.opt.wind[:] = 0.0
        self.model = mjx.put_model(model)
        self.kinematics = ChainKinematics(model)
        #: An MJX data of the model at rest (the template :meth:`place` fills).
        self.rest_data = mjx.make_data(model)
        #: Physics steps per sample period.
        self.substeps = int(physics.substeps)
        self.source_site = int(physics.source_site)
        self.source_body = int(model.site_bodyid[physics.source_site])
        self.carrier_qpos = np.asarray(physics.carrier_qpos)
        self.arm_qpos = np.asarray(physics.arm_qpos)
        actuators = np.concatenate([physics.carrier_pos_act, physics.carrier_vel_act,
                                    physics.arm_act])
        if sorted(actuators) != list(range(model.nu)):
            raise ValueError("the references must drive every actuator once")
        self._actuators = actuators

    def place(self, carrier, arm, model: mjx.Model) -> mjx.Data:
        """The rig of ``model`` (:attr:`model`, or a randomised world's) at rest with the
        carrier's and the arm's joints at ``carrier`` (4,) and ``arm`` (6,), its position
        stage computed (``AcousticPhysics.place``: at rest the velocity stage is the next
        step's first). Every method below simulates the ``model`` it is given."""
        data = self.rest_data
        qpos = data.qpos.at[self.carrier_qpos].set(carrier).at[self.arm_qpos].set(arm)
        return self.fwd_position(data.replace(qpos=qpos), model)

    def fwd_position(self, data: mjx.Data, model: mjx.Model) -> mjx.Data:
        """``mjx.fwd_position``'s stages, the kinematics :class:`ChainKinematics`'."""
        data = self.kinematics(data)
        for stage in (smooth.com_pos, smooth.camlight, smooth.tendon, smooth.crb,
                      smooth.tendon_armature, smooth.factor_m, collision_driver.collision,
                      constraint.make_constraint, smooth.transmission):
            data = stage(model, data)
        return data

    def step(self, data: mjx.Data, current, model: mjx.Model) -> mjx.Data:
        """One physics step in water moving at ``current`` (3,), the controls held.

        ``mj_step``'s stages on MJX, the fluid force added where ``mj_fwdVelocity``
        adds it (to ``qfrc_passive``, and kept in ``qfrc_fluid``), from the positions
        and velocities at the step's start; the step ends with the new positions'
        stage (``mj_fwdPosition``), which the next step and :meth:`source` read.
        """
        data = mjx.fwd_velocity(model, data)
        fluid = self.fluid.force(model, data, current)
        data = data.replace(qfrc_passive=data.qfrc_passive + fluid, qfrc_fluid=fluid)
        data = mjx.fwd_actuation(model, data)
        data = mjx.fwd_acceleration(model, data)
        # MJX keeps a constraint row for each limited joint, near its limit or not, so
        # mjx.forward would call the solver here too.
        data = mjx.solve(model, data)
        data = mjx.euler(model, data)
        return self.fwd_position(data, model)

    def source(self, data: mjx.Data, model: mjx.Model) -> tuple[jax.Array, jax.Array]:
        """The source site's world position and linear velocity (3,) each (its Jacobian
        times ``qvel``, ``mj_jacSite``'s)."""
        position = data.site_xpos[self.source_site]
        jacp, _ = mjx.jac(model, data, position, self.source_body)
        return position, data.qvel @ jacp

    def period(self, data: mjx.Data, carrier_ref, carrier_vel, arm_ref, current,
               model: mjx.Model):
        """One sample period: ``(data, position, velocity)``, the rig moved on
        ``substeps`` physics steps towards the references ``carrier_ref`` (4,),
        ``carrier_vel`` (4,) and ``arm_ref`` (6,) (the servos' controls) in water moving
        at ``current`` (3,), and the source's position and velocity (3,) after it (one
        row of ``AcousticPhysics.follow``)."""
        references = jnp.concatenate([jnp.asarray(carrier_ref), jnp.asarray(carrier_vel),
                                      jnp.asarray(arm_ref)])
        data = data.replace(ctrl=data.ctrl.at[self._actuators].set(references))
        for _ in range(self.substeps):
            data = self.step(data, current, model)
        position, velocity = self.source(data, model)
        return data, position, velocity

    def periods(self, data: mjx.Data, carrier_ref, carrier_vel, arm_ref, current,
                model: mjx.Model):
        """:meth:`period` over the rows of the references ((count, 4), (count, 4),
        (count, 6)) and currents ((count, 3)): ``(data, positions (count, 3),
        velocities (count, 3))`` after each period (a ``lax.scan``)."""

        def one(data, row):
            data, position, velocity = self.period(data, *row, model)
            return data, (position, velocity)

        data, (positions, velocities) = jax.lax.scan(
            one, data, (carrier_ref, carrier_vel, arm_ref, current))
        return data, positions, velocities
