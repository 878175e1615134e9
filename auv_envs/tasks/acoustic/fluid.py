"""MuJoCo's ellipsoid fluid model on JAX, for the rig on MJX.

MuJoCo MJX implements only the inertia-box fluid model; the acoustic rig's
geoms use the ellipsoid model (``fluidshape="ellipsoid"``). This module is
that model, as MuJoCo documents it: "Computation > Fluid forces > Ellipsoid
model" (https://mujoco.readthedocs.io/en/stable/computation/fluid.html#ellipsoid-model),
its subsections "Ellipsoid projection", "Added mass", "Viscous drag" and
"Viscous lift" (Magnus force, Kutta condition). Per geom, in the geom's frame,
with ``v`` and ``w`` the geom's linear velocity relative to the water (the
``wind`` subtracted) and its angular velocity, ``rho`` the density and
``beta`` the viscosity:

* added mass, without the acceleration terms (MuJoCo drops them: they would
  depend on ``qacc``): ``f_A = (rho m_A o v) x w``,
  ``g_A = (rho m_A o v) x v + (rho I_A o w) x w``;
* drag: ``f_D = -rho [C_blunt A_proj(v) + C_slender (A_max - A_proj(v))] |v| v``,
  ``g_D = -rho |(C_angular I_D + C_slender (I_max - I_D)) o w| w``;
* Magnus lift ``f_M = C_M rho V w x v`` (``V`` the ellipsoid's volume); Kutta lift
  ``f_K = C_K rho A_proj(v) (v^ . n^) (n^ x v) x v``, ``n^`` the unit normal of
  the cross-section whose projection along ``v`` is ``A_proj(v)`` (the docs'
  projection lemma);
* Stokes resistance of the equivalent sphere: ``f_V = -3 pi D beta v``,
  ``g_V = -pi D^3 beta w``, ``D = 2 (r_x + r_y + r_z) / 3``,

all scaled by the geom's interaction coefficient and applied at the geom's
centre to its body. The coefficients are MuJoCo's ``geom_fluid`` (the
compiler's added masses and inertias included), so a model's ``fluidcoef``
carries over; the terms are evaluated as MuJoCo's ``mj_ellipsoidFluidModel``
evaluates them, so in float64 the generalized force equals
``MjData.qfrc_fluid`` to round-off.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

#: MuJoCo's guard against division by zero (``mjMINVAL``).
MINVAL = mujoco.mjMINVAL


def _semiaxes(geom_type: np.ndarray, size: np.ndarray) -> np.ndarray:
    """The semi-axes of each geom's ellipsoid (MuJoCo's ``mju_geomSemiAxes``): a
    sphere's radius thrice, a capsule's radius twice and its half-length plus radius, a
    cylinder's radius twice and its half-length, any other geom its three sizes."""
    radius, half = size[:, 0], size[:, 1]
    axes = size.copy()
    sphere = geom_type == mujoco.mjtGeom.mjGEOM_SPHERE
    capsule = geom_type == mujoco.mjtGeom.mjGEOM_CAPSULE
    cylinder = geom_type == mujoco.mjtGeom.mjGEOM_CYLINDER
    axes[sphere] = radius[sphere, None]
    axes[capsule | cylinder, :2] = radius[capsule | cylinder, None]
    axes[capsule, 2] = half[capsule] + radius[capsule]
    axes[cylinder, 2] = half[cylinder]
    return axes


def _to_local(rot, vec):
    """Row-wise ``R^T vec``: world vectors (G, 3) in the frames ``rot`` (G, 3, 3)."""
    return jnp.einsum("gji,gj->gi", rot, vec)


def _to_world(rot, vec):
    """Row-wise ``R vec``: vectors (G, 3) in the frames ``rot`` (G, 3, 3) in the world."""
    return jnp.einsum("gij,gj->gi", rot, vec)


