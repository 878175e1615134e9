"""Env steps per second for every environment and observation mode.

Prints each figure beside Gymnasium's ``HalfCheetah-v5`` measured in the same
run (these machines are noisy, so only the ratio means much). Targets
(issues 2 and 4): every non-image mode (``state``, ``features``,
``measurements``) >= 0.5x HalfCheetah-v5 per env step; docking ``image`` at
320x240 >= 100 steps/s. Stereo rendering has its own benchmark
(``benchmarks/lars_speed.py``); here it is reported at 320x240 without a target.

    python benchmarks/throughput.py [--steps N] [--repeats R] [--envs ID ...]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402

import auv_envs  # noqa: E402

IMAGE_MODES = ("image", "stereo")


def declared_obs_modes(env_id: str) -> tuple[str, ...]:
    """The observation modes an environment class declares (its ``obs_modes``)."""
    return tuple(auv_envs.env_class(env_id).obs_modes)


def steps_per_second(env: gym.Env, n_steps: int, repeats: int) -> float:
    """Best of ``repeats`` timed runs of ``n_steps`` steps with random actions."""
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(n_steps)]
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
    parser.add_argument("--envs", nargs="+", default=list(auv_envs.ENVIRONMENTS),
                        choices=list(auv_envs.ENVIRONMENTS), metavar="ID")
    args = parser.parse_args(argv)

    reference_env = gym.make("HalfCheetah-v5")
    reference = steps_per_second(reference_env, args.steps, args.repeats)
    reference_env.close()
    print(f"HalfCheetah-v5 reference: {reference:,.0f} steps/s\n")
    print("| env | obs_mode | steps/s | ratio to HalfCheetah-v5 | target | met |")
    print("|---|---|---|---|---|---|")
    for env_id in args.envs:
        for mode in declared_obs_modes(env_id):
            image = mode in IMAGE_MODES
            kwargs = {"image_size": (320, 240)} if image else {}
            n = max(200, args.steps // 10) if image else args.steps
            env = gym.make(env_id, obs_mode=mode, **kwargs)
            rate = steps_per_second(env, n, args.repeats)
            env.close()
            ratio = rate / reference
            if mode == "stereo":
                target, met = "see lars_speed.py", None
            elif mode == "image":
                target, met = "100 steps/s @320x240", rate >= 100
            else:
                target, met = "0.5x", ratio >= 0.5
            print(f"| {env_id} | {mode} | {rate:,.0f} | {ratio:.2f} | {target} "
                  f"| {'-' if met is None else 'yes' if met else 'NO'} |")


if __name__ == "__main__":
    main()
