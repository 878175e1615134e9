"""Scripted reference controller for the docking tasks: PD on the privileged state.

It proves the task is solvable and anchors the leaderboard between the random
agent and the paper baselines. It reads only the ``state`` observation and the
documented calibration (target, thrust limits, nominal net buoyancy).

Guidance: hold heading 0 and drive the lateral/vertical errors to zero while
closing the distance along the docking axis at a speed that shrinks while the
vehicle is off the axis; the heave command feeds the nominal model's net
buoyancy forward.
"""

from __future__ import annotations

import math

import numpy as np

import auv_envs
from auv_envs.core.frames import rotation_from_euler
from baselines.registry import AgentSpec, register_agent

#: Every registered id served by the docking task module.
DOCKING_ENV_IDS = tuple(
    env_id
    for env_id, entry_point in auv_envs.ENVIRONMENTS.items()
    if entry_point.startswith("auv_envs.tasks.docking:")
)


class DockingPDAgent:
    """PD position/heading controller in the DS frame, output in the body frame.

    Args:
        env: an unwrapped docking env with ``obs_mode="state"``.
        kp, kd: translational gains (N/m, N s/m).
        kp_yaw, kd_yaw: heading gains (N m/rad, N m s/rad).
        max_axial_error: clip on the along-axis error (sets approach speed).
    """

    def __init__(self, env, kp=40.0, kd=140.0, kp_yaw=30.0, kd_yaw=60.0, max_axial_error=1.2):
        if env.obs_mode != "state":
            raise ValueError("DockingPDAgent needs obs_mode='state'")
        cal = env.calibration
        self._target = np.asarray(cal.target_position, dtype=float)
        self._limits = np.asarray(cal.thrust_limits, dtype=float)
        self._buoyancy = cal.nominal_params.net_buoyancy
        self._gains = (kp, kd, kp_yaw, kd_yaw, max_axial_error)

    def reset(self, seed: int | None = None) -> None:
        del seed  # deterministic controller

    def act(self, observation, info: dict) -> np.ndarray:
        kp, kd, kp_yaw, kd_yaw, max_axial = self._gains
        obs = np.asarray(observation, dtype=float)
        pos, yaw = obs[0:3], math.atan2(obs[6], obs[5])
        r = obs[12]
        # Heading-only rotation: the guidance treats the vehicle as level.
        rotation = rotation_from_euler(0.0, 0.0, yaw)
        err = self._target - pos
        off_axis = math.hypot(err[1], err[2])
        # Approach along the axis more slowly while far off it.
        axial_limit = max_axial * max(0.15, 1.0 - 2.0 * off_axis)
        err[0] = float(np.clip(err[0], -axial_limit, axial_limit))
        vel_world = rotation @ obs[7:10]
        force_world = kp * err - kd * vel_world
        fx, fy, fz = rotation.T @ force_world
        fz -= self._buoyancy
        yaw_err = -yaw
        torque = kp_yaw * yaw_err - kd_yaw * r
        action = np.array([fx, fy, fz, torque]) / self._limits
        return np.clip(action, -1.0, 1.0).astype(np.float32)


register_agent(
    AgentSpec(
        name="pd-state",
        factory=DockingPDAgent,
        obs_mode="state",
        env_ids=DOCKING_ENV_IDS,
        description="scripted PD on the privileged state (reference controller)",
    )
)
