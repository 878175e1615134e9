"""The docking plant compiled (``plant="compiled"``, the ``-v2`` ids) against MuJoCo's.

:class:`auv_envs.core.plant.FreeBodyPlant` integrates the hull with
:func:`auv_envs.core.plant.free_body_rk4` (CasADi-compiled scalar code) where the
``-v1`` plant lets MuJoCo's free body take the wrench at every RK4 stage
(:class:`auv_envs.core.plant.StagedIntegrator`). Away from contacts both are the
same equations, so they must agree to round-off; near the scenery the ``-v2``
env hands the step to MuJoCo.
"""

from __future__ import annotations

import pickle

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the environments)
from auv_envs.core import frames, native
from auv_envs.core.ops import FLOATS, casadi_ops
from auv_envs.core.plant import CompiledFunction, FreeBodyPlant
from auv_envs.core.vehicle import PlantPerturbation

CONSTRAINT = int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)


def _unwrapped(env_id="auv_envs/DockingStation-v2", **kwargs):
    env = gym.make(env_id, **kwargs).unwrapped
    env.reset(seed=0)
    return env


@pytest.mark.parametrize("substeps", [1, 3])
def test_free_body_plant_equals_mujocos_staged_rk4_to_round_off(substeps):
    """From random states, under random wrenches and currents, a perturbed vehicle too."""
    env = _unwrapped(physics_substeps=substeps)
    model = env.physics.model
    rng = np.random.default_rng(7)
    plant = FreeBodyPlant(env.vehicle, float(model.opt.timestep), substeps)
    worst = 0.0
    for trial in range(30):
        draws = None
        if trial % 3 == 2:  # a perturbed episode's vehicle, in MuJoCo's model as the env sets it
            draws = (rng.uniform(0.9, 1.1), rng.uniform(0.7, 1.3, 12), rng.uniform(-5, 5))
        env._use_vehicle(env.vehicle_of(draws))
        plant.vehicle(draws)
        env.physics.set_state(rng.uniform(-8, -3, 3), rng.uniform(-0.4, 0.4, 3),
                              rng.uniform(-0.5, 0.5, 6))
        tau, current = rng.uniform(-80, 80, 6), rng.uniform(-0.4, 0.4, 3)
        qpos, qvel = env.physics.qpos.copy(), env.physics.qvel.copy()
        env.hull.command(tuple(tau), tuple(current))
        model.opt.disableflags |= CONSTRAINT  # no contact: MuJoCo's step is the free body's
        env.integrator.step(substeps)
        plant.advance(qpos, qvel, tau, current)
        assert np.linalg.norm(qpos[3:]) == pytest.approx(1.0, abs=1e-15)
        worst = max(worst, np.abs(qpos - env.physics.qpos).max(),
                    np.abs(qvel - env.physics.qvel).max())
    assert 0.0 < worst < 1e-12  # different code: round-off, not bits


def test_v2_episodes_stay_on_v1s_to_round_off_and_hand_contacts_to_mujoco():
    """A driven episode into the station: the compiled and the MuJoCo plant within 1e-9 m,
    the compiled path taken away from the scenery, MuJoCo's near it."""
    v1 = gym.make("auv_envs/DockingStation-v1", obs_mode="state")
    v2 = gym.make("auv_envs/DockingStation-v2", obs_mode="state")
    plant = v2.unwrapped._plant
    calls = {"compiled": 0, "mujoco": 0}
    advance = plant.free_body.advance

    def counted(*args):
        calls["compiled"] += 1
        return advance(*args)

    plant.free_body.advance = counted
    staged = v2.unwrapped.integrator.step

    def counted_staged(*args):
        calls["mujoco"] += 1
        return staged(*args)

    v2.unwrapped.integrator.step = counted_staged
    for env in (v1, v2):
        env.reset(seed=5)
    worst, steps = 0.0, 0
    for _ in range(400):  # full surge along the line to the entrance: reaches the station
        o1, *_, i1 = v1.step(np.array([1.0, 0.0, 0.0, 0.0], np.float32))
        o2, _, term, trunc, i2 = v2.step(np.array([1.0, 0.0, 0.0, 0.0], np.float32))
        worst = max(worst, np.abs(i1["true_position"] - i2["true_position"]).max())
        steps += 1
        if term or trunc:
            break
    assert calls["compiled"] > 0 and calls["mujoco"] > 0, calls
    assert worst < 1e-9, worst


@pytest.mark.parametrize("env_id", ["auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2"])
def test_compiled_truth_equals_the_float_truth(env_id):
    """Kinematics and pixels to round-off, the same lights seen: over poses in front of the
    station and in it, with lamps hidden by its structure (compiled lines of sight against
    the float truth's ``mj_ray``)."""
    env = _unwrapped(env_id, obs_mode="features")
    intrinsics = env.rules.intrinsics
    rng = np.random.default_rng(3)
    hidden = seen = 0
    for _ in range(400):
        env.physics.set_state(rng.uniform([-12, -3, -3], [0.5, 3, 2]),
                              rng.uniform(-0.5, 0.5, 3), rng.uniform(-0.5, 0.5, 6))
        compiled, floats = env._plant.truth(env.physics.data), env._float_truth()
        assert compiled.keys() == floats.keys()
        for key, value in floats.items():
            np.testing.assert_allclose(np.asarray(compiled[key], float),
                                       np.asarray(value, float), rtol=1e-12, atol=1e-9,
                                       err_msg=key)
            np.testing.assert_array_equal(np.isnan(np.asarray(compiled[key], float)),
                                          np.isnan(np.asarray(value, float)))
        u, v = floats["pixels"][:, 0], floats["pixels"][:, 1]
        in_image = (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)
        hidden += int(np.sum(in_image & ~floats["visible"]))
        seen += int(np.sum(floats["visible"]))
    assert hidden > 20 and seen > 20, (hidden, seen)


