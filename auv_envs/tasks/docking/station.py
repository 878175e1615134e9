"""The docking scene: light layouts, the composed MuJoCo model and its physics accessors.

What the docking task (:mod:`auv_envs.tasks.docking.env`) simulates and reads: a
station with its lights (:class:`StationLayout`: six lights, [OFNMPC]; the
L-shaped lamp array, [LAMP]), the vehicle with its forward and chase
cameras (:func:`build_docking_model`), and :class:`DockingPhysics`, the named
accessors of the compiled model (the hull's pose and velocity, the lights,
the camera, lines of sight, the contact shortcut).
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
from dm_control import mjcf

from auv_envs.core import frames, rays, tessellation
from auv_envs.core.assets import MJCF, asset_path
from auv_envs.core.rendering import (
    DETAIL_SLICES,
    DetailLevels,
    detail_slices,
    outline_slices,
)
from auv_envs.core.vehicle import VehicleParams

#: ``render_camera`` values: ``"chase"`` follows the vehicle from behind and
#: above (a view for people), ``"onboard"`` is the forward camera the
#: ``image`` observation uses.
RENDER_CAMERAS = ("chase", "onboard")
#: The chase camera's name in the composed model (the vehicle's, attached with its prefix).
CHASE_CAMERA = "hovering_auv/chase"
#: The chase camera: offset from the CG in the world frame (m; it follows the
#: vehicle's position, not its attitude), downward pitch (deg), vertical field
#: of view (deg).
CHASE_OFFSET = (-3.6, 0.0, 1.4)
CHASE_PITCH_DEG = 18.0
CHASE_FOVY_DEG = 60.0
#: Headlight of the chase view (ambient, diffuse): the water stays the model's
#: (fog colour and visibility), but the view is lit as by a survey lamp. The
#: onboard camera keeps the model's dim headlight.
CHASE_HEADLIGHT = (0.45, 0.6)
#: Geom group of the vehicle's own hull (``assets/vehicles/hovering_auv.xml``):
#: drawn in views for people, left out of the nose camera's images where
#: :meth:`DockingPhysics.camera_sees_hull` shows it cannot be seen.
OWN_HULL_GROUP = 1
#: Geom group of visual-only geoms (no contacts, ignored by lines of sight):
#: the lamps and the station's drawn meshes.
VISUAL_GROUP = 2
#: Geom group of the station's primitives: they collide and block lines of sight,
#: and are drawn as meshes tessellated from them (:func:`build_docking_model`);
#: MuJoCo's views leave groups 3-5 out unless asked.
STATION_COLLISION_GROUP = 3
#: Colour of a failed lamp (``optics``): unlit grey glass, no emission.
FAILED_LAMP_RGBA = (0.25, 0.25, 0.25, 1.0)


@dataclasses.dataclass(frozen=True)
class StationLayout:
    """A light layout: its asset, camera tilt and where episodes start."""

    name: str
    asset: str
    light_labels: tuple[str, ...]
    camera_pitch_deg: float
    start_x: tuple[float, float]
    start_y: tuple[float, float]
    start_z: tuple[float, float]


SIX_LIGHTS = StationLayout(
    name="six-lights",
    asset="docking/station_six_lights.xml",
    light_labels=("L0", "L1", "L2", "L3", "L4", "L5"),
    camera_pitch_deg=0.0,
    start_x=(-12.0, -8.0),
    start_y=(-1.5, 1.5),
    start_z=(-0.8, 0.8),
)

LAMP_ARRAY = StationLayout(
    name="lamp-array",
    asset="docking/station_lamp_array.xml",
    light_labels=("A", "B", "C", "D"),
    camera_pitch_deg=20.0,
    start_x=(-12.0, -8.0),
    start_y=(-1.5, 1.5),
    start_z=(-0.2, 0.9),
)



def build_docking_model(layout: StationLayout, params: VehicleParams,
                        image_height: int | None = None) -> mujoco.MjModel:
    """:func:`compose_docking_model`, compiled."""
    return compose_docking_model(layout, params, image_height).compile()


def compose_docking_model(layout: StationLayout, params: VehicleParams,
                          image_height: int | None = None) -> MJCF:
    """Compose arena + station + vehicle from ``assets/`` with dm_control's mjcf.

    The station's primitives (its geom group 0) are drawn as one mesh per
    material (:mod:`auv_envs.core.tessellation`, in :data:`VISUAL_GROUP`),
    its round parts with :func:`~auv_envs.core.rendering.outline_slices`
    sides for images ``image_height`` rows high (the model's ``numslices``
    when None, or for images of 222 rows and more). The primitives move to
    :data:`STATION_COLLISION_GROUP`: they still collide and block lines of
    sight, and no view draws them. For images (``image_height`` given) the
    model also holds coarser meshes of the station and of the lamp spheres,
    with :func:`~auv_envs.core.rendering.detail_slices` sides, attached to
    no geom: renderers draw them in place of the finest where they show no
    difference (:meth:`DockingPhysics.detail_levels`).
    """
    arena = mjcf.from_path(str(asset_path("docking/arena.xml")))
    station = mjcf.from_path(str(asset_path(layout.asset)))
    vehicle = mjcf.from_path(str(asset_path("vehicles/hovering_auv.xml")))
    station.model = "station"  # fixed name prefix whatever the layout

    hull = vehicle.find("body", "hull")
    hull.inertial.mass = params.mass
    hull.inertial.diaginertia = list(params.inertia)
    a, b = params.length / 2.0, params.diameter / 2.0
    vehicle.find("geom", "hull").size = [a, b, b]
    nose = [a, 0.0, 0.0]
    vehicle.find("site", "nose").pos = nose
    pitch = math.radians(layout.camera_pitch_deg)
    camera = vehicle.find("camera", "nose_camera")
    camera.pos = nose
    # MuJoCo camera x = -body y; camera y (image up) tilted down by pitch.
    camera.xyaxes = [0.0, -1.0, 0.0, math.sin(pitch), 0.0, math.cos(pitch)]

    # The chase camera (renders only): "track" keeps its world-frame offset from
    # the hull and its world orientation, so it neither rolls nor yaws with the vehicle.
    chase_pitch = math.radians(CHASE_PITCH_DEG)
    hull.add("camera", name="chase", mode="track", pos=list(CHASE_OFFSET),
             xyaxes=[0.0, -1.0, 0.0, math.sin(chase_pitch), 0.0, math.cos(chase_pitch)],
             fovy=CHASE_FOVY_DEG)

    arena.worldbody.attach(station)
    arena.worldbody.attach(vehicle).add("freejoint")
    _draw_station_as_meshes(arena, station, layout.asset, image_height)
    return MJCF.of(arena)


def _draw_station_as_meshes(arena, station, asset: str, image_height: int | None) -> None:
    """Add the station's visual meshes to ``station`` and hide its primitives (see above)."""
    body = station.worldbody.body[0]
    primitives: dict[str, list] = {}
    for element in body.find_all("geom", immediate_children_only=True):
        if (element.group or 0) != 0:
            continue
        if element.material is None:
            raise ValueError(f"station geom {element.name!r} needs a material "
                             "to be drawn as a mesh")
        primitives.setdefault(element.material.name, []).append(element)
    key = (asset, image_height)
    meshes = _STATION_MESHES.get(key)
    if meshes is None:
        meshes = _tessellate_station(arena, body, primitives, image_height)
        _STATION_MESHES[key] = meshes
    for material, elements in primitives.items():
        drawn = drawn_mesh_name(material)
        station.asset.add("mesh", name=drawn, file=mjcf.Asset(meshes[material], ".msh"))
        body.add("geom", name=drawn, type="mesh", mesh=drawn,
                 material=material, group=VISUAL_GROUP, contype=0, conaffinity=0, density=0)
        for element in elements:
            element.group = STATION_COLLISION_GROUP
    # The coarser levels, as assets only (see build_docking_model).
    for name, contents in meshes.items():
        if name not in primitives:
            station.asset.add("mesh", name=name, file=mjcf.Asset(contents, ".msh"))


