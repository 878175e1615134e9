"""auv_envs.core.rays: first hits equal to MuJoCo's ``mj_ray`` on random rays, in Python
floats and compiled; the docking scenery and a scene of every primitive, turned."""

import casadi
import mujoco
import numpy as np
import pytest

from auv_envs.core import rays
from auv_envs.core.ops import FLOATS, casadi_ops
from auv_envs.core.plant import CompiledFunction
from tests.conftest import make_env

SHAPES = """
<mujoco>
  <worldbody>
    <geom type="plane" size="3 2 0.1" pos="0 0 -1" euler="10 5 0"/>
    <geom type="plane" size="0 0 0.1" pos="0 0 -3"/>
    <geom type="sphere" size="0.4" pos="1 0.5 0.2"/>
    <geom type="capsule" size="0.2 0.6" pos="-1 0.3 0.4" euler="30 60 10"/>
    <geom type="capsule" size="0.1 0.3" pos="0.2 -1 0.5"/>
    <geom type="box" size="0.3 0.5 0.2" pos="0.3 1.2 -0.2" euler="0 45 20"/>
    <geom type="box" size="0.05 0.8 0.4" pos="-0.6 -0.8 0"/>
    <geom type="box" size="0.5 0.5 0.5" pos="5 5 5" rgba="1 1 1 0"/>
    <geom type="sphere" size="0.5" pos="0 0 1.5" group="2"/>
    <body pos="0 0 3"><geom type="sphere" size="0.2"/></body>
  </worldbody>
</mujoco>
"""
GROUPS = np.array([1, 1, 0, 0, 0, 0], dtype=np.uint8)


def _mj_hits(model, data, groups, exclude, points, vecs):
    out = []
    geom = np.zeros(1, dtype=np.int32)
    for point, vec in zip(points, vecs, strict=True):
        d = mujoco.mj_ray(model, data, point, vec, groups, 1, exclude, geom)
        out.append(np.inf if d < 0 else d)
    return np.array(out)


def _compiled(primitives):
    point, vec = casadi.SX.sym("p", 3), casadi.SX.sym("v", 3)
    hit = rays.first_hit(primitives, [point[k] for k in range(3)],
                         [vec[k] for k in range(3)], casadi_ops())
    return CompiledFunction(casadi.Function("hit", [point, vec], [hit]))


def _check(primitives, model, data, groups, exclude, points, vecs):
    expected = _mj_hits(model, data, groups, exclude, points, vecs)
    floats = np.array([rays.first_hit(primitives, p.tolist(), v.tolist(), FLOATS)
                       for p, v in zip(points, vecs, strict=True)])
    compiled = _compiled(primitives)
    native = []
    for p, v in zip(points, vecs, strict=True):
        compiled.inputs[0][:], compiled.inputs[1][:] = p, v
        native.append(compiled()[0][0])
    for got in (floats, np.array(native)):
        np.testing.assert_array_equal(np.isinf(got), np.isinf(expected))
        hit = np.isfinite(expected)
        np.testing.assert_allclose(got[hit], expected[hit], rtol=1e-12, atol=1e-12)
    return np.isfinite(expected)


def test_every_primitive_matches_mj_ray():
    model = mujoco.MjModel.from_xml_string(SHAPES)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    primitives = rays.static_primitives(model, data, GROUPS, exclude_body=1)
    # Not the invisible box, the group-2 sphere nor the excluded body's sphere.
    assert [p.kind for p in primitives] == ["plane", "plane", "sphere", "capsule", "capsule",
                                            "box", "box"]
    rng = np.random.default_rng(4)
    points = rng.uniform(-2.5, 2.5, (3000, 3))
    aims = rng.uniform(-1.5, 1.5, (3000, 3))  # through the shapes' region
    vecs = (aims - points) * rng.uniform(0.3, 3.0, (3000, 1))
    # Axis-parallel rays (zero components: the box's and capsule's special cases).
    vecs[:300, 1:] = 0.0
    vecs[300:600, :2] = 0.0
    hit = _check(primitives, model, data, GROUPS, 1, points, vecs)
    assert 0.3 < hit.mean() < 0.95


@pytest.mark.parametrize("env_id", ["auv_envs/DockingStation-v2",
                                    "auv_envs/LampArrayDocking-v2"])
def test_docking_scenery_matches_mj_ray(env_id):
    env = make_env(env_id, "state")
    env.reset(seed=0)
    phys = env.unwrapped.physics
    primitives = rays.static_primitives(phys.model, phys.data, phys.ray_groups,
                                        phys.hull_body)
    lights = phys.light_positions
    rng = np.random.default_rng(5)
    # Camera centres where an approach passes, near and off the docking axis.
    points = np.repeat(rng.uniform((-4.0, -2.5, -1.4), (3.0, 2.5, 2.0), (500, 3)),
                       len(lights), axis=0)
    vecs = np.tile(lights, (500, 1)) - points
    hit = _check(primitives, phys.model, phys.data, phys.ray_groups, phys.hull_body,
                 points, vecs)
    blocked = hit & (_mj_hits(phys.model, phys.data, phys.ray_groups, phys.hull_body,
                              points, vecs) < 1.0 - 1e-6)
    env.close()
    assert blocked.sum() > 50 and (~blocked).sum() > 50


def test_moving_or_unsupported_geoms_refused():
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom type='sphere' size='0.1'/></body>"
        "</worldbody></mujoco>")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with pytest.raises(ValueError, match="moves"):
        rays.static_primitives(model, data, GROUPS, exclude_body=-1)
    assert rays.static_primitives(model, data, GROUPS, exclude_body=1) == ()
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><geom type='cylinder' size='0.1 0.2'/></worldbody></mujoco>")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with pytest.raises(ValueError, match="CYLINDER"):
        rays.static_primitives(model, data, GROUPS, exclude_body=-1)