def test_scenery_that_cannot_be_compiled_is_ray_cast_by_mujoco(monkeypatch):
    """A scenery geom the compiled lines of sight do not cover (here: refused by a patched
    ``static_primitives``) leaves them to ``mj_ray``, with a warning; the same truth."""
    from auv_envs.core import rays
    from auv_envs.tasks.docking.plant import CompiledTruth

    env = _unwrapped("auv_envs/DockingStation-v2", obs_mode="features")

    def refuse(*args):
        raise ValueError("geom 'x' is a mjGEOM_MESH")

    monkeypatch.setattr(rays, "static_primitives", refuse)
    with pytest.warns(RuntimeWarning, match="cast by MuJoCo.*MESH"):
        fallback = CompiledTruth(env.rules, env.physics)
    rng = np.random.default_rng(6)
    hidden = 0
    for _ in range(200):
        env.physics.set_state(rng.uniform([-6, -2, -1.5], [0.5, 2, 2]),
                              rng.uniform(-0.3, 0.3, 3), np.zeros(6))
        got, compiled = fallback(), env._plant.truth(env.physics.data)
        np.testing.assert_array_equal(got["visible"], compiled["visible"])
        np.testing.assert_array_equal(got["pixels"], compiled["pixels"])
        hidden += int(np.sum(~got["visible"] & np.isfinite(got["pixels"][:, 0])))
    assert hidden > 0


def test_lines_of_sight_left_to_mujoco_without_machine_code(monkeypatch):
    """On CasADi's virtual machine the compiled lines of sight would be slower than
    MuJoCo's ray casts: without machine code the truth leaves them to ``mj_ray``."""
    from auv_envs.tasks.docking.plant import CompiledTruth

    env = _unwrapped("auv_envs/DockingStation-v2", obs_mode="features")
    monkeypatch.setenv("AUV_ENVS_NATIVE", "0")
    truth = CompiledTruth(env.rules, env.physics)
    assert not truth._call.native and not truth._sight_compiled
    monkeypatch.setenv("AUV_ENVS_NATIVE", "1")
    if native.compiler() is not None:
        truth = CompiledTruth(env.rules, env.physics)
        assert truth._call.native and truth._sight_compiled


def test_quat_turned_is_mujocos_quat_integrate_on_every_backend():
    import casadi

    rng = np.random.default_rng(2)
    ops = casadi_ops()
    q, w = casadi.SX.sym("q", 4), casadi.SX.sym("w", 3)
    symbolic = casadi.Function("turn", [q, w], [casadi.vertcat(*frames.quat_turned(
        [q[k] for k in range(4)], [w[k] for k in range(3)], 0.07, ops))])
    for scale in (1.0, 1e-12, 0.0):  # the small-angle series too
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        omega = rng.normal(size=3) * scale
        expected = quat.copy()
        mujoco.mju_quatIntegrate(expected, omega, 0.07)
        np.testing.assert_allclose(frames.quat_turned(quat.tolist(), omega.tolist(), 0.07, FLOATS),
                                   expected, atol=1e-15)
        np.testing.assert_allclose(np.asarray(symbolic(quat, omega)).ravel(), expected, atol=1e-15)


def test_compiled_function_pickles_with_its_inputs():
    import casadi

    x = casadi.SX.sym("x", 3)
    call = CompiledFunction(casadi.Function("f", [x], [casadi.sin(x) * 2.0]))
    call.inputs[0][:] = (0.1, 0.2, 0.3)
    clone = pickle.loads(pickle.dumps(call))
    np.testing.assert_array_equal(clone.inputs[0], call.inputs[0])
    np.testing.assert_allclose(clone()[0], 2.0 * np.sin([0.1, 0.2, 0.3]), rtol=1e-15)
    assert clone.outputs[0] is not call.outputs[0]


def test_plant_choice_is_checked():
    with pytest.raises(ValueError, match="plant"):
        gym.make("auv_envs/DockingStation-v2", plant="fast")
    with pytest.raises(ValueError, match="compiled plant integrates with RK4"):
        gym.make("auv_envs/DockingStation-v2", integrator="euler")
    assert gym.make("auv_envs/DockingStation-v0").unwrapped._init_kwargs["plant"] == "mujoco"


def test_perturbed_vehicle_reaches_the_compiled_plant():
    """A ``paper`` episode's drawn vehicle is what the compiled plant integrates."""
    env = gym.make("auv_envs/DockingStation-v2", difficulty="paper").unwrapped
    env.reset(seed=11)
    draws = env._episode.state.plant
    assert draws is not None
    env.step(np.zeros(4, np.float32))
    mass, damping, buoyancy = draws
    np.testing.assert_array_equal(env._plant.free_body._call.inputs[4],
                                  [mass, *damping, buoyancy])
    vehicle = PlantPerturbation.apply(env._params, mass, damping.tolist(), buoyancy)
    assert env.vehicle.mass == vehicle.mass


def test_compiled_function_reads_bound_inputs_and_refuses_ones_it_cannot_bind():
    import casadi

    x = casadi.SX.sym("x", 3)
    function = casadi.Function("f", [x], [2.0 * x])
    memory = np.zeros(6)
    call = CompiledFunction(function, (memory[1:4],))
    memory[1:4] = (1.0, 2.0, 3.0)  # written after binding: read at the next call
    np.testing.assert_array_equal(call()[0], (2.0, 4.0, 6.0))
    for bad in (np.zeros(4), np.zeros(3, np.float32), np.zeros(6)[::2]):
        with pytest.raises(ValueError, match="contiguous float64"):
            CompiledFunction(function, (bad,))
