"""Where a CPU ``AcousticTracking-v2`` step's time goes, against ``HalfCheetah-v5``'s step.

The target asks every ``measurements`` single env for >= 0.8x HalfCheetah-v5's steps per
second. This script times, alternately in one process (best of ``--repeats`` passes
each, so load on the shared machine hits every row alike):

* ``HalfCheetah-v5``'s step (the reference) and the acoustic env's whole step;
* inside that step, as it runs (clocks around the calls, a few a block): the rig
  (``AcousticPhysics.follow``: MuJoCo's steps and the loop around them), the
  measurement model (``HydrophoneArray.measure``), the rest of the 50-period block
  (``simulate_block`` less those two: the references, the nuisance draws) and the step
  without its block (the observation, ``info``, the action check, the transition's own
  step, the wrappers);
* alone, in a tight loop: the rig's physics in MuJoCo's C (``mj_step``, ``substeps`` a
  period), the measurement model on one block, and the normal variates it draws (as
  many as the block's detections of the source need).

Everything is per step (one step serves one sample period). It prints the ratio now and
the time the 0.8x target leaves for everything but the rig's C and the measurement
model as they run in the env::

    python benchmarks/acoustic_cpu_floor.py [--difficulty easy] [--steps 2000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import mujoco
import numpy as np
from throughput import TARGET, Stepper, best_us  # benchmarks/ is the script's path

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.core.acoustics import ORIGIN_CLUTTER, ORIGIN_EMPTY
from auv_envs.core.difficulty import LEVELS
from auv_envs.tasks.acoustic import transition


class Clock:
    """Seconds spent in a function, summed over its calls (wraps it)."""

    def __init__(self, fn):
        self.fn, self.seconds = fn, 0.0

    def __call__(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start


class ClockedEnv:
    """The acoustic env with clocks around its block's calls (``follow``, ``measure``,
    ``simulate_block``), put back by :meth:`close`."""

    def __init__(self, stepper: Stepper):
        self.stepper, self.inner = stepper, stepper.env.unwrapped
        self.follow = self.inner.physics.follow = Clock(self.inner.physics.follow)
        array = self.inner.params.array
        self.measure = array.measure = Clock(array.measure)
        self._simulate = transition.simulate_block
        self.block = transition.simulate_block = Clock(self._simulate)

    def close(self):
        del self.inner.physics.follow, self.inner.params.array.measure
        transition.simulate_block = self._simulate

    def pass_us(self) -> dict[str, float]:
        """One pass through the stepper's actions: its parts, microseconds a step."""
        for clock in (self.follow, self.measure, self.block):
            clock.seconds = 0.0
        start = time.perf_counter()
        self.stepper.rate()
        total = time.perf_counter() - start
        us = 1e6 / len(self.stepper.actions)
        return {"acoustic step": total * us,
                "in it: the rig (MuJoCo and its loop)": self.follow.seconds * us,
                "in it: the measurement model": self.measure.seconds * us,
                "in it: the rest of the block": (self.block.seconds - self.follow.seconds
                                                 - self.measure.seconds) * us,
                "in it: the step without its block": (total - self.block.seconds) * us}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--difficulty", default="easy", choices=LEVELS,
                        help="the acoustic level (default: easy, the ids' default)")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)

    # Both envs stepped as benchmarks/throughput.py steps them (seeded random actions).
    cheetah = Stepper(gym.make("HalfCheetah-v5"), args.steps)
    stepper = Stepper(gym.make("auv_envs/AcousticTracking-v2", obs_mode="measurements",
                               difficulty=args.difficulty), args.steps)
    env, inner = stepper.env, stepper.env.unwrapped
    for action in stepper.actions[: 3 * transition.BLOCK]:  # a few blocks in: mid-episode
        env.step(action)

    # The parts alone, on copies of the episode's block and rig: the timed env is untouched.
    state, params = inner._episode.state, inner.params
    physics = inner.physics
    model, data = physics.model, mujoco.MjData(physics.model)
    data.qpos[:], data.qvel[:], data.ctrl[:] = (physics.data.qpos, physics.data.qvel,
                                                physics.data.ctrl)
    block = state.block
    rng = np.random.default_rng(0)
    array = params.array
    speed = np.linalg.norm(block.current, axis=1)
    heard = block.heard if block.heard is not None else block.positions
    wander = array.draw_wander(rng, len(block.positions), xp=np)  # None when the level has none
    measure = array.measure

    def measure_block():
        measure(rng, heard, state.plan.clock_offsets, speed, state.plan.sound_speed,
                wander, block.fades, block.nodes, noise_draws=params.noise_draws, xp=np)

    origin = block.measurements.origin
    kept = int(np.count_nonzero(block.measurements.mask))  # detections and false alarms
    # The noise is drawn for the kept detections of the source's paths only.
    paths = int(np.count_nonzero((origin != ORIGIN_EMPTY) & (origin != ORIGIN_CLUTTER)))
    normals = (3, paths, array.n_nodes)
    count = len(block.positions)
    calls = max(args.steps // 50, 4)

    clocked = ClockedEnv(stepper)
    rows: dict[str, float] = {}
    best_pass: dict[str, float] = {}
    try:
        for _ in range(args.repeats):  # alternately: one pass of each, best kept
            rows["HalfCheetah-v5 step"] = min(rows.get("HalfCheetah-v5 step", np.inf),
                                              1e6 / cheetah.rate())
            one = clocked.pass_us()
            if one["acoustic step"] < best_pass.get("acoustic step", np.inf):
                best_pass = one
            alone = {
                "alone: the rig's physics (C)": best_us(
                    lambda: mujoco.mj_step(model, data, nstep=physics.substeps),
                    args.steps, 1),
                "alone: the measurement model": best_us(measure_block, calls, 1, per=count),
                "alone: its normal variates": best_us(
                    lambda: rng.standard_normal(normals, dtype=np.float32), calls, 1,
                    per=count),
            }
            for name, us in alone.items():
                rows[name] = min(rows.get(name, np.inf), us)
    finally:
        clocked.close()
    rows = {**{"HalfCheetah-v5 step": rows.pop("HalfCheetah-v5 step")}, **best_pass, **rows}
    reference = rows["HalfCheetah-v5 step"]
    model_us = rows["alone: the rig's physics (C)"] + rows["in it: the measurement model"]
    print(f"AcousticTracking-v2 measurements at {args.difficulty!r}: {kept} detections in "
          f"a block of {count} periods ({paths} of the source's paths); the rig "
          f"{physics.substeps} physics steps a period\n")
    print("| part | µs a step |")
    print("|---|---|")
    for name, us in rows.items():
        print(f"| {name} | {us:.1f} |")
    print(f"\nratio now: {reference / rows['acoustic step']:.2f}. The {TARGET}x target: "
          f"{reference / TARGET:.1f} µs a step, of which the rig's C and the measurement "
          f"model as it runs in the env take {model_us:.1f}; the rest has "
          f"{reference / TARGET - model_us:.1f} µs and takes "
          f"{rows['acoustic step'] - model_us:.1f} now")


if __name__ == "__main__":
    main()
