"""Named accessors into the LARS capture model (:func:`auv_envs.tasks.lars.scene.build_lars_model`).

The task (:mod:`auv_envs.tasks.lars.env`) reads and sets the physics only
through :class:`LARSPhysics`: ids resolved by name once, the episode's
initial state restored without clearing all of ``MjData``, the kinematic
bodies (water, crest, head, AUV, analogs) posed for rendering, and the
ship's parts moved with the ship for a render. The arm steps in a model of
its own (the scene without what only a render reads); the scene's model
renders.
"""

from __future__ import annotations

import mujoco
import numpy as np

from auv_envs.core.env import get_physics_state
from auv_envs.tasks.lars.scene import POSED_BODIES


class LARSPhysics:
    """Named accessors into the arm's model/data pair (the dynamics: :attr:`model`,
    :attr:`data`) and the whole scene's (rendering: :attr:`scene_model`,
    :attr:`scene_data`); ids resolved once."""

    def __init__(self, scene_model: mujoco.MjModel, arm_model: mujoco.MjModel):
        self.model = arm_model
        self.data = mujoco.MjData(arm_model)
        self.scene_model = scene_model
        self.scene_data = mujoco.MjData(scene_model)
        self.mocap = {name: int(scene_model.body(name).mocapid[0]) for name in POSED_BODIES}
        self._initial = get_physics_state(arm_model, self.data)  # a new MjData is reset
        # What the ship carries (its hull, the arm's links), for rendering a moving ship.
        model = scene_model
        bodies = [model.body(name).id for name in ("turret", "boom", "jib")]
        self._ship_bodies = np.array(bodies)
        self._ship_geoms = np.array(
            [model.geom("ship").id]
            + [i for i in range(model.ngeom) if model.geom_bodyid[i] in bodies]
        )
        self._ship_sites = np.array([i for i in range(model.nsite)
                                     if model.site_bodyid[i] in bodies])

    def reset(self, q) -> None:
        """The model's initial integration state (time, velocities, warm start,
        controls, applied forces) with joint angles ``q``.

        Restored from a copy rather than by ``mj_resetData``, which clears all
        of MjData and cost several times more in a training loop: the next
        ``mj_step`` is the same, and derived quantities are recomputed by it
        (or by :meth:`refresh_kinematics`) before anything reads them.
        """
        mujoco.mj_setState(self.model, self.data, self._initial,
                           mujoco.mjtState.mjSTATE_INTEGRATION)
        self.data.qpos[:] = q

    def pose(self, name: str, position, quat) -> None:
        """Pose the scene's mocap body ``name`` for rendering."""
        i = self.mocap[name]
        self.scene_data.mocap_pos[i] = position
        self.scene_data.mocap_quat[i] = quat

    def refresh_kinematics(self, ship: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """The scene's positions and cameras for rendering, the arm at its joint angles
        now, without touching the dynamics.

        ``ship``: ``(R, t)`` of the ship's displacement (``p -> R p + t``),
        applied to the ship's hull and the arm's links after the kinematics.
        """
        model, data = self.scene_model, self.scene_data
        data.qpos[:] = self.data.qpos
        mujoco.mj_kinematics(model, data)
        if ship is not None:
            rot, shift = ship
            for pos, mat, ids in (
                (data.xpos, data.xmat, self._ship_bodies),
                (data.geom_xpos, data.geom_xmat, self._ship_geoms),
                (data.site_xpos, data.site_xmat, self._ship_sites),
            ):
                pos[ids] = pos[ids] @ rot.T + shift
                mat[ids] = (rot @ mat[ids].reshape(-1, 3, 3)).reshape(-1, 9)
        mujoco.mj_camlight(model, data)
