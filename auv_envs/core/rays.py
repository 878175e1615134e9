"""Lines of sight through static MuJoCo primitives, in scalar arithmetic for every backend.

Whether a segment is hidden by the scene's static geoms, as MuJoCo's ``mj_ray`` would
say (``engine_ray.c``: what it tests, the plane's front face within its size, spheres,
capsules and boxes), written as equations of :mod:`auv_envs.core.ops`, so a compiled
function (:class:`auv_envs.core.plant.CompiledFunction`) or JAX evaluates it without a
call into MuJoCo. Only geoms that never move are taken (their poses are read once);
:func:`static_primitives` refuses the rest. ``tests/test_rays.py`` checks the verdicts
against ``mj_ray`` on random segments.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco

from auv_envs.core import frames

#: MuJoCo's ``mjMINVAL``: its tolerance for a zero denominator or discriminant.
MINVAL = mujoco.mjMINVAL

_KINDS = {mujoco.mjtGeom.mjGEOM_PLANE: "plane", mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
          mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule", mujoco.mjtGeom.mjGEOM_BOX: "box"}


class Primitive(NamedTuple):
    """A static geom: its ``kind`` (``plane``, ``sphere``, ``capsule``, ``box``), world
    position, ``rows`` taking a world offset into its frame (three rows: the transpose
    of MuJoCo's ``geom_xmat``, for :func:`auv_envs.core.frames.rotate_rows`) and
    ``size``."""

    kind: str
    pos: tuple[float, ...]
    rows: tuple[tuple[float, ...], ...]
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
        rows = tuple(tuple(row) for row in data.geom_xmat[g].reshape(3, 3).T.tolist())
        out.append(Primitive(kind, tuple(data.geom_xpos[g].tolist()), rows,
                             tuple(model.geom_size[g].tolist())))
    return tuple(out)


#: Where a segment ends, as a share of it: ``mj_ray``'s hits at ``x >= END`` of the way
#: to a target (on it, within round-off) do not hide it.
END = 1.0 - 1e-6


def blocked(primitives, point, target, ops):
    """Whether one of ``primitives`` meets the segment from ``point`` to ``target`` (3
    scalars each; ``target`` may be a batch of arrays on JAX) before :data:`END` of the
    way: ``0 <= mj_ray(point, target - point) < END``.

    Each primitive's test is a margin, non-negative where it hides the target, and
    the margins combine by their maximum: one comparison at the end, no branches (as
    compiled code and JAX evaluate every branch anyway). A solid (box, capsule, sphere)
    hides it where the segment meets the solid and does not lie wholly inside it (from
    inside, ``mj_ray`` meets the surface on the way out only): the slab test's entry and
    exit within ``[0, END]`` for a box, the segment's squared distance from the axis or
    centre against the squared radius for a capsule or sphere. A plane hides it where
    the segment crosses its front face within its size. They agree with ``mj_ray`` but
    on a boundary (a graze, a hit exactly at ``END``), ``tests/test_rays.py``.
    """
    margin = -1.0
    for primitive in primitives:
        lpnt = _local(primitive, point)
        ltarget = _local(primitive, target)
        lvec = [(ltarget[k] - lpnt[k]) * END for k in range(3)]  # the segment to END
        meets = _MARGINS[primitive.kind](primitive, lpnt, lvec, ops)
        if primitive.kind != "plane":
            inside = _INSIDE[primitive.kind]
            lend = [lpnt[k] + lvec[k] for k in range(3)]
            meets = ops.minimum(meets, -ops.minimum(inside(primitive, lpnt, ops),
                                                    inside(primitive, lend, ops)))
        margin = ops.maximum(margin, meets)
    return margin >= 0.0


def _local(primitive: Primitive, point) -> tuple:
    """``point`` in the geom's frame."""
    return frames.rotate_rows(primitive.rows, [point[k] - primitive.pos[k] for k in range(3)])


def _nonzero(x, ops):
    """``x``, or :data:`MINVAL` where ``|x| <= MINVAL`` (a safe denominator)."""
    return ops.where(abs(x) > MINVAL, x, MINVAL)


def _plane(primitive: Primitive, p, d, ops):
    toward = d[2] <= -MINVAL  # from the front face's side only, as mj_ray
    x = -p[2] / ops.where(toward, d[2], -1.0)  # in units of the segment (to END)
    margin = ops.minimum(x, 1.0 - x)
    for k in range(2):
        if primitive.size[k] > 0:  # infinite where the size is not positive
            margin = ops.minimum(margin, primitive.size[k] - abs(p[k] + x * d[k]))
    return ops.where(toward, margin, -1.0)


def _sphere(primitive: Primitive, p, d, ops):
    t = ops.clip(-(p[0] * d[0] + p[1] * d[1] + p[2] * d[2])
                 / _nonzero(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], ops), 0.0, 1.0)
    x, y, z = p[0] + t * d[0], p[1] + t * d[1], p[2] + t * d[2]
    return primitive.size[0] ** 2 - (x * x + y * y + z * z)


