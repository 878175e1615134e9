"""The docking environment's plants: what :mod:`auv_envs.tasks.docking.transition` calls
``place``, ``advance`` and ``truth`` on the CPU. Their state is the env's MuJoCo
``MjData``, which they integrate in place and return (:mod:`auv_envs.core.task`).

* :class:`MujocoPlant` (``plant="mujoco"``, the ``-v1`` ids): MuJoCo's staged RK4 with
  the hull wrench at every stage (:class:`auv_envs.core.plant.StagedIntegrator`), the
  truth in Python floats.
* :class:`CompiledPlant` (``plant="compiled"``, the ``-v2`` ids): the hull compiled
  (:class:`auv_envs.core.plant.FreeBodyPlant`) wherever no contact can act, and the
  truth's arithmetic compiled (:class:`CompiledTruth`); the same equations to round-off.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np

from auv_envs.core import frames, rays
from auv_envs.core.camera import project_few
from auv_envs.core.ops import FLOATS, casadi_ops
from auv_envs.core.plant import CompiledFunction, FreeBodyPlant
from auv_envs.tasks.docking import transition
from auv_envs.tasks.docking.navigation import CompiledNavigation
from auv_envs.tasks.docking.optics import CompiledLampDetection
from auv_envs.tasks.docking.rules import DockingRules
from auv_envs.tasks.docking.station import DockingPhysics


class MujocoPlant:
    """The docking transition's plant on the CPU: the env's MuJoCo model and data, the hull
    wrench at every integrator stage (:class:`auv_envs.core.plant.StagedIntegrator`)."""

    def __init__(self, env):
        self.env = env

    def place(self, start: transition.Start, vehicle, failed):
        env = self.env
        env._use_vehicle(env.vehicle_of(vehicle))
        env.physics.set_state([start.x, start.y, start.z], [0.0, 0.0, start.yaw],
                              [start.surge, 0, 0, 0, 0, 0])
        if failed is not None:  # the episode's failed lamps are drawn unlit
            env.physics.show_lamps(failed)
        return env.physics.data

    def advance(self, body, tau, current, vehicle):
        self.env.physics.skip_contacts_if_clear(self.env.dt)
        self._staged(tau, current)
        return body

    def _staged(self, tau, current) -> None:
        """One control period of MuJoCo's staged RK4 (the contact gate already set)."""
        env = self.env
        env.hull.command(tau, [float(c) for c in current])
        env.integrator.step(env._physics_substeps)

    def truth(self, body) -> dict:
        return self.env._float_truth()


class CompiledPlant(MujocoPlant):
    """The plant of ``plant="compiled"`` (the ``-v2`` ids): the hull compiled
    (:class:`auv_envs.core.plant.FreeBodyPlant`) wherever no contact can act in the coming
    period, MuJoCo's staged RK4 (:class:`MujocoPlant`) where one can; the truth's
    kinematics, the lights' projection and lines of sight compiled too
    (:class:`CompiledTruth`). The same equations as ``plant="mujoco"``, to round-off."""

    def __init__(self, env):
        super().__init__(env)
        self.free_body = FreeBodyPlant(env._params, float(env.physics.model.opt.timestep),
                                       env._physics_substeps)
        self.kinematics = CompiledTruth(env.rules, env.physics)
        self._vehicle = None

    def advance(self, body, tau, current, vehicle):
        env = self.env
        if vehicle is not self._vehicle:
            self.free_body.vehicle(vehicle)
            self._vehicle = vehicle
        physics = env.physics
        if not physics.skip_contacts_if_clear(env.dt):
            self._staged(tau, current)
            return body
        self.free_body.advance(physics.qpos, physics.qvel, tau, current)
        physics.data.time += env.dt
        return body

    def truth(self, body) -> dict:
        return self.kinematics()


