"""auv_envs.core.rays: the verdicts of MuJoCo's ``mj_ray`` on random segments, in Python
floats, compiled and on JAX; the docking scenery and a scene of every primitive, turned."""

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


def _mj_blocked(model, data, groups, exclude, points, targets):
    out = []
    geom = np.zeros(1, dtype=np.int32)
    for point, target in zip(points, targets, strict=True):
        d = mujoco.mj_ray(model, data, point, target - point, groups, 1, exclude, geom)
        out.append(0.0 <= d < rays.END)
    return np.array(out)


def _compiled(primitives):
    point, target = casadi.SX.sym("p", 3), casadi.SX.sym("t", 3)
    verdict = rays.blocked(primitives, [point[k] for k in range(3)],
                           [target[k] for k in range(3)], casadi_ops())
    return CompiledFunction(casadi.Function("blocked", [point, target],
                                            [casadi.if_else(verdict, 1.0, 0.0)]))


def _check(primitives, model, data, groups, exclude, points, targets):
    """Every backend's verdicts equal mj_ray's; returns those."""
    expected = _mj_blocked(model, data, groups, exclude, points, targets)
    floats = [rays.blocked(primitives, p.tolist(), t.tolist(), FLOATS)
              for p, t in zip(points, targets, strict=True)]
    compiled = _compiled(primitives)
    native = []
    for p, t in zip(points, targets, strict=True):
        compiled.inputs[0][:], compiled.inputs[1][:] = p, t
        native.append(compiled()[0][0] > 0.5)
    np.testing.assert_array_equal(floats, expected)
    np.testing.assert_array_equal(native, expected)
    jax = pytest.importorskip("jax")
    from auv_envs.core.ops import jax_ops

    with jax.enable_x64(True):  # float32 would move the verdicts of grazes
        got = jax.jit(jax.vmap(lambda p, t: rays.blocked(primitives, p, t, jax_ops())))(
            points, targets)
    np.testing.assert_array_equal(np.asarray(got), expected)
    return expected


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
    targets = points + (aims - points) * rng.uniform(0.3, 3.0, (3000, 1))
    # Axis-parallel segments (zero components: the box's and capsule's special cases).
    targets[:300, 1:] = points[:300, 1:]
    targets[300:600, :2] = points[300:600, :2]
    hidden = _check(primitives, model, data, GROUPS, 1, points, targets)
    assert 0.2 < hidden.mean() < 0.8, hidden.mean()
    assert 0.1 < hidden[:600].mean() < 0.9
    # From inside each solid (its centre): hidden where the segment leaves it, not where
    # it ends inside it (mj_ray meets the surface on the way out only).
    solids = [p for p in primitives if p.kind != "plane"]
    centres = np.array([p.pos for p in solids] * 2)
    inner = [np.array(p.pos) + 0.5 * np.array(p.rows[0]) * p.size[0]
             for p in solids]
    targets = np.concatenate([centres[: len(solids)] + [0.0, 0.0, 5.0], inner])
    hidden = _check(primitives, model, data, GROUPS, 1, centres, targets)
    np.testing.assert_array_equal(hidden, [True] * len(solids) + [False] * len(solids))


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
    targets = np.tile(lights, (500, 1))
    hidden = _check(primitives, phys.model, phys.data, phys.ray_groups, phys.hull_body,
                    points, targets)
    env.close()
    assert hidden.sum() > 50 and (~hidden).sum() > 50


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
