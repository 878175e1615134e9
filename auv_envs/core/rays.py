"""Lines of sight through static MuJoCo primitives, in scalar arithmetic for every backend.

The ray-geom intersections of MuJoCo's ``mj_ray`` (``engine_ray.c``: the plane's front
face within its size, the sphere, the capsule with its bounding sphere, the box face by
face within its bounding sphere), restated as equations of :mod:`auv_envs.core.ops`, so a
compiled function (:class:`auv_envs.core.plant.CompiledFunction`) or JAX can evaluate
them without a call into MuJoCo. Only geoms that never move are taken (their poses are
read once), as a scene's static scenery; :func:`static_primitives` refuses the rest.
``tests/test_rays.py`` checks the first hits against ``mj_ray`` on random rays.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco

#: MuJoCo's ``mjMINVAL``: its tolerance for a zero denominator or discriminant.
MINVAL = 1e-15

#: A miss: every hit is smaller.
MISS = math.inf

_KINDS = {mujoco.mjtGeom.mjGEOM_PLANE: "plane", mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
          mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule", mujoco.mjtGeom.mjGEOM_BOX: "box"}


class Primitive(NamedTuple):
    """A static geom: its ``kind`` (``plane``, ``sphere``, ``capsule``, ``box``), world
    position, rotation (9 floats, row-major: MuJoCo's ``geom_xmat``) and ``size``."""

    kind: str
    pos: tuple[float, ...]
    mat: tuple[float, ...]
    size: tuple[float, ...]


def static_primitives(model: mujoco.MjModel, data: mujoco.MjData, groups,
                      exclude_body: int) -> tuple[Primitive, ...]:
    """The geoms ``mj_ray(model, data, ..., groups, flg_static=1, exclude_body, ...)``
    tests, at their poses in ``data`` (``mj_forward`` run).

    Raises:
        ValueError: one of them moves (its body is not welded to the world) or is not a
            plane, sphere, capsule or box.
    """
    out = []
    for g in range(model.ngeom):
        body, mat = model.geom_bodyid[g], model.geom_matid[g]
        alpha = model.mat_rgba[mat][3] if mat >= 0 else model.geom_rgba[g][3]
        group = min(mujoco.mjNGROUP - 1, max(0, int(model.geom_group[g])))
        if body == exclude_body or alpha == 0 or not groups[group]:
            continue  # what mj_ray leaves out
        name = model.geom(g).name or str(g)
        if model.body_weldid[body] != 0:
            raise ValueError(f"geom {name!r} moves: only static geoms can be compiled")
        kind = _KINDS.get(mujoco.mjtGeom(model.geom_type[g]))
        if kind is None:
            raise ValueError(f"geom {name!r} is a {mujoco.mjtGeom(model.geom_type[g]).name}: "
                             f"only {sorted(_KINDS.values())} are compiled")
        out.append(Primitive(kind, tuple(data.geom_xpos[g].tolist()),
                             tuple(data.geom_xmat[g].tolist()), tuple(model.geom_size[g].tolist())))
    return tuple(out)


def first_hit(primitives, point, vec, ops):
    """The smallest ``x >= 0`` at which ``point + x * vec`` meets one of ``primitives``
    (``mj_ray``'s distance, in units of ``vec``), :data:`MISS` where none is met.

    Args:
        primitives: :class:`Primitive` s (:func:`static_primitives`).
        point, vec: 3 scalars each, of ``ops``' backend.
        ops: a namespace of :mod:`auv_envs.core.ops`.
    """
    nearest = MISS
    for primitive in primitives:
        nearest = ops.minimum(nearest, _HITS[primitive.kind](primitive, point, vec, ops))
    return nearest


def _all(conditions, value, ops):
    """``value`` where every condition holds, :data:`MISS` elsewhere (nested ``where``:
    CasADi's comparisons do not combine with ``&``)."""
    for condition in reversed(conditions):
        value = ops.where(condition, value, MISS)
    return value


def _local(primitive: Primitive, point, vec):
    """``point - pos`` and ``vec`` in the geom's frame (``mat`` transposed)."""
    m = primitive.mat
    d = [point[k] - primitive.pos[k] for k in range(3)]
    lpnt = [m[k] * d[0] + m[3 + k] * d[1] + m[6 + k] * d[2] for k in range(3)]
    lvec = [m[k] * vec[0] + m[3 + k] * vec[1] + m[6 + k] * vec[2] for k in range(3)]
    return lpnt, lvec


def _roots(a, b, c, ops):
    """Both roots of ``a x^2 + 2 b x + c = 0`` (smaller first) and whether they are real
    (MuJoCo's discriminant test: ``b^2 - a c >= MINVAL``; where not, both are -1)."""
    det = b * b - a * c
    real = det >= MINVAL
    root = ops.sqrt(ops.where(real, det, 1.0))
    a = ops.where(real, a, 1.0)
    return ops.where(real, (-b - root) / a, -1.0), ops.where(real, (-b + root) / a, -1.0)


def _nearest_root(a, b, c, ops):
    """MuJoCo's ``ray_quad``: the smaller non-negative root, -1 where there is none."""
    low, high = _roots(a, b, c, ops)
    return ops.where(low >= 0.0, low, ops.where(high >= 0.0, high, -1.0))


def _sphere_about(centre, radius_sqr, point, vec, ops):
    """``ray_quad`` of the sphere of squared radius ``radius_sqr`` about ``centre``."""
    d = [point[k] - centre[k] for k in range(3)]
    a = vec[0] * vec[0] + vec[1] * vec[1] + vec[2] * vec[2]
    b = vec[0] * d[0] + vec[1] * d[1] + vec[2] * d[2]
    c = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - radius_sqr
    return _nearest_root(a, b, c, ops)


def _plane(primitive: Primitive, point, vec, ops):
    lpnt, lvec = _local(primitive, point, vec)
    toward = lvec[2] <= -MINVAL  # from the front face's side only
    x = -lpnt[2] / ops.where(toward, lvec[2], -1.0)
    conditions = [toward, x >= 0.0]
    for k in range(2):
        if primitive.size[k] > 0:  # an infinite plane where the size is not positive
            conditions.append(abs(lpnt[k] + x * lvec[k]) <= primitive.size[k])
    return _all(conditions, x, ops)


def _sphere(primitive: Primitive, point, vec, ops):
    x = _sphere_about(primitive.pos, primitive.size[0] ** 2, point, vec, ops)
    return _all([x >= 0.0], x, ops)


def _capsule(primitive: Primitive, point, vec, ops):
    radius, half = primitive.size[0], primitive.size[1]
    bound = _sphere_about(primitive.pos, (radius + half) ** 2, point, vec, ops)
    lpnt, lvec = _local(primitive, point, vec)
    # The round side, between the flat ends: its nearest root only (as MuJoCo).
    side = _nearest_root(lvec[0] * lvec[0] + lvec[1] * lvec[1],
                         lvec[0] * lpnt[0] + lvec[1] * lpnt[1],
                         lpnt[0] * lpnt[0] + lpnt[1] * lpnt[1] - radius * radius, ops)
    x = _all([side >= 0.0, abs(lpnt[2] + side * lvec[2]) <= half], side, ops)
    a = lvec[0] * lvec[0] + lvec[1] * lvec[1] + lvec[2] * lvec[2]
    for end in (1.0, -1.0):  # the end caps: each root on its own half-sphere
        dz = lpnt[2] - end * half
        roots = _roots(a, lvec[0] * lpnt[0] + lvec[1] * lpnt[1] + lvec[2] * dz,
                       lpnt[0] * lpnt[0] + lpnt[1] * lpnt[1] + dz * dz - radius * radius,
                       ops)
        for root in roots:
            z = lpnt[2] + root * lvec[2]
            beyond = z >= half if end > 0 else z <= -half
            x = ops.minimum(x, _all([root >= 0.0, beyond], root, ops))
    return _all([bound >= 0.0], x, ops)


def _box(primitive: Primitive, point, vec, ops):
    size = primitive.size
    bound = _sphere_about(primitive.pos, size[0] ** 2 + size[1] ** 2 + size[2] ** 2,
                          point, vec, ops)
    lpnt, lvec = _local(primitive, point, vec)
    x = MISS
    for i, (j, k) in enumerate(((1, 2), (0, 2), (0, 1))):
        moving = abs(lvec[i]) > MINVAL
        den = ops.where(moving, lvec[i], 1.0)
        for side in (-1.0, 1.0):
            sol = (side * size[i] - lpnt[i]) / den
            on_face = [moving, sol >= 0.0, abs(lpnt[j] + sol * lvec[j]) <= size[j],
                       abs(lpnt[k] + sol * lvec[k]) <= size[k]]
            x = ops.minimum(x, _all(on_face, sol, ops))
    return _all([bound >= 0.0], x, ops)


_HITS = {"plane": _plane, "sphere": _sphere, "capsule": _capsule, "box": _box}
