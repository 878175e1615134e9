"""Where a docking ``image`` step's time goes, at two image sizes, and what 4x would need.

The target asks for ``image`` steps at 84x84 to run >= 4x as fast as at
320x240. One env per size, in one process, steps through the same seeded
random actions, passes alternating between the sizes so both see the machine
in the same minute. MuJoCo's own calls are timed as the step makes them
(wrapped for the run, restored after):

* **frame**: ``mjr_render`` plus ``mjr_readPixels`` (under a software
  rasteriser the read-back waits for the drawing);
* **rest of the draw**: the renderer's other work for the frame (making its
  context current, ``mjv_updateScene``, the coarser levels' swap, the copy
  out of the buffer);
* **physics**: ``mj_step`` (the hull force's callback included);
* **rest of the step**: everything else (the task's rules, lines of sight,
  reward, observation, Gymnasium's wrappers).

Prints the median of each part over the passes, in microseconds a step, and
the bound: the 84x84 step would have to cost at most a quarter of the
320x240 one.

    python benchmarks/image_step_cost.py [--env auv_envs/DockingStation-v2] [--steps 500]
        [--passes 7] [--sizes 84x84 320x240]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from collections import defaultdict

import gymnasium as gym
from throughput import Stepper  # benchmarks/ is the script's path

import auv_envs  # noqa: F401  (registers the ids; chooses the GL backend before mujoco loads)
from auv_envs.core.rendering import CameraRenderer
from auv_envs.record import parse_image_size

#: The calls timed, by the part they are counted in.
TIMED = {"mjr_render": "frame", "mjr_readPixels": "frame", "mj_step": "physics"}


@contextlib.contextmanager
def timed_calls(seconds: defaultdict):
    """Within the block, add each timed call's duration to ``seconds[part]``."""
    import mujoco  # after auv_envs, which picks the GL backend

    originals = {name: getattr(mujoco, name) for name in TIMED}
    original_render = CameraRenderer.render

    def timer(function, part):
        def call(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                seconds[part] += time.perf_counter() - start
        return call

    try:
        for name, part in TIMED.items():
            setattr(mujoco, name, timer(originals[name], part))
        CameraRenderer.render = timer(original_render, "draw")
        yield
    finally:
        for name, function in originals.items():
            setattr(mujoco, name, function)
        CameraRenderer.render = original_render


def step_costs(env_id: str, sizes, steps: int, passes: int) -> dict:
    """``{size: {part: [us a step, one per pass]}}``, the sizes' passes alternating."""
    envs, steppers = {}, {}
    try:
        for size in sizes:
            envs[size] = gym.make(env_id, obs_mode="image", image_size=size)
            steppers[size] = Stepper(envs[size], steps)
        costs = {size: defaultdict(list) for size in sizes}
        for pass_index in range(passes + 1):  # the first pass warms up and is not kept
            for size, stepper in steppers.items():
                seconds = defaultdict(float)
                with timed_calls(seconds):
                    total = steps / stepper.rate()
                if pass_index == 0:
                    continue
                parts = {
                    "step": total,
                    "frame": seconds["frame"],
                    "rest of the draw": seconds["draw"] - seconds["frame"],
                    "physics": seconds["physics"],
                    "rest of the step": total - seconds["draw"] - seconds["physics"],
                }
                for part, value in parts.items():
                    costs[size][part].append(value / steps * 1e6)
        return costs
    finally:
        for env in envs.values():
            env.close()


def report(env_id: str, costs: dict) -> str:
    """The markdown table of median costs and the 4x bound."""
    (small, small_costs), (large, large_costs) = costs.items()
    names = [f"{w}x{h}" for w, h in (small, large)]
    median = {size: {part: statistics.median(values) for part, values in parts.items()}
              for size, parts in costs.items()}
    lines = [f"{env_id}, us a step (median of {len(small_costs['step'])} passes)", "",
             f"| part | {names[0]} | {names[1]} | ratio |", "|---|---|---|---|"]
    for part in small_costs:
        a, b = median[small][part], median[large][part]
        lines.append(f"| {part} | {a:.0f} | {b:.0f} | {b / a:.2f} |")
    step_small, step_large = median[small]["step"], median[large]["step"]
    frame_small, frame_large = median[small]["frame"], median[large]["frame"]
    fixed_small = frame_small + median[small]["physics"]
    lines += [
        "",
        f"steps/s: {1e6 / step_small:,.0f} at {names[0]}, {1e6 / step_large:,.0f} at "
        f"{names[1]}; ratio {step_large / step_small:.2f}.",
        f"The frames alone: ratio {frame_large / frame_small:.2f}.",
        f"4x would need the {names[0]} step to cost <= {step_large / 4:.0f} us (a quarter "
        f"of {step_large:.0f}); its frame and physics alone cost {fixed_small:.0f} us, "
        f"leaving {step_large / 4 - fixed_small:.0f} us for all else (now "
        f"{step_small - fixed_small:.0f}).",
    ]
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="auv_envs/DockingStation-v2")
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--passes", type=int, default=7)
    parser.add_argument("--sizes", type=parse_image_size, nargs=2,
                        default=[(84, 84), (320, 240)], metavar="WxH")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.passes < 1:
        parser.error("--steps and --passes must be at least 1")
    if args.sizes[0] == args.sizes[1]:
        parser.error("--sizes: give two different sizes")
    print(report(args.env, step_costs(args.env, args.sizes, args.steps, args.passes)))


if __name__ == "__main__":
    main()