#: The station's meshes by (station asset, image height): each ``.msh`` file's bytes
#: by mesh name (a material's name for its finest drawing, :func:`detail_mesh_name`
#: for the coarser levels). Tessellating compiles the composed model once more; the
#: meshes depend only on the station and the slices.
_STATION_MESHES: dict[tuple[str, int | None], dict[str, bytes]] = {}

#: Name of the coarser meshes of the lamp spheres (under the station's ``station/`` prefix).
LAMP_DETAIL = "lamp"


def drawn_mesh_name(material: str) -> str:
    """Name of the mesh (and geom) drawing the station's primitives of ``material``."""
    return f"drawn_{material}"


def detail_mesh_name(drawing: str, slices: int) -> str:
    """Name of the coarser mesh of ``drawing`` (a material, or :data:`LAMP_DETAIL`)."""
    return f"detail_{drawing}_{slices}"


def _tessellate_station(arena, body, primitives: dict, image_height: int | None):
    """Each material's ``.msh`` bytes, in the station body's frame."""
    # The primitives' poses and the model's quality, from the model as composed so far.
    model = mujoco.MjModel.from_xml_string(arena.to_xml_string(), assets=arena.get_assets())
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    body_id = model.body(f"station/{body.name}").id
    frame = (data.xpos[body_id], data.xmat[body_id].reshape(3, 3))
    slices = int(model.vis.quality.numslices)
    if image_height is not None:
        slices = outline_slices(image_height, slices)
    coarser = detail_slices(slices) if image_height is not None else ()
    meshes = {}
    for material, elements in primitives.items():
        geoms = [model.geom(f"station/{element.name}").id for element in elements]
        # As a binary asset: written inline, mjcf would format the arrays as text.
        meshes[material] = tessellation.msh_bytes(
            *tessellation.static_mesh(model, data, geoms, slices, frame))
        for n in coarser:
            meshes[detail_mesh_name(material, n)] = tessellation.msh_bytes(
                *tessellation.static_mesh(model, data, geoms, n, frame))
    lamps = lamp_spheres(model)
    if coarser and len(lamps):
        radii = np.unique(model.geom_size[lamps, 0])
        if len(radii) != 1:
            raise ValueError(f"the station's lamp spheres differ in radius ({radii.tolist()}); "
                             "their coarser meshes assume one")
        for n in coarser:
            meshes[detail_mesh_name(LAMP_DETAIL, n)] = tessellation.msh_bytes(
                *tessellation.sphere(float(radii[0]), n))
    return meshes