@dataclasses.dataclass(frozen=True, eq=False)
class EllipsoidFluid:
    """The ellipsoid fluid model's constants for one MuJoCo model, per geom that feels it.

    Built by :meth:`from_model`; :meth:`force` evaluates the model on MJX data.
    Arrays are NumPy float64 and become constants of the traced function (float32
    unless JAX runs in float64).

    Attributes:
        density, viscosity: the water's (``opt.density`` kg/m^3, ``opt.viscosity`` Pa s).
        geom, body, root: (G,) the geoms, their bodies and those bodies' tree roots.
        interaction: (G,) the geom's interaction coefficient (scales all its forces).
        blunt, slender, angular, kutta, magnus: (G,) the ``fluidcoef`` drag and lift
            coefficients.
        virtual_mass, virtual_inertia: (G, 3) the added mass and inertia per unit
            density, in the geom's frame.
        semiaxes: (G, 3) the ellipsoid's semi-axes (m).
        volume: (G,) its volume; area_max: (G,) its largest projected area
            ``pi r_max r_mid``.
        face_area: (G, 3) ``(r_y r_z, r_z r_x, r_x r_y)``: the projection's areas
            over pi along each axis.
        angular_moment: (G, 3) ``C_angular I_D + C_slender (I_max - I_D)``, the
            angular drag's reference moments.
        sphere_diameter: (G,) ``D``, the Stokes resistance's equivalent sphere.
    """

    density: float
    viscosity: float
    geom: np.ndarray
    body: np.ndarray
    root: np.ndarray
    interaction: np.ndarray
    blunt: np.ndarray
    slender: np.ndarray
    angular: np.ndarray
    kutta: np.ndarray
    magnus: np.ndarray
    virtual_mass: np.ndarray
    virtual_inertia: np.ndarray
    semiaxes: np.ndarray
    volume: np.ndarray
    area_max: np.ndarray
    face_area: np.ndarray
    angular_moment: np.ndarray
    sphere_diameter: np.ndarray

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> EllipsoidFluid:
        """The constants of ``model``'s ellipsoid geoms (on bodies with mass, as MuJoCo).

        Raises:
            NotImplementedError: when a body with mass and no ellipsoid geom would feel
                the inertia-box model in water (``opt.density`` or ``opt.viscosity`` > 0).
        """
        fluid = np.asarray(model.geom_fluid, dtype=np.float64).reshape(model.ngeom, -1)
        body = np.asarray(model.geom_bodyid)
        massive = model.body_mass >= MINVAL
        ellipsoid = fluid[:, 0] > 0  # the interaction coefficient, 0 or 1 from fluidshape
        if model.opt.density > 0 or model.opt.viscosity > 0:
            has_ellipsoid = np.zeros(model.nbody, bool)
            has_ellipsoid[body[ellipsoid]] = True
            boxed = np.flatnonzero(massive & ~has_ellipsoid)
            if boxed.size:
                names = [model.body(int(b)).name for b in boxed]
                raise NotImplementedError(f"bodies {names} would feel MuJoCo's inertia-box "
                                          "fluid model; only the ellipsoid model is built")
        geom = np.flatnonzero(ellipsoid & massive[body])
        fluid = fluid[geom]
        axes = _semiaxes(np.asarray(model.geom_type)[geom], np.asarray(model.geom_size)[geom])
        ordered = np.sort(axes, axis=1)
        r_mid, r_max = ordered[:, 1], ordered[:, 2]
        # I_D,ii = 8 pi / 15 r_i max(r_j, r_k)^4; I_max = 8 pi / 15 r_mid r_max^4
        others = np.stack([np.maximum(axes[:, 1], axes[:, 2]), np.maximum(axes[:, 2], axes[:, 0]),
                           np.maximum(axes[:, 0], axes[:, 1])], axis=1)
        moment = 8.0 / 15.0 * math.pi * axes * others**4
        moment_max = 8.0 / 15.0 * math.pi * r_mid * r_max**4
        blunt, slender, angular = fluid[:, 1], fluid[:, 2], fluid[:, 3]
        return cls(
            density=float(model.opt.density),
            viscosity=float(model.opt.viscosity),
            geom=geom,
            body=body[geom],
            root=np.asarray(model.body_rootid)[body[geom]],
            interaction=fluid[:, 0],
            blunt=blunt,
            slender=slender,
            angular=angular,
            kutta=fluid[:, 4],
            magnus=fluid[:, 5],
            virtual_mass=fluid[:, 6:9],
            virtual_inertia=fluid[:, 9:12],
            semiaxes=axes,
            volume=4.0 / 3.0 * math.pi * np.prod(axes, axis=1),
            area_max=math.pi * r_max * r_mid,
            face_area=np.stack([axes[:, 1] * axes[:, 2], axes[:, 2] * axes[:, 0],
                                axes[:, 0] * axes[:, 1]], axis=1),
            angular_moment=(angular[:, None] * moment
                            + slender[:, None] * (moment_max[:, None] - moment)),
            sphere_diameter=2.0 / 3.0 * np.sum(axes, axis=1),
        )

    def local_velocity(self, data: mjx.Data, wind) -> tuple[jax.Array, jax.Array]:
        """Each geom's angular and linear velocity (G, 3) each, in its own frame, the
        linear one relative to the water moving at ``wind`` (3,) (MuJoCo's
        ``mj_objectVelocity`` at the geom, less the rotated wind)."""
        rot = data.geom_xmat[self.geom]
        cvel = data.cvel[self.body]  # about the tree's centre of mass, world frame
        offset = data.geom_xpos[self.geom] - data.subtree_com[self.root]
        spin = cvel[:, :3]
        linear = cvel[:, 3:] - jnp.cross(offset, spin)
        water = _to_local(rot, jnp.broadcast_to(wind, linear.shape))
        return _to_local(rot, spin), _to_local(rot, linear) - water

    def local_wrench(self, w, v) -> tuple[jax.Array, jax.Array]:
        """The fluid's torque and force (G, 3) each on each geom, in the geom's frame,
        given its local angular velocity ``w`` and linear velocity through the water
        ``v`` (the module docstring's terms)."""
        rho, beta = self.density, self.viscosity
        # Added mass: the virtual linear and angular momenta.
        momentum = rho * self.virtual_mass * v
        spin_momentum = rho * self.virtual_inertia * w
        torque = jnp.cross(momentum, v) + jnp.cross(spin_momentum, w)
        force = jnp.cross(momentum, w)
        # Magnus lift.
        force = force + (self.magnus * rho * self.volume)[:, None] * jnp.cross(w, v)
        # The area projected along v (the docs' ellipsoid projection lemma), its normal
        # (not unit) and the cosine between v and that normal.
        face2 = self.face_area**2
        normal = face2 * v
        proj_denom = jnp.sum(face2 * face2 * v * v, axis=-1)
        proj_num = jnp.sum((self.face_area * v) ** 2, axis=-1)
        area = math.pi * jnp.sqrt(proj_denom / jnp.maximum(MINVAL, proj_num))
        speed = jnp.sqrt(jnp.sum(v * v, axis=-1))
        cos_alpha = proj_num / jnp.maximum(MINVAL, speed * proj_denom)
        # Kutta lift: the circulation (n x v) scaled, crossed with v.
        circulation = (self.kutta * rho * cos_alpha * area)[:, None] * jnp.cross(normal, v)
        force = force + jnp.cross(circulation, v)
        # Stokes resistance plus quadratic drag.
        diameter = self.sphere_diameter
        drag = (beta * 3.0 * math.pi * diameter
                + rho * speed * (area * self.blunt + self.slender * (self.area_max - area)))
        spin_moment = self.angular_moment * w
        spin_drag = (beta * math.pi * diameter**3
                     + rho * jnp.sqrt(jnp.sum(spin_moment * spin_moment, axis=-1)))
        force = force - drag[:, None] * v
        torque = torque - spin_drag[:, None] * w
        scale = self.interaction[:, None]
        return scale * torque, scale * force

    def force(self, model: mjx.Model, data: mjx.Data, wind) -> jax.Array:
        """The generalized fluid force (nv,) in water moving at ``wind`` (3,) m/s: MuJoCo's
        ``qfrc_fluid``.

        ``data`` needs its positions and velocities computed (``geom_xpos``,
        ``geom_xmat``, ``subtree_com``, ``cdof`` and ``cvel``: :func:`mjx.kinematics`,
        :func:`mjx.com_pos` and :func:`mjx.com_vel`, as in ``mj_fwdVelocity``).
        """
        w, v = self.local_velocity(data, wind)
        torque, force = self.local_wrench(w, v)
        rot = data.geom_xmat[self.geom]
        apply = jax.vmap(mjx.apply_ft, in_axes=(None, None, 0, 0, 0, 0))
        qfrc = apply(model, data, _to_world(rot, force), _to_world(rot, torque),
                     data.geom_xpos[self.geom], jnp.asarray(self.body))
        return jnp.sum(qfrc, axis=0)
