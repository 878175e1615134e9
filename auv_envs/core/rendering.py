"""Headless rendering that closes cleanly.

``MUJOCO_GL`` must be chosen before :mod:`mujoco` is imported; ``auv_envs``
sets ``egl`` as the default on Linux without a display (see
``auv_envs/__init__.py``).

Two pitfalls shape this module:

* Renderers left open print EGL tracebacks when the interpreter tears down,
  so every renderer made here is registered and closed by an ``atexit`` hook.
  The hook is registered *after* the first GL context exists: ``atexit`` runs
  hooks last-in first-out, so ours runs before the hook with which MuJoCo's EGL
  backend terminates its display.
* ``mjr_freeContext`` deletes GL objects by id in whatever context is
  current. Closing one renderer while another's context was current deleted
  the other's framebuffers (it then drew garbage or black). Closing here makes
  the renderer's own context current first, and each render makes its context
  current and re-binds the offscreen framebuffer before drawing.

And one rule makes renderers usable from any thread: a GL context is current
in one thread at a time (EGL refuses it in another, ``EGL_BAD_ACCESS``), so a
renderer releases its context after every frame (:func:`_release`). An env
renders from whichever thread steps it, and still renders after a thread that
used it has ended.
"""

from __future__ import annotations

import atexit
import dataclasses
import math
import weakref

import mujoco
import numpy as np

from auv_envs.core.tessellation import ROUND

_LIVE: weakref.WeakSet = weakref.WeakSet()
_HOOKED = False


