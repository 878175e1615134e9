"""Coarser drawings of far round parts (``DetailLevels``): the choice, the placement, the images."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from auv_envs.core import rendering
from auv_envs.core.rendering import CameraRenderer, DetailLevels
from tests.conftest import DOCKING_IDS, make_env


def needed_levels(model, data, levels, camera, width, height) -> list[int]:
    """Each geom's level written out from the stated rule, one part at a time."""
    focal = 0.5 * height / math.tan(math.radians(model.cam_fovy[camera]) / 2.0)
    corner = math.hypot(width / 2.0, height / 2.0) / focal
    scale = focal * (1.0 + corner ** 2)
    eye = data.cam_xpos[camera]
    out = []
    for level in levels:
        widest = 0.0
        for part in level.parts:
            r = model.geom_size[part, 0]
            half = 0.0 if model.geom_type[part] == mujoco.mjtGeom.mjGEOM_SPHERE \
                else model.geom_size[part, 1]
            axis = data.geom_xmat[part].reshape(3, 3)[:, 2]
            t = np.clip(np.dot(eye - data.geom_xpos[part], axis), -half, half)
            d = np.linalg.norm(eye - data.geom_xpos[part] - t * axis)
            widest = max(widest, math.inf if d <= r else scale * r / math.sqrt(d * d - r * r))
        fits = [k for k, n in enumerate(level.slices)
                if widest * (1.0 - math.cos(math.pi / n)) <= rendering.DETAIL_TOLERANCE_PX]
        out.append(fits[0] if fits else -1)
    return out


def surface_distance(model, data, geom, points) -> np.ndarray:
    """How far each world point lies from the surface of primitive ``geom``."""
    rotation = data.geom_xmat[geom].reshape(3, 3)
    local = (points - data.geom_xpos[geom]) @ rotation
    size = model.geom_size[geom]
    kind = model.geom_type[geom]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return np.abs((np.abs(local) - size).max(axis=1))
    half = 0.0 if kind == mujoco.mjtGeom.mjGEOM_SPHERE else size[1]
    along = np.clip(local[:, 2], -half, half)
    radial = np.linalg.norm(local - np.outer(along, [0.0, 0.0, 1.0]), axis=1)
    return np.abs(radial - size[0])


def approach(physics, poses):
    """Put the vehicle at ``poses`` (x, y, z) in turn, facing the station; yields each."""
    data, adr = physics.data, physics.qpos_adr
    for pose in poses:
        data.qpos[adr:adr + 3] = pose
        data.qpos[adr + 3:adr + 7] = (1.0, 0.0, 0.0, 0.0)
        mujoco.mj_forward(physics.model, data)
        yield pose


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_each_frame_draws_the_level_the_rule_asks_for(env_id):
    size = (84, 84)
    env = make_env(env_id, "image", image_size=size)
    physics = env.unwrapped.physics
    renderer = env.unwrapped.camera_renderer
    levels = physics.detail_levels()
    # The station's drawn mesh stands for its round primitives; every lamp for itself.
    assert len(levels) == 1 + len(physics.lamp_geoms)
    assert {level.parts for level in levels[1:]} == {(int(g),) for g in physics.lamp_geoms}
    try:
        env.reset(seed=3)
        seen = set()
        # From far to inside the funnel, in steps short enough to cross the thresholds.
        xs = np.linspace(-14.0, 1.5, 120)
        for pose in approach(physics, [(x, 0.1, -0.05) for x in xs]):
            renderer.render(physics.data)
            want = needed_levels(physics.model, physics.data, levels, physics.camera_id, *size)
            assert renderer._detail.chosen.tolist() == want, pose
            seen.update(want)
        # The walk used the coarsest level, a finer one and the finest drawing.
        assert {0, -1} <= seen and len(seen) >= 3
    finally:
        env.close()


