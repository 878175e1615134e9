"""Two envs stepping in two threads against the same two envs stepped in one thread.

Each family's envs hold no process-global state (``auv_envs.core.plant``), so
two threads step at once wherever MuJoCo releases the GIL (its ``mj_*`` calls
and rendering do). Prints, per env id and mode, the steps per second of two
envs stepped one after the other in one thread and of the same two envs each
in its own thread, measured alternately in one process, and their ratio
(> 1: the threads step faster together). Pure-Python work in a step holds the
GIL, so the gain depends on how much of a step is MuJoCo.

    python benchmarks/threads.py [--steps N] [--repeats R] [--image-size W H]
                                 [--envs ID[:MODE] ...]
"""

from __future__ import annotations

import argparse
import threading
import time

import gymnasium as gym
from throughput import IMAGE_MODES, Stepper  # benchmarks/ is the script's path

import auv_envs  # noqa: F401  (registers the environments)

DEFAULT_ENVS = (
    "auv_envs/DockingStation-v2:features",
    "auv_envs/DockingStation-v2:image",
    "auv_envs/LARSCapture-v0:features",
    "auv_envs/AcousticTracking-v2:measurements",
)
#: Image modes are timed at a small size by default, as an RL pixel agent uses them.
IMAGE_SIZE = (84, 84)


def _make(spec: str, image_size=IMAGE_SIZE) -> gym.Env:
    env_id, _, mode = spec.partition(":")
    kwargs = {"image_size": tuple(image_size)} if mode in IMAGE_MODES else {}
    return gym.make(env_id, obs_mode=mode or "state", **kwargs)


def serial_rate(steppers: list[Stepper]) -> float:
    """Env steps per second of the envs stepped one after the other in this thread."""
    start = time.perf_counter()
    for stepper in steppers:
        stepper.rates()
    return sum(len(s.actions) for s in steppers) / (time.perf_counter() - start)


def threaded_rate(steppers: list[Stepper]) -> float:
    """Env steps per second of the envs each stepped in its own thread, all at once."""
    errors: list = []
    barrier = threading.Barrier(len(steppers) + 1)

    def work(stepper):
        try:
            barrier.wait()
            stepper.rates()
        except BaseException as exc:  # re-raised in the caller
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(s,)) for s in steppers]
    for thread in threads:
        thread.start()
    barrier.wait()
    start = time.perf_counter()
    for thread in threads:
        thread.join()
    elapsed = time.perf_counter() - start
    if errors:
        raise errors[0]
    return sum(len(s.actions) for s in steppers) / elapsed


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000, help="steps per env per pass")
    parser.add_argument("--repeats", type=int, default=3, help="passes of each kind (best kept)")
    parser.add_argument("--image-size", type=int, nargs=2, default=IMAGE_SIZE,
                        metavar=("W", "H"), help="image modes' size (default 84 84)")
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS),
                        help="env ids, each optionally with :MODE (default: state)")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.repeats < 1:
        parser.error("--steps and --repeats must be >= 1")
    print("| env:mode | 1 thread, 2 envs (steps/s) | 2 threads, 1 env each | ratio |")
    print("|---|---|---|---|")
    for spec in args.envs:
        envs = [_make(spec, args.image_size), _make(spec, args.image_size)]
        try:
            steppers = [Stepper(env, args.steps) for env in envs]
            serial, threaded = 0.0, 0.0
            for _ in range(args.repeats):  # alternately, best of each
                serial = max(serial, serial_rate(steppers))
                threaded = max(threaded, threaded_rate(steppers))
        finally:
            for env in envs:
                env.close()
        print(f"| {spec} | {serial:,.0f} | {threaded:,.0f} | {threaded / serial:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