class CompiledTruth:
    """:meth:`DockingRules.kinematics` of the hull's free joint, the lights' pixels
    (:func:`~auv_envs.core.camera.project_few`) and their lines of sight through the
    static scenery (:func:`auv_envs.core.rays.blocked`, ``mj_ray``'s verdicts) as
    one compiled call (:class:`auv_envs.core.plant.CompiledFunction`, built from the same
    code on CasADi symbols). Scenery that cannot be compiled (a moving geom, a mesh) is
    ray-cast by MuJoCo instead (:meth:`DockingPhysics.unoccluded`), with a warning; so
    is all scenery where the call is not machine code (:mod:`auv_envs.core.native`),
    since CasADi's virtual machine would be slower. The same verdicts either way."""

    def __init__(self, rules: DockingRules, physics: DockingPhysics):
        try:
            scenery = rays.static_primitives(physics.model, physics.data, physics.ray_groups,
                                             physics.hull_body)
        except ValueError as error:
            warnings.warn(f"lines of sight cast by MuJoCo, not compiled: {error}",
                          RuntimeWarning, stacklevel=2)
            scenery = None
        function, self._layout, self._pixels = _truth_function(rules, scenery)
        # The inputs are the hull's free joint in MjData itself: nothing copied per call.
        self._call = CompiledFunction(function, (physics.qpos, physics.qvel))
        if scenery is not None and not self._call.native:
            # On CasADi's virtual machine the lines of sight cost more than MuJoCo's ray
            # casts; as machine code, less (docs/speed.md).
            scenery = None
            function, self._layout, self._pixels = _truth_function(rules, scenery)
            self._call = CompiledFunction(function, (physics.qpos, physics.qvel))
        self._sight_compiled = scenery is not None
        self.physics, self.lights, self._n = physics, rules.lights, len(rules.lights)

    def __call__(self) -> dict:
        out, lights = self._call()
        values = out.tolist()
        truth = {key: tuple(values[part]) if many else values[part.start]
                 for key, part, many in self._layout}
        n = self._n
        # Copies: the call's outputs are written again by the next call.
        pixels = out[self._pixels].reshape(-1, 2).copy()
        if not self._sight_compiled:  # lines of sight left to MuJoCo (see __init__)
            visible = np.array(self.physics.unoccluded(truth["camera_position"], self.lights,
                                                       (lights[:n] > 0.5).tolist()))
            return transition.truth_with_lights(truth, pixels, visible, FLOATS)
        lights = lights.copy()
        return transition.truth_with_lights(truth, pixels, lights[:n] > 0.5, FLOATS,
                                            lights[n:3 * n].reshape(-1, 2),
                                            int(lights[3 * n]))


@functools.lru_cache(maxsize=32)
def _truth_function(rules: DockingRules, scenery: tuple[rays.Primitive, ...] | None):
    """:class:`CompiledTruth`'s CasADi function of ``(qpos, qvel)`` (outputs: the truth, and
    per light 1 where its pixel is in the image (:func:`~auv_envs.core.camera.inside_image`:
    a NaN pixel is not) and no geom of ``scenery`` lies on the segment from the camera
    centre to it, else 0; the image alone where ``scenery`` is None), with the truth's keys
    (each with its slice of the output and whether it is a tuple) and the pixels' slice;
    built once per task's rules and scenery (a CasADi function is immutable)."""
    import casadi

    ops = casadi_ops()
    qpos, qvel = casadi.SX.sym("qpos", 7), casadi.SX.sym("qvel", 6)
    rotation = frames.rotation_rows_from_quat(*(qpos[k] for k in range(3, 7)))
    truth = rules.kinematics([qpos[k] for k in range(3)], rotation,
                             [qvel[k] for k in range(6)], ops)
    pixels, in_image = project_few(rules.intrinsics, rules.lights, truth["camera_position"],
                                   truth.pop("camera_rows"), ops)
    layout, flat = [], []
    for key, value in truth.items():
        many = isinstance(value, tuple | list)
        values = list(value) if many else [value]
        layout.append((key, slice(len(flat), len(flat) + len(values)), many))
        flat.extend(values)
    pixel_slice = slice(len(flat), len(flat) + 2 * len(rules.lights))
    flat.extend(c for pixel in pixels for c in pixel)
    camera, seen = truth["camera_position"], []
    for light, inside in zip(rules.lights, in_image, strict=True):
        if scenery is not None:
            inside = ops.logical_and(inside, ops.logical_not(
                rays.blocked(scenery, camera, light, ops)))
        seen.append(ops.where(inside, 1.0, 0.0))
    # truth_with_lights' visible pixels and count, selected and summed in the call
    shown = [ops.where(flag > 0.5, c, 0.0) for flag, pixel in zip(seen, pixels, strict=True)
             for c in pixel]
    function = casadi.Function("docking_truth", [qpos, qvel],
                               [casadi.vertcat(*flat), casadi.vertcat(*seen, *shown, sum(seen))],
                               {"cse": True})
    return function, tuple(layout), pixel_slice


def compiled_sensors(params: transition.DockingParams) -> transition.DockingParams:
    """``params`` with its sensors compiled for the CPU (``sensors="compiled"``): the
    navigation sensors (:class:`~auv_envs.tasks.docking.navigation.CompiledNavigation`) in
    the ``nav`` modes, and the lights' detection through the water
    (:class:`~auv_envs.tasks.docking.optics.CompiledLampDetection`, with the DVL/INS
    readings where no navigation suite makes them) in the modes with lights, where the
    water hides lamps (``optics``)."""
    changes = {}
    nav = params.navigation
    if nav is not None:
        changes["navigation"] = CompiledNavigation(nav.sensors, nav.seabed_z, nav.dt)
    if params.optics is not None and params.obs_mode in transition.LIGHT_MODES:
        changes["lamp_detection"] = CompiledLampDetection(
            params.light_positions, params.optics, params.noise[0], params.pixel_bounds,
            params.focal_px, params.dt, None if nav is not None else params.noise[1:])
    return dataclasses.replace(params, **changes)
