"""The docking stations' meshes against MuJoCo's own primitives, pixel by pixel.

The image observation draws each station as meshes tessellated from its
primitives (``auv_envs.core.tessellation``), and far parts and lamps with the
coarser meshes of ``auv_envs.core.rendering.DetailLevels``. Here a second
renderer draws the primitives themselves instead (a copy of the model with the two geom groups
swapped, the same round-geom slices), from the vehicle's camera at poses
placed along the approach (``x`` from -6 to 2 m, random lateral offsets and
yaw), and the two images are compared::

    python scripts/station_mesh_check.py [--poses 75] [--sizes 84x84 320x240]

Prints, per layout and size, how many pixels differ by more than
``--levels`` grey levels (max and mean per frame) and how many frames are
bit-identical.
"""

from __future__ import annotations

import argparse
import copy
import math

import numpy as np

import auv_envs  # noqa: F401  (registers the ids; chooses the GL backend before mujoco loads)
from auv_envs.record import parse_image_size

ENV_IDS = ("auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2")


def compare(env_id: str, size: tuple[int, int], poses: int, seed: int = 11,
            levels: int = 8) -> list[tuple[int, bool]]:
    """Per pose: (pixels differing by more than ``levels``, frames bit-identical)."""
    import gymnasium as gym
    import mujoco

    from auv_envs.core.rendering import CameraRenderer
    from auv_envs.tasks.docking.station import STATION_COLLISION_GROUP, VISUAL_GROUP

    env = gym.make(env_id, obs_mode="image", image_size=size)
    physics = env.unwrapped.physics
    model = physics.model
    meshes = model.geom_type == mujoco.mjtGeom.mjGEOM_MESH
    primitives = model.geom_group == STATION_COLLISION_GROUP
    as_primitives = copy.copy(model)
    as_primitives.geom_group[meshes] = STATION_COLLISION_GROUP
    as_primitives.geom_group[primitives] = VISUAL_GROUP
    ours = env.unwrapped.camera_renderer
    # The same groups left out as the observation's renderer (the hull, where unseen).
    reference = CameraRenderer(as_primitives, (physics.camera_name,), *size,
                               hidden_groups=ours.hidden_groups, fit_outlines=True)
    rng = np.random.default_rng(seed)
    out = []
    try:
        env.reset(seed=seed)
        data, adr = physics.data, physics.qpos_adr
        for x in np.linspace(-6.0, 2.0, poses):
            yaw = rng.uniform(-0.4, 0.4)
            data.qpos[adr:adr + 3] = (x, rng.uniform(-0.5, 0.5), rng.uniform(-0.4, 0.4))
            data.qpos[adr + 3:adr + 7] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            mujoco.mj_forward(model, data)
            a = ours.render(data).astype(int)
            b = reference.render(data).astype(int)
            difference = np.abs(a - b).max(axis=-1)
            out.append((int((difference > levels).sum()), bool(difference.max() == 0)))
    finally:
        reference.close()
        env.close()
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=75)
    parser.add_argument("--sizes", nargs="+", type=parse_image_size,
                        default=[(84, 84), (320, 240)], metavar="WxH")
    parser.add_argument("--levels", type=int, default=8)
    args = parser.parse_args(argv)
    if args.poses < 1:
        parser.error("--poses must be positive")
    sizes = args.sizes
    print(f"| env | size | poses | pixels > {args.levels} levels: max | mean | "
          "frames bit-identical |")
    print("|---|---|---|---|---|---|")
    for env_id in ENV_IDS:
        for width, height in sizes:
            rows = compare(env_id, (width, height), args.poses, levels=args.levels)
            counts = [n for n, _ in rows]
            print(f"| {env_id} | {width}x{height} | {len(rows)} | {max(counts)} of "
                  f"{width * height:,} | {np.mean(counts):.2f} | "
                  f"{sum(same for _, same in rows)} |")


if __name__ == "__main__":
    main()
