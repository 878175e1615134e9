"""Env steps per second for every environment and observation mode.

Prints each figure beside Gymnasium's ``HalfCheetah-v5`` measured in the same
run, alternately with the env it is compared to (these machines are shared and
noisy, so only the ratio means much). Targets: every non-image mode
(``state``, ``features``, ``measurements``) >= 0.8x HalfCheetah-v5 per env
step (an earlier target was 0.5x); docking ``image`` at
320x240 >= 100 steps/s. Docking ``image`` is timed at 84x84 and 320x240,
alternately, with their ratio (target: 84x84 >= 4x as fast as 320x240 and
>= 1000 steps/s). Stereo rendering has its own benchmark
(``benchmarks/lars_speed.py``); here it is reported at 320x240 without a target.

    python benchmarks/throughput.py [--steps N] [--repeats R] [--envs ID ...] [--modes M ...]
                                    [--set KEY=VALUE ...]

``--envs`` takes superseded ids too (``auv_envs.PREVIOUS_VERSIONS``, e.g.
``auv_envs/DockingStation-v1``), to time a version against the current one; ``--set``
passes arguments to every env it times (``--set sensors=compiled``: the docking ids'
compiled sensors), each value read as ``train.py --set`` reads it (a Python literal,
else a YAML scalar).

The targets' check: ``--steps 2000 --envs auv_envs/DockingStation-v2
auv_envs/LampArrayDocking-v2``.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import auv_envs
from baselines.registry import env_obs_modes
from baselines.rl.config import ConfigError, parse_overrides

IMAGE_MODES = ("image", "stereo")
#: Steps per second of a non-image mode over HalfCheetah-v5's: the target.
TARGET = 0.8


class Stepper:
    """Steps one env through a fixed list of seeded random actions, resetting at episode end."""

    def __init__(self, env: gym.Env, n_steps: int):
        self.env = env
        env.action_space.seed(0)
        self.actions = [env.action_space.sample() for _ in range(n_steps)]
        env.reset(seed=0)

    def rate(self) -> float:
        """Steps per second (wall clock) over one pass through the actions."""
        return self.rates()[0]

    def rates(self) -> tuple[float, float]:
        """Steps per wall-clock second and per CPU second of this process, over one pass."""
        env = self.env
        start, start_cpu = time.perf_counter(), time.process_time()
        for action in self.actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
        return len(self.actions) / wall, len(self.actions) / cpu


def best_us(fn, calls: int, repeats: int, per: int = 1, reset=None) -> float:
    """Microseconds of one ``fn()`` divided by ``per``, best of ``repeats`` passes of
    ``calls`` calls (``reset()``, when given, before each pass, outside the clock)."""
    best = float("inf")
    for _ in range(repeats):
        if reset is not None:
            reset()
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - start) / calls)
    return best * 1e6 / per


def steps_per_second(env: gym.Env, n_steps: int, repeats: int) -> float:
    """Best of ``repeats`` timed runs of ``n_steps`` steps with random actions."""
    stepper = Stepper(env, n_steps)
    return max(stepper.rate() for _ in range(repeats))


def paired_rates(subject: Stepper, reference: Stepper, repeats: int) -> np.ndarray:
    """Best-of-``repeats`` steps/s of ``subject`` and ``reference``, timed alternately.

    Alternating the two, pass by pass, makes them share the machine's load
    (other processes on a shared machine change it from second to second), so
    their ratio means more than two figures taken a minute apart.

    Returns:
        ``[[subject wall, subject CPU], [reference wall, reference CPU]]``
        steps per second, each the best pass.
    """
    best = np.zeros((2, 2))
    for _ in range(repeats):
        best[1] = np.maximum(best[1], reference.rates())
        best[0] = np.maximum(best[0], subject.rates())
    return best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--envs", nargs="+", default=list(auv_envs.ENVIRONMENTS),
                        choices=[*auv_envs.ENVIRONMENTS, *auv_envs.PREVIOUS_VERSIONS],
                        metavar="ID")
    parser.add_argument("--modes", nargs="+", metavar="MODE",
                        help="only these observation modes (default: every mode)")
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                        help="arguments of every env timed")
    args = parser.parse_args(argv)
    try:
        settings = parse_overrides(args.set)
    except ConfigError as error:
        parser.error(f"--set: {error}")

    reference_env = gym.make("HalfCheetah-v5")
    reference = Stepper(reference_env, args.steps)
    print("Each row times its env and HalfCheetah-v5 alternately "
          f"(best of {args.repeats} passes each; image modes: the reference's best so far).")
    print("steps/s and ratio: wall clock (the target); CPU ratio: per CPU second of this "
          "process, less sensitive to other processes' load.\n")
    print("| env | obs_mode | steps/s | HalfCheetah-v5 steps/s | ratio | CPU ratio | target "
          "| met |")
    print("|---|---|---|---|---|---|---|---|")
    best_reference = 0.0
    small_image_rows = []
    for env_id in args.envs:
        for mode in env_obs_modes(env_id):
            if args.modes and mode not in args.modes:
                continue
            image = mode in IMAGE_MODES
            if mode == "image":
                small_image_rows.append(image_sizes(env_id, max(200, args.steps // 10),
                                                    min(args.repeats, 3)))
            kwargs = {"image_size": (320, 240)} if image else {}
            n = max(200, args.steps // 10) if image else args.steps
            env = gym.make(env_id, obs_mode=mode, **kwargs, **settings)
            subject = Stepper(env, n)
            cpu_ratio = None
            if image:  # its target is absolute; pairing would only slow the run
                rate = max(subject.rate() for _ in range(min(args.repeats, 3)))
                ref_rate = best_reference or max(reference.rate() for _ in range(args.repeats))
            else:
                (rate, cpu_rate), (ref_rate, ref_cpu_rate) = paired_rates(
                    subject, reference, args.repeats
                )
                cpu_ratio = cpu_rate / ref_cpu_rate
            best_reference = max(best_reference, ref_rate)
            env.close()
            ratio = rate / ref_rate
            if mode == "stereo":
                target, met = "see lars_speed.py", None
            elif mode == "image":
                target, met = "100 steps/s @320x240", rate >= 100
            else:
                target, met = f"{TARGET}x", ratio >= TARGET
            cpu = "-" if cpu_ratio is None else f"{cpu_ratio:.2f}"
            print(f"| {env_id} | {mode} | {rate:,.0f} | {ref_rate:,.0f} | {ratio:.2f} | {cpu} "
                  f"| {target} | {'-' if met is None else 'yes' if met else 'NO'} |")
    reference_env.close()
    if small_image_rows:
        print("\n| env | image 84x84 steps/s | image 320x240 steps/s | ratio | target | met |")
        print("|---|---|---|---|---|---|")
        for env_id, small, large in small_image_rows:
            met = small >= 4.0 * large and small >= 1000.0
            print(f"| {env_id} | {small:,.0f} | {large:,.0f} | {small / large:.2f} "
                  f"| >= 4x and >= 1000/s | {'yes' if met else 'NO'} |")


def image_sizes(env_id: str, n_steps: int, repeats: int) -> tuple[str, float, float]:
    """``(env_id, steps/s at 84x84, steps/s at 320x240)`` in ``image`` mode, timed
    alternately (best of ``repeats`` passes each)."""
    envs = [gym.make(env_id, obs_mode="image", image_size=size)
            for size in ((84, 84), (320, 240))]
    steppers = [Stepper(env, n_steps) for env in envs]
    best = [0.0, 0.0]
    for _ in range(repeats):
        for k, stepper in enumerate(steppers):
            best[k] = max(best[k], stepper.rate())
    for env in envs:
        env.close()
    return env_id, best[0], best[1]


if __name__ == "__main__":
    main()