def lamp_spheres(model: mujoco.MjModel) -> np.ndarray:
    """Ids of the lamp spheres: the sphere geoms in :data:`VISUAL_GROUP`."""
    return np.flatnonzero((model.geom_group == VISUAL_GROUP)
                          & (model.geom_type == mujoco.mjtGeom.mjGEOM_SPHERE))


#: Margins of :meth:`DockingPhysics.skip_contacts_if_clear`: a speed the hull cannot
#: gain within one control period (thrust accelerates it by < 0.05 m/s in 0.1 s)
#: and a distance, m.
_SPEED_MARGIN = 0.5
_DISTANCE_MARGIN = 0.05


class _StaticScenery:
    """Where the hull could touch static geometry: planes and one bounding box.

    Built once from the compiled model: every collidable geom outside the hull
    must belong to a body without degrees of freedom (the station, the seabed).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, hull_body: int):
        hull_root = model.body_rootid[hull_body]
        collidable = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        # Radius about the hull's origin (the CG) of a sphere holding every hull geom.
        self.hull_radius = float(
            max(np.linalg.norm(model.geom_pos[g]) + model.geom_rbound[g]
                for g in range(model.ngeom)
                if model.body_rootid[model.geom_bodyid[g]] == hull_root and collidable[g])
        )
        self.planes: list[tuple[float, ...]] = []  # (nx, ny, nz, offset): n . p - offset
        low, high = np.full(3, np.inf), np.full(3, -np.inf)
        for g in np.flatnonzero(collidable):
            body = model.geom_bodyid[g]
            if model.body_rootid[body] == hull_root:
                continue
            if model.body_weldid[body] != 0:
                raise ValueError("docking scenery must be static (no joints outside the hull)")
            rot = data.geom_xmat[g].reshape(3, 3)
            if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
                normal = rot[:, 2]
                self.planes.append((*normal.tolist(), float(normal @ data.geom_xpos[g])))
                continue
            centre, half = model.geom_aabb[g][:3], model.geom_aabb[g][3:]
            corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                                for sz in (-1, 1)]) * half + centre
            world = corners @ rot.T + data.geom_xpos[g]
            low, high = np.minimum(low, world.min(axis=0)), np.maximum(high, world.max(axis=0))
        self.box = (*low.tolist(), *high.tolist())

    def clear(self, x: float, y: float, z: float, reach: float) -> bool:
        """Whether a sphere of radius ``reach`` at (x, y, z) is clear of all the scenery."""
        for nx, ny, nz, offset in self.planes:
            if nx * x + ny * y + nz * z - offset <= reach:
                return False
        x0, y0, z0, x1, y1, z1 = self.box
        dx = max(x0 - x, 0.0, x - x1)
        dy = max(y0 - y, 0.0, y - y1)
        dz = max(z0 - z, 0.0, z - z1)
        return dx * dx + dy * dy + dz * dz > reach * reach


class DockingPhysics:
    """Named accessors into one MuJoCo model/data pair; ids resolved once."""

    def __init__(self, model: mujoco.MjModel, n_lights: int):
        self.model = model
        self.data = mujoco.MjData(model)
        self.hull_body = model.body("hovering_auv/hull").id
        # The free joint sits on the attachment frame that carries the hull.
        joint = model.joint(model.body_jntadr[model.body_parentid[self.hull_body]])
        # The hull wrench is applied as the free joint's generalized force: the
        # hull's frame and centre of mass must be the joint's frame.
        hull = self.hull_body
        if not (np.allclose(model.body_pos[hull], 0.0) and np.allclose(model.body_ipos[hull], 0.0)
                and np.allclose(model.body_quat[hull], (1.0, 0.0, 0.0, 0.0))):
            raise ValueError("the hull body must sit at its free joint's frame, CG at its origin")
        self.qpos_adr = joint.qposadr[0]
        self.qvel_adr = joint.dofadr[0]
        self.hull_geoms = np.flatnonzero(model.geom_bodyid == hull)
        if np.any(model.geom_group[self.hull_geoms] != OWN_HULL_GROUP):
            raise ValueError(f"the hull's geoms must be in geom group {OWN_HULL_GROUP}")
        cam = model.camera("hovering_auv/nose_camera")
        self.camera_name = cam.name
        self.camera_id = cam.id
        self.camera_pos_body = model.cam_pos[cam.id].copy()
        cam_mat = np.zeros(9)
        mujoco.mju_quat2Mat(cam_mat, model.cam_quat[cam.id])
        self.camera_mat_body = cam_mat.reshape(3, 3)
        mujoco.mj_forward(model, self.data)
        self.light_positions = np.array(
            [self.data.site(f"station/light_{i}").xpos for i in range(n_lights)]
        )
        self.seabed_z = float(self.data.geom("seabed").xpos[2])
        # The lamp geom drawn at each light (a visual-only sphere at the light's site).
        visual = lamp_spheres(model)
        self.lamp_geoms = np.array([
            visual[np.argmin(np.linalg.norm(self.data.geom_xpos[visual] - p, axis=1))]
            for p in self.light_positions
        ])
        if not np.allclose(self.data.geom_xpos[self.lamp_geoms], self.light_positions):
            raise ValueError("every light site needs a lamp geom (a sphere in group "
                             f"{VISUAL_GROUP}) at its position")
        self._lamp_look = (model.geom_matid[self.lamp_geoms].copy(),
                           model.geom_rgba[self.lamp_geoms].copy())
        # Rays see the scenery: the seabed and hull (geom groups 0-1) and the station's
        # primitives (STATION_COLLISION_GROUP); not group 2, the visual-only geoms
        # (the lamps and the station's drawn meshes).
        self.ray_groups = np.array([1, 1, 0, 0, 0, 0], dtype=np.uint8)
        self.ray_groups[STATION_COLLISION_GROUP] = 1
        # Views into MjData made once (its array properties build a new view on
        # every access) and buffers reused every step; mj_resetData and
        # mj_setState write in place, so the views stay valid.
        adr, vadr = self.qpos_adr, self.qvel_adr
        self._pos = self.data.qpos[adr : adr + 3]
        self._quat = self.data.qpos[adr + 3 : adr + 7]
        self._qvel = self.data.qvel[vadr : vadr + 6]
        #: The hull's free joint in ``data``: position and quaternion, velocity (views).
        self.qpos, self.qvel = self.data.qpos[adr : adr + 7], self._qvel
        self._rot = np.empty(9)
        self._ray_origin = np.empty(3)
        self._ray_vec = np.empty(3)
        self._ray_geom = np.empty(1, dtype=np.int32)
        self._scenery = _StaticScenery(model, self.data, hull)
        self._constraint_bit = int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)

    def skip_contacts_if_clear(self, duration: float) -> bool:
        """Turn MuJoCo's collision and constraint stages off for the next
        ``duration`` seconds when the hull cannot reach any static geometry in
        that time, on otherwise; returns whether it cannot (clear).

        With no contact possible the constraint stage has nothing to do: the
        step is the same to the bit, and each of RK4's four stages skips
        collision detection (about a fifth of the plant's cost).
        """
        x, y, z = self._pos.tolist()
        vx, vy, vz, wx, wy, wz = self._qvel.tolist()
        scenery = self._scenery
        speed = math.sqrt(vx * vx + vy * vy + vz * vz) + scenery.hull_radius * math.sqrt(
            wx * wx + wy * wy + wz * wz
        )
        reach = scenery.hull_radius + (speed + _SPEED_MARGIN) * duration + _DISTANCE_MARGIN
        opt = self.model.opt
        clear = scenery.clear(x, y, z, reach)
        if clear:
            opt.disableflags |= self._constraint_bit
        else:
            opt.disableflags &= ~self._constraint_bit
        return clear

    def show_lamps(self, failed: np.ndarray | None) -> None:
        """Draw the ``failed`` lamps unlit (no material, grey), the others as built."""
        matid, rgba = self._lamp_look
        geoms = self.lamp_geoms
        self.model.geom_matid[geoms] = matid
        self.model.geom_rgba[geoms] = rgba
        if failed is not None and failed.any():
            self.model.geom_matid[geoms[failed]] = -1
            self.model.geom_rgba[geoms[failed]] = FAILED_LAMP_RGBA

    def detail_levels(self) -> tuple[DetailLevels, ...]:
        """The coarser drawings image renderers may use (:class:`DetailLevels`): each of
        the station's drawn meshes, standing for its round primitives, and each lamp
        sphere. Empty where the model holds no coarser meshes (built without an image
        height, :func:`build_docking_model`)."""
        model = self.model
        meshes = {model.mesh(m).name: m for m in range(model.nmesh)}

        def coarser(drawing: str) -> tuple[tuple[int, ...], tuple[int, ...]]:
            found = [(n, meshes[name]) for n in DETAIL_SLICES
                     if (name := "station/" + detail_mesh_name(drawing, n)) in meshes]
            return tuple(m for _, m in found), tuple(n for n, _ in found)

        round_primitives = np.flatnonzero((model.geom_group == STATION_COLLISION_GROUP)
                                          & np.isin(model.geom_type, list(tessellation.ROUND)))
        levels = []
        drawn = np.flatnonzero((model.geom_group == VISUAL_GROUP)
                               & (model.geom_type == mujoco.mjtGeom.mjGEOM_MESH))
        for geom in drawn.tolist():
            material = model.material(model.geom_matid[geom]).name.removeprefix("station/")
            if model.mesh(model.geom_dataid[geom]).name != "station/" + drawn_mesh_name(material):
                continue  # not a drawing of the station's primitives
            ids, slices = coarser(material)
            parts = round_primitives[model.geom_matid[round_primitives] == model.geom_matid[geom]]
            if ids and len(parts):
                levels.append(DetailLevels(geom, ids, slices, tuple(parts.tolist())))
        ids, slices = coarser(LAMP_DETAIL)
        if ids:
            levels.extend(DetailLevels(int(g), ids, slices, (int(g),)) for g in self.lamp_geoms)
        return tuple(levels)

    def position(self) -> np.ndarray:
        return self._pos.copy()

    def rotation(self) -> np.ndarray:
        mujoco.mju_quat2Mat(self._rot, self._quat)
        return self._rot.reshape(3, 3).copy()

    def body_velocity(self, rotation: np.ndarray) -> np.ndarray:
        """(u, v, w, p, q, r) in the body frame."""
        out = self._qvel.copy()
        out[0:3] = out[0:3] @ rotation
        return out

    def kinematics(self) -> tuple[list, list, list]:
        """The hull's state as Python floats, for the per-step path.

        Returns:
            Position (3), body-to-world rotation (9, row-major) and the free
            joint's velocity (world linear, body angular; 6).
        """
        mujoco.mju_quat2Mat(self._rot, self._quat)
        return self._pos.tolist(), self._rot.tolist(), self._qvel.tolist()

    def set_state(self, position, euler, body_velocity) -> None:
        mujoco.mj_resetData(self.model, self.data)
        adr = self.qpos_adr
        self.data.qpos[adr : adr + 3] = position
        self.data.qpos[adr + 3 : adr + 7] = frames.quat_from_euler(*euler, np)
        rot = frames.rotation_from_euler(*euler, np)
        self.data.qvel[self.qvel_adr : self.qvel_adr + 3] = rot @ np.asarray(body_velocity[0:3])
        self.data.qvel[self.qvel_adr + 3 : self.qvel_adr + 6] = body_velocity[3:6]
        mujoco.mj_forward(self.model, self.data)

    def camera_sees_hull(self, width: int, height: int) -> bool:
        """Whether any of the hull can show in the nose camera's ``width`` x ``height`` image.

        No, when the hull lies behind the plane through the camera centre
        across the body's x axis (every hull geom axis-aligned, ending at or
        behind the camera's x) and every ray of the camera's frustum points
        forward (positive body x at its four corners, which span it): a point
        seen is then ahead of that plane. True where that cannot be shown.
        """
        model = self.model
        for g in self.hull_geoms:
            aligned = np.allclose(model.geom_quat[g], (1.0, 0.0, 0.0, 0.0))
            if not aligned or model.geom_type[g] != mujoco.mjtGeom.mjGEOM_ELLIPSOID:
                return True
            if model.geom_pos[g][0] + model.geom_size[g][0] > self.camera_pos_body[0]:
                return True
        half_y = math.tan(math.radians(model.cam_fovy[self.camera_id]) / 2.0)
        half_x = half_y * width / height
        corners = np.array([(sx * half_x, sy * half_y, -1.0)
                            for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)])
        forward = (corners @ self.camera_mat_body.T)[:, 0]
        return bool(np.any(forward <= 0.0))

    def unoccluded(self, origin, targets, candidates) -> list[bool]:
        """Which candidate targets static scenery does not hide from ``origin``.

        One ``mj_ray`` per candidate (``False`` entries cast no ray): for a few
        rays it is several times cheaper than ``mj_multiRay``, whose set-up
        covers every geom whatever the rays.

        Args:
            origin: ray origin (3 floats), e.g. the camera centre.
            targets: target points, each 3 floats.
            candidates: per target, whether to test it at all.

        Returns:
            Per target: candidate and line of sight clear.
        """
        model, data, groups, exclude = self.model, self.data, self.ray_groups, self.hull_body
        start, vec, geom = self._ray_origin, self._ray_vec, self._ray_geom
        ox, oy, oz = origin
        start[0], start[1], start[2] = ox, oy, oz
        out = []
        for candidate, (x, y, z) in zip(candidates, targets, strict=True):
            if candidate:
                vec[0], vec[1], vec[2] = x - ox, y - oy, z - oz
                dist = mujoco.mj_ray(model, data, start, vec, groups, 1, exclude, geom)
                # dist is in units of |vec|: something is hit before the target.
                candidate = not 0.0 <= dist < rays.END
            out.append(candidate)
        return out


