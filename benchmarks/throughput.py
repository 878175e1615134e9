"""Env steps per second for every environment and observation mode.

Prints each figure beside Gymnasium's ``HalfCheetah-v5`` measured in the same
run, alternately with the env it is compared to (these machines are shared and
noisy, so only the ratio means much). Targets
(issues 2 and 4): every non-image mode (``state``, ``features``,
``measurements``) >= 0.5x HalfCheetah-v5 per env step; docking ``image`` at
320x240 >= 100 steps/s. Stereo rendering has its own benchmark
(``benchmarks/lars_speed.py``); here it is reported at 320x240 without a target.

    python benchmarks/throughput.py [--steps N] [--repeats R] [--envs ID ...]

The issue's check: ``--steps 2000 --envs auv_envs/DockingStation-v0
auv_envs/LampArrayDocking-v0``.
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


class Stepper:
    """Steps one env through a fixed list of seeded random actions, resetting at episode end."""

    def __init__(self, env: gym.Env, n_steps: int):
        self.env = env
        env.action_space.seed(0)
        self.actions = [env.action_space.sample() for _ in range(n_steps)]
        env.reset(seed=0)

    def rate(self) -> float:
        """Steps per second over one pass through the actions."""
        env = self.env
        start = time.perf_counter()
        for action in self.actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return len(self.actions) / (time.perf_counter() - start)


def steps_per_second(env: gym.Env, n_steps: int, repeats: int) -> float:
    """Best of ``repeats`` timed runs of ``n_steps`` steps with random actions."""
    stepper = Stepper(env, n_steps)
    return max(stepper.rate() for _ in range(repeats))


def paired_rates(subject: Stepper, reference: Stepper, repeats: int) -> tuple[float, float]:
    """Best-of-``repeats`` steps/s of ``subject`` and ``reference``, timed alternately.

    Alternating the two, pass by pass, makes them share the machine's load
    (other processes on a shared machine change it from second to second), so
    their ratio means more than two figures taken a minute apart.
    """
    best_subject = best_reference = 0.0
    for _ in range(repeats):
        best_reference = max(best_reference, reference.rate())
        best_subject = max(best_subject, subject.rate())
    return best_subject, best_reference


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--envs", nargs="+", default=list(auv_envs.ENVIRONMENTS),
                        choices=list(auv_envs.ENVIRONMENTS), metavar="ID")
    args = parser.parse_args(argv)

    reference_env = gym.make("HalfCheetah-v5")
    reference = Stepper(reference_env, args.steps)
    print("Each row times its env and HalfCheetah-v5 alternately "
          f"(best of {args.repeats} passes each; image modes: the reference's best so far).\n")
    print("| env | obs_mode | steps/s | HalfCheetah-v5 steps/s | ratio | target | met |")
    print("|---|---|---|---|---|---|---|")
    best_reference = 0.0
    for env_id in args.envs:
        for mode in declared_obs_modes(env_id):
            image = mode in IMAGE_MODES
            kwargs = {"image_size": (320, 240)} if image else {}
            n = max(200, args.steps // 10) if image else args.steps
            env = gym.make(env_id, obs_mode=mode, **kwargs)
            subject = Stepper(env, n)
            if image:  # its target is absolute; pairing would only slow the run
                rate = max(subject.rate() for _ in range(min(args.repeats, 3)))
                ref_rate = best_reference or max(reference.rate() for _ in range(args.repeats))
            else:
                rate, ref_rate = paired_rates(subject, reference, args.repeats)
            best_reference = max(best_reference, ref_rate)
            env.close()
            ratio = rate / ref_rate
            if mode == "stereo":
                target, met = "see lars_speed.py", None
            elif mode == "image":
                target, met = "100 steps/s @320x240", rate >= 100
            else:
                target, met = "0.5x", ratio >= 0.5
            print(f"| {env_id} | {mode} | {rate:,.0f} | {ref_rate:,.0f} | {ratio:.2f} | {target} "
                  f"| {'-' if met is None else 'yes' if met else 'NO'} |")
    reference_env.close()


if __name__ == "__main__":
    main()
