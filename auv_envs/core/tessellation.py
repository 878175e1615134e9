"""Static scenery drawn as one triangle mesh: fewer triangles, one draw.

MuJoCo's renderer draws each primitive geom from a shared unit shape built at
the model's ``visual/quality``: a capsule is an open cylinder of ``numslices``
sides and ``numstacks`` rings along its length, plus two hemispheres of
``numstacks / 2`` rings. The rings along a straight cylinder change no
outline, and under directional lights no shading either, yet under software GL
(Mesa llvmpipe) a small frame's time is mostly these vertices, and each geom
is a draw of its own. A static body's primitives are therefore drawn as one
mesh tessellated here from the same shapes: a box as its 12 triangles, a
straight part as one band of quads, round parts (caps, spheres) with enough
rings that their outlines are as close to a circle as the slices make them.

``slices`` comes from :func:`auv_envs.core.rendering.outline_slices`: the
polygon of a round part has ``slices`` sides around its axis, and its
meridian (the outline seen side-on) ``4 * cap_stacks(slices)`` sides, at
least as many.

The mesh is visual only; the primitives it replaces keep colliding and
blocking rays (``auv_envs.tasks.docking.station``).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

#: Round geom types: drawn as polygons of ``slices`` sides about an axis, radius ``size[0]``.
ROUND = {
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
}
#: Geom types this module tessellates.
SUPPORTED = {int(mujoco.mjtGeom.mjGEOM_BOX): "box", **ROUND}


def cap_stacks(slices: int) -> int:
    """Rings of a hemisphere whose side-on outline has at least ``slices`` sides."""
    if slices < 3:
        raise ValueError(f"slices must be >= 3, got {slices}")
    return math.ceil(slices / 4)


def box(size) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box of half-sizes ``size``: 24 vertices (4 per face, with the face's normal), 12 faces."""
    half = np.asarray(size, dtype=float)
    if half.shape != (3,) or np.any(half <= 0):
        raise ValueError(f"box half-sizes must be 3 positive numbers, got {size}")
    vertices, normals, faces = [], [], []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        for sign in (-1.0, 1.0):
            base = len(vertices)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                point = np.zeros(3)
                point[axis], point[u], point[v] = sign * half[axis], a * half[u], b * half[v]
                vertices.append(point)
                normals.append(np.eye(3)[axis] * sign)
            # (u, v, axis) is right-handed: counter-clockwise seen from +axis.
            quad = ((0, 1, 2), (0, 2, 3)) if sign > 0 else ((0, 2, 1), (0, 3, 2))
            faces += [[base + i for i in tri] for tri in quad]
    return np.array(vertices), np.array(normals), np.array(faces, dtype=np.int32)


def _rings(radius: float, rings: list[tuple[float, float]], slices: int,
           close_bottom: bool, close_top: bool):
    """A surface of revolution about z from rings ``(z, elevation)`` of ``slices`` vertices.

    A vertex at azimuth ``a`` on ring ``(z, e)`` sits at ``radius n + (0, 0, z)``
    with normal ``n = (cos e cos a, cos e sin a, sin e)``; consecutive rings are joined by
    quads, and a closed end by a fan to the pole ``radius`` beyond its ring's ``z``.
    """
    vertices, normals = [], []
    azimuth = 2.0 * np.pi * np.arange(slices) / slices
    for z, elevation in rings:
        normal = np.stack([np.cos(elevation) * np.cos(azimuth),
                           np.cos(elevation) * np.sin(azimuth),
                           np.full(slices, np.sin(elevation))], axis=1)
        point = radius * normal
        point[:, 2] = z + radius * np.sin(elevation)
        vertices.append(point)
        normals.append(normal)
    vertices, normals = np.concatenate(vertices), np.concatenate(normals)
    faces = []
    nxt = (np.arange(slices) + 1) % slices
    for ring in range(len(rings) - 1):
        a = ring * slices + np.arange(slices)
        b = ring * slices + nxt
        c, d = a + slices, b + slices
        faces += [np.stack([a, b, d], axis=1), np.stack([a, d, c], axis=1)]
    extra_v, extra_n = [], []
    for closed, ring, sign in ((close_bottom, 0, -1.0), (close_top, len(rings) - 1, 1.0)):
        if not closed:
            continue
        z = rings[ring][0]
        pole = len(vertices) + len(extra_v)
        extra_v.append([0.0, 0.0, z + radius * sign])
        extra_n.append([0.0, 0.0, sign])
        a = ring * slices + np.arange(slices)
        b = ring * slices + nxt
        tri = np.stack([b, a, np.full(slices, pole)], axis=1) if sign < 0 else \
            np.stack([a, b, np.full(slices, pole)], axis=1)
        faces.append(tri)
    if extra_v:
        vertices = np.concatenate([vertices, np.array(extra_v)])
        normals = np.concatenate([normals, np.array(extra_n)])
    return vertices, normals, np.concatenate(faces).astype(np.int32)


