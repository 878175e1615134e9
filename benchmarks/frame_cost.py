"""What a docking camera frame costs, geom by geom, at two image sizes.

Renders the docking camera's scene (the ``image`` observation's renderer, at
the start of a seeded episode) with only its first ``n`` scene geoms, for
growing ``n``, and times ``mjr_render`` plus ``mjr_readPixels`` (the read-back
waits for the rasteriser), best of ``--repeats`` passes of ``--frames``
frames. Under a software rasteriser (Mesa llvmpipe) the difference between
rows is what those geoms' triangles cost; the first row is the frame's fixed
cost. The image-size target (84x84 >= 4x as fast as 320x240) depends on it. The
scene is drawn as the observation draws it, far parts with their coarser
meshes (``DetailLevels``), unless ``--finest``.

    python benchmarks/frame_cost.py [--env auv_envs/DockingStation-v2] [--frames 200] [--finest]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym

import auv_envs  # noqa: F401  (registers the ids; chooses the GL backend before mujoco loads)


def geom_type_names(mujoco) -> dict[int, str]:
    """Geom type names by MuJoCo's enum value, for the table."""
    return {int(getattr(mujoco.mjtGeom, name)): name.removeprefix("mjGEOM_").lower()
            for name in dir(mujoco.mjtGeom) if name.startswith("mjGEOM_")}


def frame_costs(env_id: str, size: tuple[int, int], frames: int, repeats: int,
                finest: bool = False):
    """``[(n, type of geom n, ms per frame with the first n geoms)]`` for ``n = 0..ngeom``."""
    import mujoco  # after auv_envs, which picks the GL backend

    env = gym.make(env_id, obs_mode="image", image_size=size)
    try:
        env.reset(seed=0)
        unwrapped = env.unwrapped
        renderer, model, data = (unwrapped.camera_renderer, unwrapped.physics.model,
                                 unwrapped.physics.data)
        renderer._gl.make_current()
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, renderer._ctx)
        scene, viewport = renderer._scene, renderer._viewports[0]
        mujoco.mjv_updateScene(model, data, renderer._option, renderer._perturb,
                               renderer._cams[0], mujoco.mjtCatBit.mjCAT_ALL, scene)
        if renderer._detail is not None and not finest:
            renderer._detail.apply(data, renderer._cams[0].fixedcamid, scene)
        total = scene.ngeom
        names = geom_type_names(mujoco)
        types = [names.get(int(scene.geoms[k].type), "?") for k in range(total)]
        rows = []
        for n in range(total + 1):
            scene.ngeom = n
            best = float("inf")
            for _ in range(repeats):
                start = time.perf_counter()
                for _ in range(frames):
                    mujoco.mjr_render(viewport, scene, renderer._ctx)
                    mujoco.mjr_readPixels(renderer._buffer, None, renderer._full, renderer._ctx)
                best = min(best, (time.perf_counter() - start) / frames)
            rows.append((n, types[n - 1] if n else "-", 1e3 * best))
        scene.ngeom = total
        return rows
    finally:
        env.close()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="auv_envs/DockingStation-v2")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--finest", action="store_true",
                        help="draw every geom at its finest (no coarser levels)")
    args = parser.parse_args(argv)
    if args.frames < 1 or args.repeats < 1:
        parser.error("--frames and --repeats must be positive")
    small = frame_costs(args.env, (84, 84), args.frames, args.repeats, args.finest)
    large = frame_costs(args.env, (320, 240), args.frames, args.repeats, args.finest)
    drawing = "finest drawing" if args.finest else "as the observation draws them"
    print(f"{args.env}: ms per frame with the first n scene geoms drawn ({drawing})")
    print("| n | geom n | 84x84 ms | 320x240 ms | ratio |")
    print("|---|---|---|---|---|")
    for (n, kind, a), (_, _, b) in zip(small, large, strict=True):
        print(f"| {n} | {kind} | {a:.3f} | {b:.3f} | {b / a:.2f} |")


if __name__ == "__main__":
    main()
