"""The station drawn as meshes: each shape against its equations, then against MuJoCo's drawing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.conftest import DOCKING_IDS, make_env


def signed_volume(vertices, faces) -> float:
    """Volume enclosed by the triangles (divergence theorem); positive when they face outwards."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def edges_are_shared_in_pairs(vertices, faces) -> bool:
    """Closed surface: every edge (by vertex position) belongs to exactly two triangles."""
    keys = [tuple(np.round(v, 9)) for v in vertices]
    count: dict = {}
    for tri in faces:
        for i, j in ((0, 1), (1, 2), (2, 0)):
            edge = frozenset((keys[tri[i]], keys[tri[j]]))
            count[edge] = count.get(edge, 0) + 1
    return all(n == 2 for n in count.values())


def test_a_box_is_its_six_faces_facing_out():
    from auv_envs.core.tessellation import box

    half = np.array([0.3, 0.2, 0.1])
    v, n, f = box(half)
    assert v.shape == (24, 3) and f.shape == (12, 3)
    np.testing.assert_allclose(np.abs(v), np.broadcast_to(half, v.shape))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    # Each vertex's normal is its face's axis, and the vertex lies on that face.
    np.testing.assert_allclose((v * n).sum(axis=1), (np.abs(n) @ half))
    assert signed_volume(v, f) == pytest.approx(8 * half.prod())
    assert edges_are_shared_in_pairs(v, f)


@pytest.mark.parametrize("slices", [3, 8, 17, 28])
def test_a_capsule_lies_on_its_surface_with_true_normals(slices):
    from auv_envs.core.tessellation import cap_stacks, capsule

    r, h = 0.05, 0.7
    v, n, f = capsule(r, h, slices)
    axis_point = np.stack([np.zeros(len(v)), np.zeros(len(v)), np.clip(v[:, 2], -h, h)], axis=1)
    np.testing.assert_allclose(np.linalg.norm(v - axis_point, axis=1), r, rtol=1e-12)
    np.testing.assert_allclose(n, (v - axis_point) / r, atol=1e-12)
    assert edges_are_shared_in_pairs(v, f)
    # Inscribed: below the true volume, above that of the inscribed polygon's prism alone.
    polygon = 0.5 * slices * r * r * math.sin(2 * math.pi / slices)
    true = math.pi * r * r * 2 * h + 4.0 / 3.0 * math.pi * r**3
    assert polygon * 2 * h < signed_volume(v, f) < true
    # Round outlines: slices sides about the axis, a meridian of at least as many.
    k = cap_stacks(slices)
    assert 4 * k >= slices and 4 * (k - 1) < slices
    off_axis = np.hypot(v[:, 0], v[:, 1]) > 1e-9
    azimuths = np.unique(np.round(np.arctan2(v[off_axis, 1], v[off_axis, 0]), 9))
    assert len(azimuths) == slices
    # The straight part is one band: 2 rings at the equators, none between.
    between = np.abs(v[:, 2]) < h - 1e-12
    assert not between.any()


def test_a_cylinder_is_a_prism_of_its_polygon_and_a_sphere_a_capsule_of_no_length():
    from auv_envs.core.tessellation import capsule, cylinder, sphere

    r, h, slices = 0.1, 0.4, 12
    v, n, f = cylinder(r, h, slices)
    polygon = 0.5 * slices * r * r * math.sin(2 * math.pi / slices)
    assert signed_volume(v, f) == pytest.approx(polygon * 2 * h)
    assert edges_are_shared_in_pairs(v, f)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    for a, b in zip(sphere(r, slices), capsule(r, 0.0, slices), strict=True):
        np.testing.assert_array_equal(a, b)


def test_bad_shapes_and_unknown_geoms_are_refused():
    import mujoco

    from auv_envs.core import tessellation

    with pytest.raises(ValueError, match="slices"):
        tessellation.capsule(0.1, 0.2, 2)
    with pytest.raises(ValueError, match="radius"):
        tessellation.sphere(0.0, 12)
    with pytest.raises(ValueError, match="half-sizes"):
        tessellation.box([0.1, -0.2, 0.3])
    v, n, f = tessellation.box([0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="normals"):
        tessellation.msh_bytes(v, n[:-1], f)
    with pytest.raises(ValueError, match="indices"):
        tessellation.msh_bytes(v, n, f + 1)
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="egg" type="ellipsoid" size="0.1 0.2 0.3"/>'
        "</worldbody></mujoco>")
    data = mujoco.MjData(model)
    with pytest.raises(ValueError, match="'egg'.*not tessellated"):
        tessellation.static_mesh(model, data, [0], 12)
    with pytest.raises(ValueError, match="no geoms"):
        tessellation.static_mesh(model, data, [], 12)


