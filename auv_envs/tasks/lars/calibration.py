"""What an agent may know about the LARS capture task: :class:`LARSCalibration`.

The stereo rig and its hand-eye transforms, the arm's kinematics and
dynamics, the marker and the AUV, the success tolerances and the workspace,
read-only ([LTAT] eq. 3 for the hand-eye transforms, eqs. 29-30 for the arm).
The task (:mod:`auv_envs.tasks.lars.env`) builds it; agents read it as
``env.unwrapped.calibration``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from auv_envs.core.ops import FLOATS
from auv_envs.tasks.lars.arm import ArmModel
from auv_envs.tasks.lars.scene import MarkerGeometry
from auv_envs.tasks.lars.sea import LARSSeaModel
from auv_envs.tasks.lars.stereo import StereoRig


@dataclasses.dataclass(frozen=True)
class CaptureTolerances:
    """Success: the capture tip within ``position`` (m) of the AUV's capture
    point with a relative speed below ``speed`` (m/s). The paper's final
    capture error was about 28 mm ([LTAT], §3)."""

    position: float = 0.05
    speed: float = 0.25


@dataclasses.dataclass(frozen=True)
class LARSCalibration:
    """What a classical agent may know (read-only; arrays are not writeable).

    Attributes:
        stereo: the rectified stereo pair (intrinsics of both cameras, baseline).
        left_in_end, right_in_end: (4, 4) hand-eye transforms: pose of each
            camera (OpenCV axes) in the arm-end frame ([LTAT], eq. 3's
            ``t_c H``).
        capture_tip_in_end: (3,) the capture device's tip in the arm-end frame.
        arm: kinematics (forward, inverse, Jacobian) and dynamics M(q),
            C(q, qd), G(q) of the arm (eq. 29).
        control_period: seconds per env step.
        torque_limits: (3,) N m that scale the normalised torque action.
        joint_limits: (3, 2) rad.
        position_gains: (Kp, Kd) of the ``position`` inner loop (eq. 30).
        marker: the marker's geometry on the hull (corners in the AUV body
            frame, ``D`` of eq. 4).
        marker_sides: (0.15, 0.4, 0.4) m.
        capture_point_body: (3,) the AUV's lifting eye in its body frame.
        auv_length, auv_diameter, auv_mass: Explore-100-like AUV (Table 1).
        auv_freeboard: height of the hull's top line above the local water
            level, m (the AUV floats this proud).
        tolerances: success tolerances.
        workspace: (3, 2) box the arm end must stay inside, in the ship's
            frame (the world frame unless a ``sea`` moves the ship).
        pixel_noise_std: std of the ``features`` pixel noise, px.
        sea: the irregular-sea model (spectrum, AUV and ship responses,
            wash-over and analog settings) of an env built with ``sea=``;
            None otherwise.
    """

    stereo: StereoRig
    left_in_end: np.ndarray
    right_in_end: np.ndarray
    capture_tip_in_end: np.ndarray
    arm: ArmModel
    control_period: float
    torque_limits: np.ndarray
    joint_limits: np.ndarray
    position_gains: tuple[float, float]
    marker: MarkerGeometry
    marker_sides: tuple[float, float, float]
    capture_point_body: np.ndarray
    auv_length: float
    auv_diameter: float
    auv_mass: float
    auv_freeboard: float
    tolerances: CaptureTolerances
    workspace: np.ndarray
    pixel_noise_std: float
    sea: LARSSeaModel | None = None

    def end_pose(self, q) -> np.ndarray:
        """World pose (4, 4) of the levelled arm-end frame at joint angles ``q``."""
        out = np.eye(4)
        out[:3, :3] = self.arm.end_rotation(q, FLOATS)
        out[:3, 3] = self.arm.forward_kinematics(q)
        return out

    def camera_poses(self, q) -> tuple[np.ndarray, np.ndarray]:
        """World poses (4, 4) of the left and right cameras (OpenCV axes) at ``q``.

        Forward kinematics composed with the hand-eye transforms ([LTAT], eq. 3).
        """
        end = self.end_pose(q)
        return end @ self.left_in_end, end @ self.right_in_end


def read_only(values) -> np.ndarray:
    """A float array copy of ``values`` that cannot be written."""
    out = np.array(values, dtype=float)
    out.setflags(write=False)
    return out


def read_only_pose(rotation: np.ndarray, translation) -> np.ndarray:
    """The (4, 4) homogeneous pose of ``rotation`` and ``translation``, not writeable."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    out.setflags(write=False)
    return out
