"""The CPU arm's shortcuts give the same numbers as what they replace, to the bit: the
compiled truth (:mod:`auv_envs.tasks.lars.compiled`) against the transition's truth in
floats, and the arm's own model against the whole scene's."""

import math

import mujoco
import numpy as np
import pytest

from auv_envs.core.env import TaskEnv
from auv_envs.core.ops import FLOATS
from auv_envs.tasks.lars import transition
from auv_envs.tasks.lars.env import LARSCaptureTask


def _same(a, b) -> bool:
    """Equal, NaN equal to NaN, through nested tuples and lists of the same types."""
    if isinstance(a, tuple | list):
        return (type(a) is type(b) and len(a) == len(b)
                and all(_same(x, y) for x, y in zip(a, b, strict=True)))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("sea_state", ["calm", "severe"])
def test_compiled_truth_is_the_float_truth(sea_state):
    env = TaskEnv(LARSCaptureTask, obs_mode="features", sea_state=sea_state)
    plant, params = env._plant, env.params
    rng = np.random.default_rng(11)
    compared = 0
    for seed in range(12):
        env.reset(seed=seed)
        for _ in range(40):
            _, _, terminated, truncated, _ = env.step(rng.uniform(-0.5, 0.5, 3))
            state = env._episode.state
            compiled = plant.truth(env.physics.data, params, state.scene, state.steps, FLOATS)
            floats = transition.truth(params, state.scene, state.steps, *plant.joints(), FLOATS)
            assert compiled.keys() == floats.keys()
            for key, value in floats.items():
                assert _same(compiled[key], value), (key, compiled[key], value)
            compared += 1
            if terminated or truncated:
                break
    assert plant._compiled is not None and compared > 100


def test_the_sea_ids_use_the_float_truth():
    env = TaskEnv(LARSCaptureTask, obs_mode="state", difficulty="paper")
    env.reset(seed=0)
    env.step(np.zeros(3))
    assert env._plant._compiled is None


def test_the_arm_model_steps_as_the_whole_scene():
    env = TaskEnv(LARSCaptureTask)
    physics = env.physics
    assert physics.model.nbody < physics.scene_model.nbody
    datas = [mujoco.MjData(physics.model), mujoco.MjData(physics.scene_model)]
    rng = np.random.default_rng(5)
    for data in datas:
        data.qpos[:] = (0.2, 0.3, -1.0)
    for _ in range(300):
        action = rng.uniform(-1.0, 1.0, 3)
        for model, data in zip((physics.model, physics.scene_model), datas, strict=True):
            data.ctrl[:] = action
            mujoco.mj_step(model, data, 4)
    np.testing.assert_array_equal(datas[0].qpos, datas[1].qpos)
    np.testing.assert_array_equal(datas[0].qvel, datas[1].qvel)
    assert np.abs(datas[0].qpos - (0.2, 0.3, -1.0)).max() > 0.1  # it moved


def test_a_render_shows_the_arm_where_it_is():
    env = TaskEnv(LARSCaptureTask, render_mode="rgb_array", render_size=(64, 48))
    env.reset(seed=1)
    for _ in range(20):
        env.step(np.ones(3))
    env.render()
    scene = env.physics.scene_data
    np.testing.assert_array_equal(scene.qpos, env.physics.data.qpos)
    tip = env.physics.scene_model.site("tip").id
    np.testing.assert_allclose(scene.site_xpos[tip],
                               env._arm.forward_kinematics(env.physics.data.qpos), atol=1e-9)