def _capsule(primitive: Primitive, p, d, ops):
    """The closest points of the segment ``p + s d`` (s in [0, 1]) and the axis from
    ``(0, 0, -half)`` to ``(0, 0, half)``: Ericson, *Real-Time Collision Detection*
    (2005), 5.1.9, with the axis's terms written out."""
    radius, half = primitive.size[0], primitive.size[1]
    rz = p[2] + half  # p minus the axis's start
    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    e = 4.0 * half * half
    b = 2.0 * half * d[2]
    c = d[0] * p[0] + d[1] * p[1] + d[2] * rz
    f = 2.0 * half * rz
    denom = a * e - b * b
    s = ops.where(denom > MINVAL * a * e, ops.clip((b * f - c * e) / _nonzero(denom, ops),
                                                   0.0, 1.0), 0.0)
    t_free = (b * s + f) / e
    inv_a = 1.0 / _nonzero(a, ops)
    s = ops.where(t_free < 0.0, ops.clip(-c * inv_a, 0.0, 1.0),
                  ops.where(t_free > 1.0, ops.clip((b - c) * inv_a, 0.0, 1.0), s))
    t = ops.clip(t_free, 0.0, 1.0)
    x, y = p[0] + s * d[0], p[1] + s * d[1]
    z = p[2] + s * d[2] - (2.0 * t - 1.0) * half
    return radius * radius - (x * x + y * y + z * z)


def _box(primitive: Primitive, p, d, ops):
    near, far = 0.0, 1.0
    for k in range(3):
        inv = 1.0 / _nonzero(d[k], ops)
        low, high = (-primitive.size[k] - p[k]) * inv, (primitive.size[k] - p[k]) * inv
        near = ops.maximum(near, ops.minimum(low, high))
        far = ops.minimum(far, ops.maximum(low, high))
    return far - near


def _inside_sphere(primitive: Primitive, p, ops):
    return primitive.size[0] ** 2 - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2])


def _inside_capsule(primitive: Primitive, p, ops):
    radius, half = primitive.size[0], primitive.size[1]
    dz = p[2] - ops.clip(p[2], -half, half)
    return radius * radius - (p[0] * p[0] + p[1] * p[1] + dz * dz)


def _inside_box(primitive: Primitive, p, ops):
    size = primitive.size
    return ops.minimum(ops.minimum(size[0] - abs(p[0]), size[1] - abs(p[1])),
                       size[2] - abs(p[2]))


#: Per solid: a margin non-negative where a point (in the geom's frame) is inside it.
_INSIDE = {"sphere": _inside_sphere, "capsule": _inside_capsule, "box": _inside_box}
#: Per kind: a margin non-negative where the segment ``p + s d``, s in [0, 1], meets it.
_MARGINS = {"plane": _plane, "sphere": _sphere, "capsule": _capsule, "box": _box}