def capsule(radius: float, half_length: float, slices: int):
    """A capsule along z: radius ``radius``, straight from ``-half_length`` to ``+half_length``."""
    _check_round(radius, slices)
    k = cap_stacks(slices)
    # Elevations from the bottom pole's first ring up to the top pole's last ring;
    # the two equators are joined by the cylinder's single band of quads.
    rings = [(-half_length, -0.5 * np.pi * i / k) for i in range(k - 1, -1, -1)]
    rings += [(half_length, 0.5 * np.pi * i / k) for i in range(k)]
    return _rings(radius, rings, slices, close_bottom=True, close_top=True)


def sphere(radius: float, slices: int):
    """A sphere about the origin."""
    return capsule(radius, 0.0, slices)


def cylinder(radius: float, half_length: float, slices: int):
    """A closed cylinder along z: one band of quads and two flat discs (each its own normals)."""
    _check_round(radius, slices)
    side = _rings(radius, [(-half_length, 0.0), (half_length, 0.0)], slices, False, False)
    parts = [side]
    for z, sign in ((-half_length, -1.0), (half_length, 1.0)):
        azimuth = 2.0 * np.pi * np.arange(slices) / slices
        rim = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth),
                        np.full(slices, z)], axis=1)
        vertices = np.concatenate([rim, [[0.0, 0.0, z]]])
        normals = np.tile([0.0, 0.0, sign], (slices + 1, 1))
        a = np.arange(slices)
        b = (a + 1) % slices
        pole = np.full(slices, slices)
        faces = np.stack([a, b, pole], axis=1) if sign > 0 else np.stack([b, a, pole], axis=1)
        parts.append((vertices, normals, faces.astype(np.int32)))
    return merge(parts)


def _check_round(radius: float, slices: int) -> None:
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    if slices < 3:
        raise ValueError(f"slices must be >= 3, got {slices}")


def merge(parts):
    """One mesh from several ``(vertices, normals, faces)``: faces re-indexed."""
    vertices, normals, faces, offset = [], [], [], 0
    for v, n, f in parts:
        vertices.append(v)
        normals.append(n)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(normals), np.concatenate(faces)


def msh_bytes(vertices, normals, faces) -> bytes:
    """The mesh in MuJoCo's binary ``.msh`` format (a mesh asset's file contents).

    Four int32 counts (vertices, normals, texture coordinates, faces), then
    the float32 vertices and normals and the int32 faces.
    """
    vertices = np.asarray(vertices, np.float32)
    normals = np.asarray(normals, np.float32)
    faces = np.asarray(faces, np.int32)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or normals.shape != vertices.shape:
        raise ValueError("need (n, 3) vertices and as many (n, 3) normals")
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError("faces must be (m, 3) indices of the vertices")
    header = np.array([len(vertices), len(normals), 0, len(faces)], np.int32)
    return header.tobytes() + vertices.tobytes() + normals.tobytes() + faces.tobytes()


def geom_mesh(model: mujoco.MjModel, geom: int, slices: int):
    """Geom ``geom`` of ``model`` in its own frame, tessellated (see the module doc)."""
    kind = SUPPORTED.get(int(model.geom_type[geom]))
    size = model.geom_size[geom]
    if kind == "box":
        return box(size)
    if kind == "capsule":
        return capsule(size[0], size[1], slices)
    if kind == "cylinder":
        return cylinder(size[0], size[1], slices)
    if kind == "sphere":
        return sphere(size[0], slices)
    raise ValueError(f"geom {model.geom(geom).name!r}: type {int(model.geom_type[geom])} "
                     f"is not tessellated here (only {sorted(SUPPORTED.values())})")


def static_mesh(model: mujoco.MjModel, data: mujoco.MjData, geoms, slices: int, frame=None):
    """The geoms ``geoms`` as one mesh, in ``frame = (position, rotation)`` (world if None).

    ``data`` must hold the geoms' poses (after ``mj_kinematics``). Returns
    ``(vertices (n, 3), normals (n, 3), faces (m, 3) int32)``, faces
    counter-clockwise seen from outside.
    """
    if len(geoms) == 0:
        raise ValueError("no geoms to tessellate")
    origin, rotation = ((np.zeros(3), np.eye(3)) if frame is None
                        else (np.asarray(frame[0], float), np.asarray(frame[1], float)))
    parts = []
    for geom in geoms:
        v, n, f = geom_mesh(model, geom, slices)
        rot = data.geom_xmat[geom].reshape(3, 3)
        world = v @ rot.T + data.geom_xpos[geom]
        parts.append(((world - origin) @ rotation, n @ rot.T @ rotation, f))
    return merge(parts)
