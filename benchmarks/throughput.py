"""Env steps per second for every environment and observation mode.

Prints each figure beside Gymnasium's ``HalfCheetah-v5`` measured in the same
run (these machines are noisy, so only the ratio means much). Targets
(issue 2): ``state``/``features`` >= 0.5x HalfCheetah-v5 per env step;
``image`` at 320x240 >= 100 steps/s.

    python benchmarks/throughput.py [--steps N] [--repeats R]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import auv_envs  # noqa: E402
from auv_envs.tasks.docking import OBS_MODES  # noqa: E402


def steps_per_second(env: gym.Env, n_steps: int, repeats: int) -> float:
    """Best of ``repeats`` timed runs of ``n_steps`` steps with random actions."""
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(n_steps, *env.action_space.shape)).astype(np.float32)
    best = 0.0
    env.reset(seed=0)
    for _ in range(repeats):
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        best = max(best, n_steps / (time.perf_counter() - start))
    return best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)

    reference_env = gym.make("HalfCheetah-v5")
    reference = steps_per_second(reference_env, args.steps, args.repeats)
    reference_env.close()
    print(f"HalfCheetah-v5 reference: {reference:,.0f} steps/s\n")
    print("| env | obs_mode | steps/s | ratio to HalfCheetah-v5 | target | met |")
    print("|---|---|---|---|---|---|")
    for env_id in auv_envs.ENVIRONMENTS:
        for mode in OBS_MODES:
            kwargs = {"image_size": (320, 240)} if mode == "image" else {}
            n = max(200, args.steps // 10) if mode == "image" else args.steps
            env = gym.make(env_id, obs_mode=mode, **kwargs)
            rate = steps_per_second(env, n, args.repeats)
            env.close()
            ratio = rate / reference
            if mode == "image":
                target, met = "100 steps/s @320x240", rate >= 100
            else:
                target, met = "0.5x", ratio >= 0.5
            print(f"| {env_id} | {mode} | {rate:,.0f} | {ratio:.2f} | {target} "
                  f"| {'yes' if met else 'NO'} |")


if __name__ == "__main__":
    main()