def test_a_kept_choice_equals_a_fresh_one_along_a_walk():
    # levels_for keeps its answer while the camera stays within the margin to the
    # nearest threshold; a fresh chooser each frame must agree everywhere.
    env = make_env(DOCKING_IDS[0], "image", image_size=(84, 84))
    physics = env.unwrapped.physics
    chooser = env.unwrapped.camera_renderer._detail
    try:
        env.reset(seed=1)
        kept = 0
        s = np.linspace(0.0, 1.0, 300)  # a weaving approach, 3-4 cm a frame
        poses = np.column_stack([-12.0 + 13.0 * s, 0.5 * np.sin(9.0 * s), 0.3 * np.cos(7.0 * s)])
        for pose in approach(physics, poses):
            before = chooser._kept.get(physics.camera_id)
            answer = chooser.levels_for(physics.data, physics.camera_id)
            kept += before is not None and chooser._kept.get(physics.camera_id) is before
            chooser._kept.clear()
            fresh = chooser.levels_for(physics.data, physics.camera_id)
            assert answer.tolist() == fresh.tolist(), pose
        assert kept > 100  # the shortcut was taken, and checked
    finally:
        env.close()


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_a_coarser_mesh_lies_on_the_primitives_where_it_is_drawn(env_id):
    # Placement checked against the primitives' own equations: every vertex of a
    # swapped-in mesh, posed as the scene now draws it, lies on some primitive's
    # surface (tessellated shapes are inscribed: vertices on the surface).
    env = make_env(env_id, "image", image_size=(84, 84))
    physics = env.unwrapped.physics
    model, data = physics.model, physics.data
    renderer = env.unwrapped.camera_renderer
    station_geoms = np.flatnonzero(model.geom_group == 3)
    try:
        env.reset(seed=0)
        next(approach(physics, [(-6.0, 0.0, 0.0)]))
        renderer.render(data)
        chooser = renderer._detail
        assert (chooser.chosen >= 0).all()  # far: every geom drawn coarser
        scene = renderer._scene
        checked = 0
        for level, k in zip(chooser._levels, chooser.chosen.tolist(), strict=True):
            j = next(j for j in range(scene.ngeom) if scene.geoms[j].objid == level.geom)
            geom = scene.geoms[j]
            mesh = level.meshes[k]
            assert geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.dataid == 2 * mesh
            start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            world = model.mesh_vert[start:start + count] @ geom.mat.T + geom.pos
            owners = [level.geom] if level.parts == (level.geom,) else station_geoms
            gap = np.min([surface_distance(model, data, g, world) for g in owners], axis=0)
            assert gap.max() < 2e-5, (model.geom(level.geom).name, gap.max())
            checked += 1
        assert checked == len(chooser._levels)
    finally:
        env.close()


def test_far_frames_match_the_finest_drawing_but_for_a_few_outline_pixels():
    # The same frames with and without the coarser levels (one renderer each).
    size = (84, 84)
    env = make_env(DOCKING_IDS[0], "image", image_size=size)
    physics = env.unwrapped.physics
    ours = env.unwrapped.camera_renderer
    finest = CameraRenderer(physics.model, (physics.camera_name,), *size,
                            hidden_groups=ours.hidden_groups, fit_outlines=True)
    try:
        env.reset(seed=2)
        differing, coarse = [], 0
        for _ in approach(physics, [(x, 0.2, 0.1) for x in np.linspace(-8.0, 1.0, 20)]):
            a = ours.render(physics.data).astype(int)
            b = finest.render(physics.data).astype(int)
            coarse += int((ours._detail.chosen >= 0).any())
            differing.append(int((np.abs(a - b).max(axis=-1) > 8).sum()))
        assert coarse >= 15
        assert max(differing) <= 12 and np.mean(differing) <= 3, differing
    finally:
        finest.close()
        env.close()


def test_features_models_hold_no_coarser_meshes():
    env = make_env(DOCKING_IDS[0], "features")
    try:
        assert env.unwrapped.physics.detail_levels() == ()
    finally:
        env.close()


def test_bad_detail_levels_are_refused():
    with pytest.raises(ValueError, match="one slices count per mesh"):
        DetailLevels(0, (1, 2), (6,), (0,))
    with pytest.raises(ValueError, match="must increase"):
        DetailLevels(0, (1, 2), (8, 6), (0,))
    with pytest.raises(ValueError, match="round parts"):
        DetailLevels(0, (1,), (6,), ())
    env = make_env(DOCKING_IDS[0], "image", image_size=(32, 24))
    physics = env.unwrapped.physics
    model = physics.model
    box = int(np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_BOX)[0])
    lamp = int(physics.lamp_geoms[0])
    try:
        for levels, message in (
                ((DetailLevels(lamp, (1,), (6,), (box,)),), "is not round"),
                ((DetailLevels(lamp, (1,), (6,), (model.ngeom,)),), "is not a geom"),
                ((DetailLevels(lamp, (model.nmesh,), (6,), (lamp,)),), "mesh .* is not in"),
                ((DetailLevels(model.ngeom, (0,), (6,), (lamp,)),), "geom .* is not in")):
            with pytest.raises(ValueError, match=message):
                CameraRenderer(model, (physics.camera_name,), 32, 24, detail=levels)
    finally:
        env.close()
