"""The docking task's rules, written once for every backend of :mod:`auv_envs.core.ops`.

What the vehicle's state means for the task: the camera's pose, where the
nose is against the entrance, the attitude and body velocities the sensors
report, when the vehicle has docked or failed, and the reward. The CPU
environment (:mod:`auv_envs.tasks.docking.env`) evaluates these functions on
Python floats every step; the batched environment
(:mod:`auv_envs.tasks.docking.mjx_plant`) evaluates the same functions on JAX arrays.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import operator

from auv_envs.core import frames
from auv_envs.core.camera import CameraIntrinsics

#: Failure reasons, in the order they are checked: the first that holds ends the episode.
FAILURE_REASONS = ("behind_entrance", "seabed", "lights_lost", "out_of_bounds", "surfaced")
def failure_reason(code, success) -> str:
    """The ``failure_reason`` episode metric of a failure code (index + 1 in
    :data:`FAILURE_REASONS`, 0: none): ``""`` for a success, ``"time_limit"`` otherwise."""
    code = int(code)
    if code:
        return FAILURE_REASONS[code - 1]
    return "" if success else "time_limit"


#: Distance from the entrance beyond which the vehicle is out of bounds, m.
OUT_OF_BOUNDS = 30.0


@dataclasses.dataclass(frozen=True)
class DockingTolerances:
    """Allowable deviations at the entrance (success), our documented defaults.

    The nose must be within ``longitudinal`` of the entrance plane, within
    ``lateral`` / ``vertical`` of the docking axis, and the heading within
    ``heading_deg`` of the station's axis.
    """

    lateral: float = 0.2
    vertical: float = 0.2
    heading_deg: float = 10.0
    longitudinal: float = 0.15


@dataclasses.dataclass(frozen=True)
class DockingRules:
    """The geometry of a docking scene and the rules of its episodes.

    Attributes:
        intrinsics: the forward camera's intrinsics.
        camera_position: camera centre in the body frame (3 floats).
        camera_rotation: OpenCV camera frame to body frame (3 rows of 3 floats).
        lights: light positions in the DS (= world) frame, a tuple of 3-tuples.
        nose_offset: CG-to-nose distance along body x, m.
        hull_axes: the hull ellipsoid's semi-axes (x, y, z), m.
        seabed_z: seabed height, m.
        tolerances: success tolerances.
        min_visible: lights that must be in view.
        lights_lost_timeout: seconds with fewer in view before failure.
        control_period: seconds per step.
        out_of_bounds: distance from the entrance beyond which the vehicle is out of
            bounds, m.
        behind_radius: the nose past the entrance plane fails only within this distance
            of the entrance (m); None: anywhere (the docking ids, which start in front).
        surface_z: the water surface's height (m): the centre of gravity reaching it fails
            (``"surfaced"``); None: no surface (the docking ids, a few metres from the
            station, never reach it).
    """

    intrinsics: CameraIntrinsics
    camera_position: tuple
    camera_rotation: tuple
    lights: tuple
    nose_offset: float
    hull_axes: tuple
    seabed_z: float
    tolerances: DockingTolerances
    min_visible: int
    lights_lost_timeout: float
    control_period: float
    out_of_bounds: float = OUT_OF_BOUNDS
    behind_radius: float | None = None
    surface_z: float | None = None

    @functools.cached_property
    def heading_tolerance(self) -> float:
        """The heading tolerance, rad (computed once: :meth:`docked` runs every step)."""
        return math.radians(self.tolerances.heading_deg)

    def kinematics(self, position, rotation, qvel, ops) -> dict:
        """The vehicle's pose as the task sees it.

        Args:
            position: CG position (3 scalars), DS frame.
            rotation: body-to-world rotation, 9 scalars row by row.
            qvel: the free joint's velocity (world linear, body angular; 6 scalars).
            ops: the backend.

        Returns:
            A dict: ``position``, ``camera_position`` (3), ``camera_rows`` (the
            camera-to-world rotation), ``euler`` (roll, pitch, yaw), ``velocity``
            (body u, v, w, p, q, r), the nose's ``longitudinal``, ``lateral`` and
            ``vertical`` offsets from the entrance centre, ``heading``,
            ``distance`` (nose to entrance centre) and ``seabed_clearance``
            (lowest point of the hull ellipsoid above the seabed).
        """
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation
        x, y, z = position
        vx, vy, vz = qvel[0], qvel[1], qvel[2]
        velocity = [
            vx * r00 + vy * r10 + vz * r20,
            vx * r01 + vy * r11 + vz * r21,
            vx * r02 + vy * r12 + vz * r22,
            qvel[3], qvel[4], qvel[5],
        ]
        bx, by, bz = self.camera_position
        camera_position = (
            x + r00 * bx + r01 * by + r02 * bz,
            y + r10 * bx + r11 * by + r12 * bz,
            z + r20 * bx + r21 * by + r22 * bz,
        )
        rows = ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22))
        euler = frames.euler_floats(rows, ops)
        offset = self.nose_offset
        nose = (x + r00 * offset, y + r10 * offset, z + r20 * offset)
        ax, ay, az = self.hull_axes
        half_height = ops.sqrt((ax * r20) ** 2 + (ay * r21) ** 2 + (az * r22) ** 2)
        return {
            "position": position,
            "camera_position": camera_position,
            "camera_rows": frames.compose_rows(rows, self.camera_rotation),
            "euler": euler,
            "velocity": velocity,
            "longitudinal": nose[0],
            "lateral": nose[1],
            "vertical": nose[2],
            "heading": euler[2],
            "distance": ops.sqrt(nose[0] ** 2 + nose[1] ** 2 + nose[2] ** 2),
            "seabed_clearance": z - half_height - self.seabed_z,
        }

    @staticmethod
    def potential(truth: dict):
        """The shaping potential: distance to the entrance + 0.5 |heading error|."""
        return truth["distance"] + 0.5 * abs(truth["heading"])

    def docked(self, truth: dict):
        """Whether the nose is within every tolerance of the entrance."""
        tol = self.tolerances
        return ((abs(truth["longitudinal"]) <= tol.longitudinal)
                & (abs(truth["lateral"]) <= tol.lateral)
                & (abs(truth["vertical"]) <= tol.vertical)
                & (abs(truth["heading"]) <= self.heading_tolerance))

    def lights_lost_time(self, lost_time, fov_violation, ops):
        """Seconds the lights have been lost after this step (0 once enough are in view)."""
        return ops.where(fov_violation, lost_time + self.control_period, 0.0)

    def failures(self, truth: dict, docked, lost_time, ops) -> tuple:
        """One flag per :data:`FAILURE_REASONS` entry (``"surfaced"`` with a surface only),
        for the state after a step."""
        behind = (truth["longitudinal"] > self.tolerances.longitudinal) & ops.logical_not(docked)
        if self.behind_radius is not None:
            behind = behind & (truth["distance"] < self.behind_radius)
        flags = (
            behind,
            truth["seabed_clearance"] <= 0.0,
            lost_time > self.lights_lost_timeout,
            truth["distance"] > self.out_of_bounds,
        )
        if self.surface_z is None:
            return flags
        return (*flags, truth["position"][2] >= self.surface_z)

    @staticmethod
    def failure_index(flags, ops):
        """Index + 1 of the first failure flag that holds in :data:`FAILURE_REASONS`, 0 if none."""
        code = 0
        for index in range(len(flags) - 1, -1, -1):
            code = ops.where(flags[index], index + 1, code)
        return code

    @staticmethod
    def reward_terms(prev_potential, potential, action, fov_violation, docked, failed,
                     ops) -> dict:
        """The reward's terms (they sum to the reward); ``action`` is the normalised 4-vector."""
        ax, ay, az, an = action
        return {
            "progress": prev_potential - potential,
            "control": -0.001 * (ax * ax + ay * ay + az * az + an * an),
            "visibility": ops.where(fov_violation, -0.01, 0.0),
            "success": ops.where(docked, 10.0, 0.0),
            "failure": ops.where(failed, -10.0, 0.0),
        }

    @staticmethod
    def state_observation(truth: dict, current, ops) -> list:
        """The privileged ``state`` observation's 16 entries (see the env's docstring)."""
        roll, pitch, yaw = truth["euler"]
        return [*truth["position"], roll, pitch, ops.cos(yaw), ops.sin(yaw),
                *truth["velocity"], *current]

    @staticmethod
    def sensor_readings(truth: dict, noise, stds, mod=operator.mod) -> tuple[tuple, tuple]:
        """DVL/INS readings: ``(u, v, w, r)`` and ``(roll, pitch, yaw)`` (yaw wrapped).

        Args:
            truth: from :meth:`kinematics`.
            noise: 7 standard normals (velocity 3, yaw rate, attitude 3), or
                None for exact readings.
            stds: ``(velocity, yaw rate, attitude)`` noise standard deviations.
            mod: the wrap's remainder (:func:`~auv_envs.core.frames.wrap_angle`).
        """
        u, v, w, _, _, r = truth["velocity"]
        roll, pitch, yaw = truth["euler"]
        if noise is not None:
            n0, n1, n2, n3, n4, n5, n6 = noise
            s_v, s_r, s_a = stds
            u, v, w, r = u + s_v * n0, v + s_v * n1, w + s_v * n2, r + s_r * n3
            roll, pitch, yaw = roll + s_a * n4, pitch + s_a * n5, yaw + s_a * n6
        return (u, v, w, r), (roll, pitch, frames.wrap_angle(yaw, mod))
