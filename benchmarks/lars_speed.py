"""LARS capture speed: stereo vs mono render cost, stereo and features env steps/s.

Measured in one run (these machines are noisy, so only same-run ratios mean
much); the single view and the pair are timed in alternating blocks.
Targets: a stereo pair <= 1.3x a single view of the same size;
``stereo`` at 640x480 >= 50 env steps/s; ``features`` >= 0.5x Gymnasium
``HalfCheetah-v5`` env steps/s.

    python benchmarks/lars_speed.py [--steps N] [--repeats R]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
from throughput import steps_per_second  # benchmarks/ is the script's path

import auv_envs  # noqa: F401
from auv_envs.core.env import TaskEnv
from auv_envs.core.rendering import CameraRenderer
from auv_envs.tasks.lars.env import LARSCaptureTask


def render_seconds(env: TaskEnv, views, size, n: int, repeats: int):
    """Best mean wall and CPU seconds per render for each camera tuple in ``views``.

    The renderers are timed in alternating blocks of ``n`` renders (``repeats``
    rounds), so that load drifting during the run affects them alike; CPU time
    is the process's, which includes llvmpipe's rasteriser threads.
    """
    renderers = [CameraRenderer(env.physics.scene_model, cams, *size) for cams in views]
    try:
        env._pose_scene()
        data = env.physics.scene_data
        wall = [float("inf")] * len(views)
        cpu = [float("inf")] * len(views)
        for renderer in renderers:
            renderer.render(data)
        for _ in range(repeats):
            for i, renderer in enumerate(renderers):
                start, start_cpu = time.perf_counter(), time.process_time()
                for _ in range(n):
                    renderer.render(data)
                wall[i] = min(wall[i], (time.perf_counter() - start) / n)
                cpu[i] = min(cpu[i], (time.process_time() - start_cpu) / n)
        return wall, cpu
    finally:
        for renderer in renderers:
            renderer.close()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    size = (640, 480)

    reference_env = gym.make("HalfCheetah-v5")
    reference = steps_per_second(reference_env, args.steps, args.repeats)
    reference_env.close()
    features_env = gym.make("auv_envs/LARSCapture-v0", obs_mode="features")
    features = steps_per_second(features_env, args.steps, args.repeats)
    features_env.close()

    env = TaskEnv(LARSCaptureTask, obs_mode="stereo", image_size=size)
    env.reset(seed=0)
    (mono, pair), (mono_cpu, pair_cpu) = render_seconds(
        env, (("left",), ("left", "right")), size, 20, 3 * args.repeats)
    stereo = steps_per_second(env, 200, args.repeats)
    env.close()

    ratio = pair / mono
    print(f"HalfCheetah-v5 reference: {reference:,.0f} steps/s\n")
    print("| measure | value | target | met |")
    print("|---|---|---|---|")
    print(f"| single view 640x480 | {mono * 1e3:.2f} ms | | |")
    print(f"| stereo pair 640x480 (one buffer) | {pair * 1e3:.2f} ms | | |")
    print(f"| stereo / single | {ratio:.2f}x | <= 1.3x | {'yes' if ratio <= 1.3 else 'NO'} |")
    print(f"| stereo / single, CPU time | {pair_cpu / mono_cpu:.2f}x "
          f"({pair_cpu * 1e3:.2f} / {mono_cpu * 1e3:.2f} ms) | | |")
    print(f"| stereo env 640x480 | {stereo:,.0f} steps/s | >= 50 | "
          f"{'yes' if stereo >= 50 else 'NO'} |")
    print(f"| features env | {features:,.0f} steps/s ({features / reference:.2f}x) | >= 0.5x | "
          f"{'yes' if features >= 0.5 * reference else 'NO'} |")


if __name__ == "__main__":
    main()
