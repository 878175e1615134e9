"""The LARS capture scene: AUV and marker geometry, the AUV's motion, the MJCF model.

Geometry ([LTAT], §2.2.2 and Table 1): an Explore-100-like AUV, 1.8 m long,
0.2 m in diameter, 47 kg, with an isosceles-triangle marker of sides 0.15,
0.4 and 0.4 m painted on its top surface. The base corners A1 (port) and A2
(starboard) lie on the curved hull, the apex A3 on the top line towards the
bow; the base's midpoint therefore sits ``D = r (1 - cos a)`` below the top
line, the "fixed error caused by the marking on the cylindrical surface" of
eq. 4.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
from dm_control import mjcf

from auv_envs.core import frames
from auv_envs.core.assets import MJCF, asset_path
from auv_envs.core.pytree import dataclass_pytree

#: Explore-100-like AUV ([LTAT], Table 1).
AUV_LENGTH = 1.8
AUV_DIAMETER = 0.2
AUV_MASS = 47.0
#: Height of the hull's top line above the local water level, m ("upper
#: surface just above the water": 47 kg displace ~81 % of the hull).
AUV_FREEBOARD = 0.05
#: Marker sides (base, leg, leg), m ([LTAT], Fig. 5).
MARKER_SIDES = (0.15, 0.4, 0.4)
#: The paint's radius: 1.5 mm proud of the hull so it renders above it.
MARKER_RADIUS = AUV_DIAMETER / 2.0 + 0.0015
#: Body-x position of the marker's base edge (the apex points to the bow).
MARKER_BASE_X = -0.15
#: Lifting eye (capture point) on the top line aft of the marker, body frame.
CAPTURE_POINT_BODY = (-0.45, 0.0, AUV_DIAMETER / 2.0)
#: Look-alike floaters: 0.9 m long, same paint, marker scaled by 0.8.
ANALOG_SCALE = 0.8
ANALOG_MARKER_BASE_X = -0.12


def auv_rotation(pitch, yaw, xp):
    """Body-to-world rotation (3, 3) of the level-rolled AUV with nose-up ``pitch`` and
    ``yaw`` (``xp``: NumPy, or ``jax.numpy``).

    frames.py's ZYX pitch is nose-down positive, hence the sign.
    """
    return frames.rotation_from_euler(0.0, -pitch, yaw, xp)


@dataclasses.dataclass(frozen=True)
class MarkerGeometry:
    """The triangle marker on a cylinder of radius ``radius``.

    Attributes:
        corners: (3, 3) body-frame corners A1 (port base), A2 (starboard
            base), A3 (apex), m.
        depth_offset: ``D`` of eq. 4: how far the base midpoint lies below
            the top line, m.
    """

    corners: np.ndarray
    depth_offset: float
    radius: float
    base_x: float
    half_angle: float
    height: float

    @classmethod
    def on_cylinder(cls, sides=MARKER_SIDES, radius=MARKER_RADIUS, base_x=MARKER_BASE_X):
        base, leg, _ = sides
        half_angle = math.asin(0.5 * base / radius)
        drop = radius * (1.0 - math.cos(half_angle))
        height = math.sqrt(leg**2 - (0.5 * base) ** 2 - drop**2)
        y, z = radius * math.sin(half_angle), radius * math.cos(half_angle)
        corners = np.array([[base_x, y, z], [base_x, -y, z], [base_x + height, 0.0, radius]])
        corners.setflags(write=False)
        return cls(corners, drop, radius, base_x, half_angle, height)

    def mesh(self, rows: int = 12, cols: int = 10) -> tuple[np.ndarray, np.ndarray]:
        """Vertices and faces of the painted patch, following the curved hull.

        The patch is the triangle developed on the cylinder: at a fraction
        ``t`` of the way to the apex it spans the hull angles
        ``[-a (1 - t), a (1 - t)]``, so its three corners are exactly
        :attr:`corners`.
        """
        verts = []
        for k in range(rows):
            t = k / rows
            x = self.base_x + t * self.height
            for j in range(cols + 1):
                phi = (2.0 * j / cols - 1.0) * self.half_angle * (1.0 - t)
                verts.append((x, self.radius * math.sin(phi), self.radius * math.cos(phi)))
        verts.append(tuple(self.corners[2]))
        apex = len(verts) - 1
        faces = []
        for k in range(rows - 1):
            for j in range(cols):
                a, b = k * (cols + 1) + j, (k + 1) * (cols + 1) + j
                faces += [(a, b, b + 1), (a, b + 1, a + 1)]
        last = (rows - 1) * (cols + 1)
        faces += [(last + j, apex, last + j + 1) for j in range(cols)]
        return np.array(verts), np.array(faces)


@dataclass_pytree()
@dataclasses.dataclass(frozen=True)
class AUVMotion:
    """The AUV's motion in one episode ([LTAT], §2.3: uniform surge along X,
    fixed Y, sinusoidal heave along Z), plus constant yaw and pitch offsets.

    The local water level heaves with the AUV (it floats on the wave):
    ``water(t) = A sin(w t + phase)`` and the hull's top line stays
    ``AUV_FREEBOARD`` above it.

    Attributes:
        x0, y0: CG position at t = 0, m.
        surge: speed along world x, m/s.
        heave_amplitude: m (paper: 0.2).
        heave_period: s.
        heave_phase: rad.
        yaw: heading offset from world +x, rad (counter-clockwise from above).
        pitch: nose-up pitch, rad.
    """

    x0: float
    y0: float
    surge: float
    heave_amplitude: float
    heave_period: float
    heave_phase: float
    yaw: float
    pitch: float

    @property
    def omega(self) -> float:
        return 2.0 * math.pi / self.heave_period

    def rotation(self) -> np.ndarray:
        """Body-to-world rotation (see :func:`auv_rotation`)."""
        return auv_rotation(self.pitch, self.yaw, np)

    def quaternion(self) -> np.ndarray:
        """The same rotation as a MuJoCo ``(w, x, y, z)`` quaternion (same pitch sign)."""
        return frames.quat_from_euler(0.0, -self.pitch, self.yaw, np)


#: Documented randomisation ranges of :class:`AUVMotion` (``reset`` draws
#: uniformly; ``options`` may pin any of them).
MOTION_RANGES = {
    "x0": (-0.4, 0.4),
    "y0": (1.9, 2.2),
    "surge": (0.03, 0.12),
    "heave_amplitude": (0.2, 0.2),
    "heave_period": (5.0, 9.0),
    "heave_phase": (0.0, 2.0 * math.pi),
    "yaw": (math.radians(-30.0), math.radians(30.0)),
    "pitch": (math.radians(-4.0), math.radians(4.0)),
}


def uniform_draws(rng: np.random.Generator, bounds, ops) -> list[float]:
    """One uniform draw in each ``(low, high)`` of ``bounds``, as Python floats (or the
    scalars of another backend of :mod:`auv_envs.core.ops`).

    ``Generator.uniform(low, high)`` is ``low + (high - low) * random()``, so
    these are the values (and the stream position) of successive scalar
    ``rng.uniform`` calls, drawn in one call: a reset draws about ten, and
    each scalar call costs more than the arithmetic.
    """
    draws = ops.unpack(rng.random(len(bounds)))
    return [lo + (hi - lo) * u for (lo, hi), u in zip(bounds, draws, strict=True)]


_MOTION_BOUNDS = tuple(MOTION_RANGES.values())


def sample_motion(rng: np.random.Generator, overrides: dict | None,
                  ops) -> AUVMotion:
    """Draw an :class:`AUVMotion` in :data:`MOTION_RANGES`; ``overrides`` pins fields
    (Python floats; the draws are the scalars of ``ops``)."""
    overrides = dict(overrides or {})
    unknown = set(overrides) - set(MOTION_RANGES)
    if unknown:
        raise ValueError(
            f"unknown motion option(s) {sorted(unknown)}; valid: {sorted(MOTION_RANGES)}"
        )
    values = {}
    # Always draw every field: pinning one keeps the rest of the stream.
    for name, drawn in zip(MOTION_RANGES, uniform_draws(rng, _MOTION_BOUNDS, ops),
                           strict=True):
        if name not in overrides:
            values[name] = drawn
            continue
        values[name] = float(overrides[name])
        if not math.isfinite(values[name]):
            raise ValueError(f"motion option {name} must be finite, got {values[name]}")
        if name == "heave_period" and values[name] <= 0:
            raise ValueError("heave_period must be positive")
    return AUVMotion(**values)


#: The scene's kinematic (mocap) bodies, posed for rendering from the episode's motion.
POSED_BODIES = ("water", "crest", "head", "auv", "analog_0", "analog_1")
#: What the arm's dynamics never read: the posed bodies, the ship's hull, the person's
#: camera and the sun (:func:`build_lars_model`'s arm model leaves them out).
SCENERY = {"body": POSED_BODIES, "geom": ("ship",), "camera": ("side",), "light": ("sun",)}


def build_lars_model(
    baseline: float, fovy_deg: float, marker: MarkerGeometry, analog_marker: MarkerGeometry
) -> tuple[mujoco.MjModel, mujoco.MjModel]:
    """:func:`compose_lars_model`, compiled: ``(scene, arm)``."""
    scene, arm = compose_lars_model(baseline, fovy_deg, marker, analog_marker)
    return scene.compile(), arm.compile()


def compose_lars_model(
    baseline: float, fovy_deg: float, marker: MarkerGeometry, analog_marker: MarkerGeometry
) -> tuple[MJCF, MJCF]:
    """Compose the scene from ``assets/lars/scene.xml`` with dm_control's mjcf:
    ``(scene, arm)``, the whole scene (rendering) and the arm alone without the
    :data:`SCENERY` (the dynamics: the same bodies, joints, masses and actuators, so the
    same trajectories to the bit, for a cheaper physics step: ``docs/speed.md``)."""
    scene = mjcf.from_path(str(asset_path("lars/scene.xml")))
    for name, geom in (("marker", marker), ("analog_marker", analog_marker)):
        verts, faces = geom.mesh()
        mesh = scene.find("mesh", name)
        mesh.vertex = verts.ravel().tolist()
        mesh.face = faces.ravel().tolist()
    left, right = scene.find("camera", "left"), scene.find("camera", "right")
    y, z = left.pos[1], left.pos[2]
    left.pos = [-baseline / 2.0, y, z]
    right.pos = [baseline / 2.0, y, z]
    left.fovy = right.fovy = fovy_deg
    hull = scene.find("geom", "hull")
    half = AUV_LENGTH / 2.0 - AUV_DIAMETER / 2.0
    hull.fromto = [-half, 0, 0, half, 0, 0]
    hull.size = [AUV_DIAMETER / 2.0]
    whole = MJCF.of(scene)
    for kind, names in SCENERY.items():
        for name in names:
            scene.find(kind, name).remove()
    return whole, MJCF.of(scene)