def test_the_binary_mesh_is_what_mujoco_reads():
    import mujoco

    from auv_envs.core import tessellation

    v, n, f = tessellation.capsule(0.05, 0.3, 9)
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><asset><mesh name="m" file="m.msh"/></asset>'
        '<worldbody><geom type="mesh" mesh="m"/></worldbody></mujoco>',
        {"m.msh": tessellation.msh_bytes(v, n, f)})
    assert model.mesh_facenum[0] == len(f)
    # MuJoCo recentres a mesh on its centroid; the capsule is symmetric about its own.
    np.testing.assert_allclose(model.mesh_vert.min(axis=0), v.min(axis=0), atol=1e-6)
    np.testing.assert_allclose(model.mesh_vert.max(axis=0), v.max(axis=0), atol=1e-6)


def test_a_posed_geom_is_placed_where_mujoco_puts_it():
    import mujoco

    from auv_envs.core import tessellation

    model = mujoco.MjModel.from_xml_string("""
    <mujoco><worldbody><body pos="1 2 3" euler="10 20 30">
      <geom type="capsule" fromto="0 0 0 0.3 -0.4 0.5" size="0.05"/>
      <geom type="box" size="0.1 0.2 0.3" pos="0.5 0 0" euler="0 40 0"/>
    </body></worldbody></mujoco>""")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    body = (data.xpos[1], data.xmat[1].reshape(3, 3))
    for geom in range(model.ngeom):
        v, _, _ = tessellation.static_mesh(model, data, [geom], 16, frame=body)
        world = v @ body[1].T + body[0]
        # Every vertex is on the surface of the geom as MuJoCo posed it.
        local = (world - data.geom_xpos[geom]) @ data.geom_xmat[geom].reshape(3, 3)
        size = model.geom_size[geom]
        if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_BOX:
            assert np.all(np.abs(local) <= size + 1e-12)
            assert np.all(np.isclose(np.abs(local), size).any(axis=1))
        else:
            axial = np.clip(local[:, 2], -size[1], size[1])
            radial = np.linalg.norm(local - np.stack([0 * axial, 0 * axial, axial], 1), axis=1)
            np.testing.assert_allclose(radial, size[0], rtol=1e-9)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_the_station_is_drawn_as_meshes_and_collides_as_primitives(env_id):
    import mujoco

    from auv_envs.tasks.docking.station import STATION_COLLISION_GROUP, VISUAL_GROUP

    env = make_env(env_id, "features")
    physics = env.unwrapped.physics
    model = physics.model
    meshes = np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_MESH)
    assert len(meshes) >= 1
    assert np.all(model.geom_group[meshes] == VISUAL_GROUP)
    assert np.all(model.geom_contype[meshes] == 0) and np.all(model.geom_conaffinity[meshes] == 0)
    primitives = np.flatnonzero(model.geom_group == STATION_COLLISION_GROUP)
    assert len(primitives) >= 8
    assert all(model.geom(g).name.startswith("station/") for g in primitives)
    # Lines of sight: blocked by the primitives, not by the meshes.
    assert physics.ray_groups[STATION_COLLISION_GROUP] == 1
    assert physics.ray_groups[VISUAL_GROUP] == 0
    data = physics.data
    mujoco.mj_forward(model, data)
    rail = primitives[np.argmax(model.geom_size[primitives, 1] * (
        model.geom_type[primitives] == mujoco.mjtGeom.mjGEOM_CAPSULE))]
    target = data.geom_xpos[rail]
    origin = target + np.array([0.0, 0.0, 3.0])
    assert physics.unoccluded(origin, [target + [0.0, 0.0, -0.5]], [True]) == [False]
    env.close()


def test_a_small_image_gets_a_coarser_mesh():
    import mujoco

    def mesh_vertices(**kwargs):
        # The finest drawing: the meshes geoms draw (the coarser levels are assets only).
        env = make_env(DOCKING_IDS[0], **kwargs)
        model = env.unwrapped.physics.model
        drawn = model.geom_dataid[model.geom_type == mujoco.mjtGeom.mjGEOM_MESH]
        count = int(model.mesh_vertnum[drawn].sum())
        env.close()
        return count, model

    small, _ = mesh_vertices(obs_mode="image", image_size=(84, 84))
    large, _ = mesh_vertices(obs_mode="image", image_size=(320, 240))
    default, model = mesh_vertices(obs_mode="features")
    assert small < large == default
    assert mujoco.mjtGeom.mjGEOM_MESH in model.geom_type


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_the_meshes_look_like_mujocos_own_primitives(env_id):
    # MuJoCo draws the primitives from its own unit shapes; drawn instead of the
    # meshes (groups swapped in a copy of the model, same slices), the images
    # of the vehicle's camera along the approach must be the same but for a few
    # outline pixels (python scripts/station_mesh_check.py, with the observation's
    # coarser levels where far: at most 15 of 76,800 at 320x240 over 75 poses).
    from scripts.station_mesh_check import compare

    size = (160, 120)
    rows = compare(env_id, size, poses=12)
    differing = [n / (size[0] * size[1]) for n, _ in rows]
    assert max(differing) < 0.002, differing
    assert np.mean(differing) < 0.0005
    assert sum(same for _, same in rows) >= 1  # most poses are the same to the bit