class CameraRenderer:
    """Renders named cameras of one model side by side into a fresh ``uint8`` array.

    With one camera this is a monocular renderer; with two (left, right) it
    draws both views into one offscreen buffer and reads them back with one
    ``mjr_readPixels`` call, faster than two renderer passes (``benchmarks/lars_speed.py``
    times stereo against mono).
    :meth:`render_with_range` also reads the depth buffer, as each pixel's range.
    """

    def __init__(self, model: mujoco.MjModel, cameras: tuple[str, ...], width: int, height: int,
                 headlight: tuple[float, float] | None = None, fog: bool = False,
                 skybox: bool = False, hidden_groups: tuple[int, ...] = (),
                 fit_outlines: bool = False, detail: tuple[DetailLevels, ...] = ()):
        """Args:
            model: the compiled model (its ``vis`` offscreen size grows if needed;
                this renderer's own buffer is exactly its images' size).
            cameras: names of the model's cameras, drawn left to right.
            width, height: size of each camera's image, pixels.
            headlight: ``(ambient, diffuse)`` grey levels of the headlight for
                this renderer only (e.g. a brighter view for a person than the
                vehicle's camera gets); None keeps the model's headlight. The
                model is not changed, so other renderers see the same scene.
            fog: draw the model's fog (``visual/map`` fogstart/fogend times the
                model's extent, ``visual/rgba`` fog colour): objects fade into
                the water's colour with distance, as in turbid water.
            skybox: draw the model's skybox texture (where no geom is).
                Fog and skybox belong to views for people; the cameras of
                observations draw neither.
            hidden_groups: geom groups this renderer does not draw (e.g. a
                vehicle's own hull, which its camera cannot see: under
                software GL drawing it cost 0.25 ms of a 0.89 ms 84x84 frame,
                and it changes no pixel).
            fit_outlines: draw round geoms (spheres, capsules, cylinders,
                ellipsoids) as polygons of :func:`outline_slices` sides, fewer
                for small images than the model's ``visual/quality`` asks:
                their outlines stay within half a pixel, but the shading of a
                large curved surface changes (at 160x120 a LARS stereo pair
                differed on up to a fifth of its pixels), so a task turns it on
                where it measured the images (the docking camera).
            detail: geoms drawn, frame by frame, with the coarsest of their
                :class:`DetailLevels` that keeps every outline within
                :data:`DETAIL_TOLERANCE_PX` at its distance from the camera (a
                geom close enough to need more sides is drawn as the model and
                ``fit_outlines`` draw it).
        """
        global _HOOKED
        if not cameras:
            raise ValueError("need at least one camera")
        for group in hidden_groups:
            if not 0 <= group < mujoco.mjNGROUP:
                raise ValueError(f"hidden_groups: {group} is not a geom group "
                                 f"(0-{mujoco.mjNGROUP - 1})")
        self._model = model
        self._width, self._height = int(width), int(height)
        self._cams = []
        for name in cameras:
            cam = mujoco.MjvCamera()
            cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            cam.fixedcamid = model.camera(name).id
            self._cams.append(cam)
        # Checked before any GL object exists.
        self._detail = _DetailChooser(model, detail, [cam.fixedcamid for cam in self._cams],
                                      self._width, self._height) if detail else None
        total_width = self._width * len(cameras)
        # The offscreen framebuffer is made at the model's offwidth x offheight when the
        # context is: sized to this renderer's images, a small image costs a small
        # buffer to clear, draw and read (at the model's 1280x960 an 84x84 frame cost
        # nearly what a 320x240 one did). The model keeps the larger of the two sizes,
        # for renderers made from it elsewhere (mujoco.Renderer checks it).
        # The round geoms' polygons are built into the context too, at the
        # model's quality; both are restored once the context exists.
        offscreen, quality = model.vis.global_, model.vis.quality
        model_size = (offscreen.offwidth, offscreen.offheight)
        model_quality = (quality.numslices, quality.numstacks)
        offscreen.offwidth, offscreen.offheight = total_width, self._height
        if fit_outlines:
            quality.numslices = outline_slices(self._height, model_quality[0])
            quality.numstacks = max(2, round(model_quality[1] * quality.numslices
                                             / model_quality[0]))
        try:
            self._gl = mujoco.GLContext(total_width, self._height)
            self._gl.make_current()
            try:
                self._ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
            finally:
                _release(self._gl)
        finally:
            offscreen.offwidth = max(model_size[0], total_width)
            offscreen.offheight = max(model_size[1], self._height)
            quality.numslices, quality.numstacks = model_quality
        self._scene = mujoco.MjvScene(model, maxgeom=1000)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_FOG] = fog
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = skybox
        self._option = mujoco.MjvOption()
        #: The geom groups this renderer leaves out (``hidden_groups``).
        self.hidden_groups = tuple(sorted(set(hidden_groups)))
        for group in self.hidden_groups:
            self._option.geomgroup[group] = 0
        self._perturb = mujoco.MjvPerturb()
        self._buffer = np.empty((self._height, total_width, 3), dtype=np.uint8)
        # Made on the first render_with_range: the depth buffer and each pixel's ray length.
        self._depth: np.ndarray | None = None
        self._ray_length: np.ndarray | None = None
        self._viewports = [
            mujoco.MjrRect(k * self._width, 0, self._width, self._height)
            for k in range(len(cameras))
        ]
        self._full = mujoco.MjrRect(0, 0, total_width, self._height)
        if headlight is not None and not model.vis.headlight.active:
            raise ValueError("headlight given, but the model's headlight is off")
        self._headlight = headlight
        _LIVE.add(self)
        if not _HOOKED:
            atexit.register(_close_all)
            _HOOKED = True

    @property
    def closed(self) -> bool:
        return self._gl is None

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """RGB image ``(H, W * n_cameras, 3)`` for the (forward-computed) state in ``data``."""
        if self._gl is None:
            raise RuntimeError("renderer is closed")
        self._draw(data)
        return np.flipud(self._buffer).copy()

    def render_with_range(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """The RGB image of :meth:`render` and each pixel's range, from one draw.

        The range is the distance (m) from the camera centre to the surface
        seen through the pixel's centre, along that pixel's ray; ``inf``
        where the ray meets no geometry. It is read from the depth buffer,
        whose value ``b`` maps to the depth ``z`` along the optical axis
        through the standard OpenGL perspective projection with MuJoCo's
        clipping planes (``near, far = model.vis.map.znear, zfar`` times
        ``model.stat.extent``, as in :class:`mujoco.Renderer` with its
        default depth mapping): ``z = near / (1 - b (1 - near / far))``. A
        pixel ``(u, v)`` (centre ``u + 0.5``, ``v + 0.5``; principal point
        at the image centre, focal length ``f = H / (2 tan(fovy / 2))``)
        sees along the ray ``((u + 0.5 - W/2) / f, (v + 0.5 - H/2) / f, 1)``,
        so its range is ``z`` times that ray's length.

        Returns:
            ``(rgb (H, W * n_cameras, 3) uint8, range (H, W * n_cameras) float32)``.
        """
        if self._gl is None:
            raise RuntimeError("renderer is closed")
        if self._depth is None:
            self._depth = np.empty(self._buffer.shape[:2], dtype=np.float32)
            self._ray_length = self._ray_lengths()
        self._draw(data, self._depth)
        model = self._model
        near = model.vis.map.znear * model.stat.extent
        far = model.vis.map.zfar * model.stat.extent
        depth = np.flipud(self._depth).astype(np.float64)
        z = near / (1.0 - depth * (1.0 - near / far))
        # The cleared buffer (1, the far plane) is where no geometry was drawn.
        z[depth >= 1.0] = np.inf
        return np.flipud(self._buffer).copy(), (z * self._ray_length).astype(np.float32)

    def render_geom_ids(self, data: mujoco.MjData) -> np.ndarray:
        """Which geom each pixel sees, ``(H, W * n_cameras)`` int32 geom ids, -1 where none.

        A segmentation draw of the same scene (MuJoCo's ``mjRND_SEGMENT`` with
        ``mjRND_IDCOLOR``: each drawn geom coloured by its index in the scene
        plus one), decoded through the scene's geoms. Ground truth for image
        labels (which part of an object shows); nothing an observation uses.
        """
        if self._gl is None:
            raise RuntimeError("renderer is closed")
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        try:
            self._draw(data)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
        rgb = np.flipud(self._buffer).astype(np.int32)
        index = rgb[..., 0] + 256 * rgb[..., 1] + 65536 * rgb[..., 2] - 1
        scene = self._scene
        lookup = np.full(scene.ngeom + 1, -1, dtype=np.int32)  # the last entry: index -1
        for k in range(scene.ngeom):
            geom = scene.geoms[k]
            if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[k] = geom.objid
        index[(index < 0) | (index >= scene.ngeom)] = -1
        return lookup[index]

    def _ray_lengths(self) -> np.ndarray:
        """Per pixel, the length of its ray ``(x, y, 1)`` in camera coordinates (>= 1)."""
        lengths = []
        for cam in self._cams:
            fovy = np.radians(self._model.cam_fovy[cam.fixedcamid])
            focal = 0.5 * self._height / np.tan(fovy / 2.0)
            x = (np.arange(self._width) + 0.5 - self._width / 2.0) / focal
            y = (np.arange(self._height) + 0.5 - self._height / 2.0) / focal
            lengths.append(np.sqrt(1.0 + x[None, :] ** 2 + y[:, None] ** 2))
        return np.hstack(lengths)

    def _draw(self, data: mujoco.MjData, depth: np.ndarray | None = None) -> None:
        self._gl.make_current()
        try:
            self._draw_current(data, depth)
        finally:
            _release(self._gl)

    def _draw_current(self, data: mujoco.MjData, depth: np.ndarray | None) -> None:
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        for cam, viewport in zip(self._cams, self._viewports, strict=True):
            mujoco.mjv_updateScene(
                self._model, data, self._option, self._perturb, cam,
                mujoco.mjtCatBit.mjCAT_ALL, self._scene,
            )
            if self._headlight is not None:
                # mjv_updateScene makes the headlight the scene's first light.
                light = self._scene.lights[0]
                light.ambient[:] = self._headlight[0]
                light.diffuse[:] = self._headlight[1]
            if self._detail is not None:
                self._detail.apply(data, cam.fixedcamid, self._scene)
            mujoco.mjr_render(viewport, self._scene, self._ctx)
        mujoco.mjr_readPixels(self._buffer, depth, self._full, self._ctx)

    def close(self) -> None:
        if self._gl is not None:
            # GL objects are freed in the *current* context: make ours current
            # first, or freeing would delete another renderer's buffers.
            self._gl.make_current()
            self._ctx.free()
            self._gl.free()  # releases the context too
            self._gl = None
            self._ctx = None


    def __del__(self):
        # Dropped without close(): free GL objects in our own context.
        try:
            self.close()
        except Exception:  # interpreter shutdown: GL may already be gone
            pass


def outline_slices(height: int, model_slices: int) -> int:
    """Sides of the polygon a round geom is drawn with in an image ``height`` rows high.

    A circle of radius ``R`` pixels drawn as a regular ``n``-gon strays at
    most ``R (1 - cos(pi / n)) ~ R pi^2 / (2 n^2)`` pixels from its outline.
    For a round geom spanning up to two thirds of the image height
    (``R = height / 3``) to stay within half a pixel of its outline,
    ``n >= pi sqrt(height / 3)``: 17 sides at 84 rows, 28 (MuJoCo's default,
    which the model's ``numslices`` caps this at) from 222 rows on, so images
    of 240 rows and more are drawn as before. Under software GL a small
    frame's time is mostly these polygons' vertices (at 84x84, 28 sides cost
    about twice the time of 17; ``docs/speed.md``).
    """
    return int(min(model_slices, max(8, math.ceil(math.pi * math.sqrt(height / 3.0)))))


#: Sides of the coarser meshes a task may add for :class:`DetailLevels` (those
#: below the sides an image's finest drawing uses, :func:`detail_slices`).
DETAIL_SLICES = (6, 8, 12, 17)


#: How far (pixels) a :class:`DetailLevels` mesh's outline may stray from a circle.
#: Pixels whose centres lie that close to an outline can turn: along the docking
#: approach (``scripts/station_mesh_check.py``, 75 poses) 0.5 px turned up to 35 of
#: 7,056 pixels at 84x84 (mean 10.5 a frame), 0.1 px up to 9 (mean 1.2), where the
#: finest drawings alone turned up to 2.
DETAIL_TOLERANCE_PX = 0.1


def detail_slices(finest: int) -> tuple[int, ...]:
    """The :data:`DETAIL_SLICES` below ``finest``: the coarser levels worth building."""
    return tuple(n for n in DETAIL_SLICES if n < finest)


@dataclasses.dataclass(frozen=True)
class DetailLevels:
    """Coarser stand-ins for one drawn geom, chosen frame by frame by apparent size.

    Under software GL a small image's frame time is mostly vertices
    (``docs/speed.md``): a round part a few pixels across drawn with the
    sides an image-filling one needs costs many times what its outline needs.

    Attributes:
        geom: the drawn geom (a sphere, drawn at the context's slices, or a mesh).
        meshes: ids of meshes of the model drawing the same shape, in the same
            geom frame as ``geom`` would place them, with fewer sides; coarsest first.
        slices: the polygon sides of each of those meshes' round parts, increasing.
        parts: the round primitives (sphere, capsule and cylinder geoms) whose
            outlines ``geom`` draws; their radius and axis decide the level.
    """

    geom: int
    meshes: tuple[int, ...]
    slices: tuple[int, ...]
    parts: tuple[int, ...]

    def __post_init__(self):
        if not self.meshes or len(self.meshes) != len(self.slices):
            raise ValueError("DetailLevels: need one slices count per mesh, at least one mesh")
        if any(b <= a for a, b in zip(self.slices, self.slices[1:], strict=False)) \
                or self.slices[0] < 3:
            raise ValueError(f"DetailLevels: slices must increase from >= 3, got {self.slices}")
        if not self.parts:
            raise ValueError("DetailLevels: need the round parts the geom draws")


class _DetailChooser:
    """Per frame, swaps each :class:`DetailLevels` geom in the scene for its coarsest
    mesh that keeps the outlines of its parts within :data:`DETAIL_TOLERANCE_PX`.

    A part of radius ``r`` whose axis passes ``d`` from the camera spans at
    most ``R = s r / sqrt(d^2 - r^2)`` pixels, where ``s`` is the focal length
    in pixels times ``1 + tan^2`` of the angle to the image's corner (where the
    perspective stretches a small circle most). A polygon of ``n`` sides keeps
    that outline within ``t`` pixels while ``R (1 - cos(pi / n)) <= t``, so each
    level holds from a squared distance ``r^2 + (s r / R_n)^2`` on; the
    thresholds are computed once, and a frame costs one distance per part.
    """

    def __init__(self, model: mujoco.MjModel, levels, camera_ids, width: int, height: int):
        self._levels = tuple(levels)
        parts, starts = [], []
        for level in self._levels:
            if not 0 <= level.geom < model.ngeom:
                raise ValueError(f"DetailLevels: geom {level.geom} is not in the model")
            for mesh in level.meshes:
                if not 0 <= mesh < model.nmesh:
                    raise ValueError(f"DetailLevels: mesh {mesh} is not in the model")
            starts.append(len(parts))
            for part in level.parts:
                if not 0 <= part < model.ngeom:
                    raise ValueError(f"DetailLevels: part {part} is not a geom of the model")
                if int(model.geom_type[part]) not in ROUND:
                    raise ValueError(f"DetailLevels: part {model.geom(part).name!r} is not "
                                     f"round (one of {sorted(ROUND.values())})")
                parts.append(part)
        self._parts = np.array(parts)
        self._starts = np.array(starts)
        radius = model.geom_size[self._parts, 0].copy()
        # Half the length of each part's straight axis (0 for a sphere).
        self._half = np.where(model.geom_type[self._parts] == mujoco.mjtGeom.mjGEOM_SPHERE,
                              0.0, model.geom_size[self._parts, 1])
        # The largest outline radius (pixels) each level draws within the tolerance;
        # levels padded with 0 (never enough) to the longest ladder.
        width_levels = max(len(level.slices) for level in self._levels)
        allowed = np.zeros((len(self._levels), width_levels))
        for i, level in enumerate(self._levels):
            allowed[i, :len(level.slices)] = [DETAIL_TOLERANCE_PX / (1.0 - math.cos(math.pi / n))
                                              for n in level.slices]
        owner = np.repeat(np.arange(len(self._levels)), np.diff(np.append(starts, len(parts))))
        # Per camera, each part's squared distance from which each level holds.
        self._from = {}
        for cam in camera_ids:
            focal = 0.5 * height / math.tan(math.radians(model.cam_fovy[cam]) / 2.0)
            corner = math.hypot(width / 2.0, height / 2.0) / focal
            scale = focal * (1.0 + corner * corner)
            with np.errstate(divide="ignore"):
                span = scale * radius[:, None] / allowed[owner]
            self._from[cam] = radius[:, None] ** 2 + span ** 2
        # Each mesh's placement relative to the geom's own frame: MuJoCo centres a
        # mesh on its inertial frame and moves the geom by the same offset; None
        # where the two frames agree.
        self._offsets = [[self._offset(model, level.geom, mesh) for mesh in level.meshes]
                         for level in self._levels]
        self._mesh_type = int(mujoco.mjtGeom.mjGEOM_MESH)
        self._geom_obj = int(mujoco.mjtObj.mjOBJ_GEOM)
        self._slots: tuple[int, list] | None = None  # (scene size, each level's scene geom)
        self._rows = np.arange(len(self._levels))
        # Parts on bodies welded to the world stay put: a choice is kept until
        # the camera has moved as far as the nearest threshold (levels_for).
        self._static = bool(np.all(model.body_weldid[model.geom_bodyid[self._parts]] == 0))
        self._from_distance = {cam: np.sqrt(limit) for cam, limit in self._from.items()}
        # A geom on such a body is always drawn at the same pose: each level's placement
        # is worked out on its first frame and kept, by (geom index, level).
        self._fixed = [bool(model.body_weldid[model.geom_bodyid[level.geom]] == 0)
                       for level in self._levels]
        self._placed: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._kept: dict[int, tuple[np.ndarray, float, np.ndarray]] = {}
        #: The level index drawn for each geom in the last frame (-1: the geom's own).
        self.chosen = np.full(len(self._levels), -1)

    @staticmethod
    def _offset(model, geom: int, mesh: int) -> tuple[np.ndarray, np.ndarray] | None:
        def pose(mesh_id):
            rotation = np.zeros(9)
            mujoco.mju_quat2Mat(rotation, model.mesh_quat[mesh_id])
            return model.mesh_pos[mesh_id].copy(), rotation.reshape(3, 3)

        if int(model.geom_type[geom]) == int(mujoco.mjtGeom.mjGEOM_MESH):
            own_pos, own_rot = pose(model.geom_dataid[geom])
        else:
            own_pos, own_rot = np.zeros(3), np.eye(3)
        pos, rot = pose(mesh)
        shift, turn = own_rot.T @ (pos - own_pos), own_rot.T @ rot
        if np.abs(shift).max() < 1e-12 and np.abs(turn - np.eye(3)).max() < 1e-12:
            return None
        return shift, turn

    def levels_for(self, data: mujoco.MjData, camera: int) -> np.ndarray:
        """The level index each geom needs from ``camera`` now (-1: its own drawing).

        Each part's distance changes no faster than the camera moves, so while
        the parts are fixed in the world, the answer stands until the camera
        has moved as far as the nearest threshold was: it is kept till then.
        """
        eye = data.cam_xpos[camera]
        kept = self._kept.get(camera)
        if kept is not None:
            x, y, z = (eye - kept[0]).tolist()
            if x * x + y * y + z * z < kept[1]:
                return kept[2]
        offset = eye - data.geom_xpos[self._parts]
        # Each geom's z axis in the world: the last column of its row-major rotation.
        axis = data.geom_xmat[self._parts][:, 2::3]
        # The nearest point of each part's axis segment (NumPy's small-array calls
        # cost more than their arithmetic here, hence the in-place clip).
        along = (offset * axis).sum(axis=1)
        np.minimum(np.maximum(along, -self._half, out=along), self._half, out=along)
        offset -= along[:, None] * axis
        distance2 = (offset * offset).sum(axis=1)
        holds = np.logical_and.reduceat(distance2[:, None] >= self._from[camera],
                                        self._starts, axis=0)
        first = holds.argmax(axis=1)
        levels = np.where(holds[self._rows, first], first, -1)
        if self._static:
            margin = np.abs(np.sqrt(distance2)[:, None] - self._from_distance[camera]).min()
            self._kept[camera] = (eye.copy(), margin * margin, levels)
        return levels

    def apply(self, data: mujoco.MjData, camera: int, scene: mujoco.MjvScene) -> None:
        """Swap the geoms of ``scene`` (just updated from ``data``) for their levels."""
        chosen = self.levels_for(data, camera)
        self.chosen = chosen
        if (chosen < 0).all():
            return
        if self._slots is None or self._slots[0] != scene.ngeom:
            # Each level's geom in the scene (None: not drawn), fixed while the scene's
            # geoms are (the same model, options and camera give the same order).
            self._slots = (scene.ngeom, [None if j < 0 else scene.geoms[j]
                                         for j in self._scene_slots(scene)])
        slots = self._slots[1]
        for i, k in enumerate(chosen.tolist()):
            if k < 0 or (geom := slots[i]) is None:
                continue
            level = self._levels[i]
            offset = self._offsets[i][k]
            if offset is not None:
                placed = self._placed.get((i, k))
                if placed is None:
                    rotation = geom.mat  # (3, 3), the geom's frame in the world
                    placed = (geom.pos + rotation @ offset[0], rotation @ offset[1])
                    if self._fixed[i]:
                        self._placed[i, k] = placed
                geom.pos[:] = placed[0]
                geom.mat[:] = placed[1]
            geom.type = self._mesh_type
            # A mesh's drawing is 2 * id (its convex hull's 2 * id + 1).
            geom.dataid = 2 * level.meshes[k]

    def _scene_slots(self, scene: mujoco.MjvScene) -> list[int]:
        """Where each level's geom sits in ``scene`` (-1: not drawn)."""
        where = {}
        for j in range(scene.ngeom):
            geom = scene.geoms[j]
            if geom.objtype == self._geom_obj:
                where[geom.objid] = j
        return [where.get(level.geom, -1) for level in self._levels]


def _release(gl) -> None:
    """Make no context current in this thread (``gl``'s backend), so that any thread
    may make ``gl`` current next."""
    backend = type(gl).__module__
    if backend == "mujoco.egl":
        from mujoco import egl

        egl.EGL.eglMakeCurrent(egl.EGL_DISPLAY, egl.EGL.EGL_NO_SURFACE,
                               egl.EGL.EGL_NO_SURFACE, egl.EGL.EGL_NO_CONTEXT)
    elif backend == "mujoco.osmesa":
        from mujoco import osmesa

        osmesa.osmesa.OSMesaMakeCurrent(None, None, osmesa.GL.GL_FLOAT, 0, 0)
    elif backend == "mujoco.glfw":
        from mujoco import glfw

        glfw.glfw.make_context_current(None)
    else:
        raise RuntimeError(f"unknown MuJoCo GL backend {backend!r}")


def _close_all() -> None:
    for renderer in list(_LIVE):
        renderer.close()
