"""Docking ``image`` steps per second with and without the coarser drawings of far parts.

One env per layout and size steps through the same seeded random actions,
passes alternating between the camera renderer's ``DetailLevels`` on (as
shipped) and off (every geom at its finest drawing), so both halves of each
pair see the machine in the same minute. Prints each pass and the ratio of
the medians::

    python benchmarks/detail_speed.py [--steps 400] [--pairs 6] [--sizes 84x84 320x240]
"""

from __future__ import annotations

import argparse
import statistics

import gymnasium as gym
from throughput import Stepper  # benchmarks/ is the script's path

import auv_envs  # noqa: F401  (registers the ids; chooses the GL backend before mujoco loads)
from auv_envs.record import parse_image_size

ENV_IDS = ("auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2")


def paired_rates(env_id: str, size: tuple[int, int], steps: int, pairs: int):
    """``(rates with the levels, rates without)``, steps/s, one per pass."""
    env = gym.make(env_id, obs_mode="image", image_size=size)
    try:
        renderer = env.unwrapped.camera_renderer
        levels = renderer._detail
        if levels is None:
            raise RuntimeError(f"{env_id}: its image renderer draws no coarser levels")
        stepper = Stepper(env, steps)
        with_levels, without = [], []
        for _ in range(pairs):
            renderer._detail = levels
            with_levels.append(stepper.rate())
            renderer._detail = None
            without.append(stepper.rate())
        renderer._detail = levels
        return with_levels, without
    finally:
        env.close()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--pairs", type=int, default=6)
    parser.add_argument("--sizes", nargs="+", type=parse_image_size,
                        default=[(84, 84), (320, 240)], metavar="WxH")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.pairs < 1:
        parser.error("--steps and --pairs must be positive")
    sizes = args.sizes
    print(f"image steps/s, {args.pairs} alternating pairs of {args.steps} steps")
    print("| env | size | with the levels | finest only | ratio of medians |")
    print("|---|---|---|---|---|")
    for env_id in ENV_IDS:
        for size in sizes:
            on, off = paired_rates(env_id, size, args.steps, args.pairs)
            print(f"| {env_id} | {size[0]}x{size[1]} | {', '.join(f'{r:,.0f}' for r in on)} | "
                  f"{', '.join(f'{r:,.0f}' for r in off)} | "
                  f"{statistics.median(on) / statistics.median(off):.2f} |")


if __name__ == "__main__":
    main()
