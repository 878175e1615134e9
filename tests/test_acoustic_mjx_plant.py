"""The acoustic rig on MJX (:class:`auv_envs.tasks.acoustic.mjx_plant.RigPlantMJX`) is the CPU
plant (:class:`auv_envs.tasks.acoustic.env.AcousticPhysics`).

The JAX ellipsoid fluid model equals MuJoCo's own ``qfrc_fluid`` to round-off in
float64; fed what the task's transition feeds the CPU plant, the MJX rig follows
it to round-off in float64 over 2 s and within 1 cm in float32 over 20 s.
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")
from mujoco import mjx  # noqa: E402

import auv_envs  # noqa: E402, F401
from auv_envs.tasks.acoustic.fluid import EllipsoidFluid  # noqa: E402
from auv_envs.tasks.acoustic.mjx_plant import RigPlantMJX  # noqa: E402

#: The id whose plant the MJX rig reproduces (Euler, two 5 ms steps a period).
ENV_ID = "auv_envs/AcousticTracking-v1"
pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")


@pytest.fixture
def x64():
    """JAX in float64 for the test, restored after it."""
    with jax.enable_x64(True):
        yield


def _physics():
    return gym.make(ENV_ID, obs_mode="state").unwrapped.physics


def _recorded_episode(seed: int, seconds: float):
    """An episode's rig as the transition drives the CPU plant: the placed joints
    ``(carrier, arm)``, the rows ``(carrier_ref, carrier_vel, arm_ref, current)`` of
    periods 1..n (the current each period moves in) and the source's positions and
    velocities (n + 1, 3) at periods 0..n, read from the plant's own calls."""
    env = gym.make(ENV_ID, obs_mode="state").unwrapped
    physics = env.physics
    placed, calls = [], []
    place, follow = physics.place, physics.follow

    def recording_place(carrier, arm):
        placed.append((np.copy(carrier), np.copy(arm)))
        return place(carrier, arm)

    def recording_follow(rig, *args):
        rig, *out = follow(rig, *args)
        calls.append(([np.copy(a) for a in args[:4]], [np.copy(a) for a in out]))
        return rig, *out

    physics.place, physics.follow = recording_place, recording_follow
    env.reset(seed=seed)
    n = int(round(seconds / env.dt))
    action = np.zeros(3, np.float32)  # the estimates do not act on the rig
    while sum(len(args[3]) for args, _ in calls) <= n:
        env.step(action)
    rows = [np.concatenate([args[i] for args, _ in calls])[1 : n + 1] for i in range(4)]
    positions, velocities = (np.concatenate([out[i] for _, out in calls])[: n + 1]
                             for i in range(2))
    return placed[0], rows, positions, velocities


def _placed_and_followed(plant: RigPlantMJX):
    """``(carrier, arm, *rows) -> (placed source position, positions, velocities)`` on
    MJX, compiled."""

    def run(carrier, arm, *rows):
        data = plant.place(carrier, arm, plant.model)
        start, _ = plant.source(data, plant.model)
        _, positions, velocities = plant.periods(data, *rows, plant.model)
        return start, positions, velocities

    return run


def test_fluid_force_is_mujocos(x64):
    physics = _physics()
    model, data = physics.model, physics.data
    plant = RigPlantMJX(physics)
    force = jax.jit(lambda mx_data, wind: plant.fluid.force(plant.model, mx_data, wind))
    rng = np.random.default_rng(0)
    low, high = model.jnt_range[physics.arm_qpos].T
    worst = 0.0
    for k in range(6):
        data.qpos[physics.carrier_qpos] = (rng.uniform(50, 250), rng.uniform(50, 250),
                                           rng.uniform(-25, -5), rng.uniform(-np.pi, np.pi))
        data.qpos[physics.arm_qpos] = rng.uniform(low, high)
        data.qvel[:] = rng.normal(0.0, 0.8, model.nv) if k else 0.0
        wind = rng.normal(0.0, 0.3, 3) if k else np.zeros(3)
        model.opt.wind[:] = wind
        mujoco.mj_forward(model, data)
        expected = data.qfrc_fluid.copy()
        got = np.asarray(force(mjx.put_data(model, data), wind))
        assert got.dtype == np.float64
        if not k:  # at rest in still water: no force, and no NaN from the guards
            np.testing.assert_array_equal(got, expected)
            continue
        worst = max(worst, np.max(np.abs(got - expected)) / np.max(np.abs(expected)))
    assert worst < 1e-9


def test_float64_periods_are_the_cpu_plant(x64):
    (carrier, arm), rows, positions, velocities = _recorded_episode(seed=3, seconds=2.0)
    plant = RigPlantMJX(_physics())
    start, got, got_velocity = jax.jit(_placed_and_followed(plant))(carrier, arm, *rows)
    assert got.dtype == np.float64
    np.testing.assert_allclose(start, positions[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got, positions[1:], rtol=0, atol=1e-8)
    np.testing.assert_allclose(got_velocity, velocities[1:], rtol=0, atol=1e-8)


def test_float32_episodes_stay_within_a_centimetre():
    plant = RigPlantMJX(_physics())
    run = jax.jit(_placed_and_followed(plant))
    for seed in (11, 12):  # one compiled program for both: the same shapes
        (carrier, arm), rows, positions, _ = _recorded_episode(seed=seed, seconds=20.0)
        _, got, _ = run(carrier, arm, *rows)
        assert got.dtype == np.float32
        assert np.max(np.linalg.norm(np.asarray(got) - positions[1:], axis=1)) < 0.01


def test_the_plant_refuses_what_it_does_not_build():
    implicit = gym.make(ENV_ID, obs_mode="state", integrator="implicitfast").unwrapped
    with pytest.raises(ValueError, match="Euler"):
        RigPlantMJX(implicit.physics)
    boxed = mujoco.MjModel.from_xml_string("""
        <mujoco><option density="1000"/><worldbody><body><freejoint/>
          <geom type="box" size="0.1 0.2 0.3"/></body></worldbody></mujoco>""")
    with pytest.raises(NotImplementedError, match="inertia-box"):
        EllipsoidFluid.from_model(boxed)
