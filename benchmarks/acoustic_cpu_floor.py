"""Where a CPU ``AcousticTracking-v2`` step's time goes, against ``HalfCheetah-v5``'s step.

Issue 39 asks every ``measurements`` single env for >= 0.8x HalfCheetah-v5's steps per
second. This script times, alternately in one process (best of ``--repeats`` each, so
load on the shared machine hits every row alike):

* ``HalfCheetah-v5``'s step (the reference) and the acoustic env's whole step;
* the parts of the acoustic step that are the model itself, per sample period (one
  step serves one period): the rig's physics (``mj_step``, ``substeps`` a period, in
  MuJoCo's C), the measurement model (``HydrophoneArray.measure`` over a 50-period
  block, divided by 50) and, inside it, the normal variates it draws (NumPy's
  generator, as many as the block's kept detections need);
* the rest: the step's Python around them (what a leaner shell could save), and of it
  the step without its block (the block served again instead of simulating the next:
  the observation, ``info``, the action check, the transition's own step and the
  wrappers).

It prints each part in microseconds a step, the ratio now, and the ceiling: the ratio
the step would reach if everything but the rig's physics and the measurement model
took no time::

    python benchmarks/acoustic_cpu_floor.py [--difficulty paper] [--steps 2000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import mujoco
import numpy as np

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.core.difficulty import LEVELS
from auv_envs.tasks.acoustic import transition


def best_us(fn, calls: int, repeats: int, per: int = 1) -> float:
    """Microseconds of one ``fn()`` divided by ``per``, best of ``repeats`` passes of
    ``calls`` calls."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - start) / calls)
    return best * 1e6 / per


def without_block(env, action, steps: int, repeats: int) -> float:
    """Microseconds of a step whose block is served again instead of simulated (the
    transition's ``simulate_block`` swapped for one that restarts the current block at
    the step, then put back)."""
    simulate = transition.simulate_block

    def again(params, plan, previous, start, backend):
        return simulate(params, plan, previous, start, backend) if previous is None \
            else previous._replace(start=start)

    transition.simulate_block = again
    try:
        env.reset(seed=1)
        inner = env.unwrapped

        def step():
            if inner._episode.done:
                env.reset()
            env.step(action)

        return best_us(step, steps, repeats)
    finally:
        transition.simulate_block = simulate
        env.reset(seed=0)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--difficulty", default="paper", choices=LEVELS)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)

    cheetah = gym.make("HalfCheetah-v5")
    cheetah.reset(seed=0)
    cheetah_action = cheetah.action_space.sample()
    env = gym.make("auv_envs/AcousticTracking-v2", obs_mode="measurements",
                   difficulty=args.difficulty)
    env.action_space.seed(0)
    action = env.action_space.sample()
    env.reset(seed=0)
    inner = env.unwrapped
    for _ in range(3 * transition.BLOCK):  # a few blocks in: a state mid-episode
        env.step(action)

    def env_step():
        if inner._episode.done:
            env.reset()
        env.step(action)

    # The model's parts on copies of the env's episode, so the timed env is untouched.
    state, params = inner._episode.state, inner.params
    physics = inner.physics
    model, data = physics.model, mujoco.MjData(physics.model)
    data.qpos[:], data.qvel[:], data.ctrl[:] = (physics.data.qpos, physics.data.qvel,
                                                physics.data.ctrl)
    substeps = physics.substeps
    block = state.block
    rng = np.random.default_rng(0)
    array = params.array
    speed = np.linalg.norm(block.current, axis=1)
    heard = block.heard if block.heard is not None else block.positions

    wander = array.draw_wander(rng, len(block.positions))  # None when the level has none

    def measure():
        array.measure(rng, heard, state.plan.clock_offsets, speed, state.plan.sound_speed,
                      wander, block.fades, block.nodes, noise_draws=params.noise_draws)

    kept = int(block.measurements.mask.sum())  # detections and false alarms of the block
    normals = (3, kept, array.n_nodes)
    count = len(block.positions)
    rows = {name: float("inf") for name in ("HalfCheetah-v5 step", "acoustic step",
                                            "rig physics", "measurement model",
                                            "its normal variates")}
    calls = max(args.steps // 50, 4)
    for _ in range(args.repeats):  # alternately: one pass of each, best kept
        rows["HalfCheetah-v5 step"] = min(rows["HalfCheetah-v5 step"], best_us(
            lambda: cheetah.step(cheetah_action), args.steps, 1))
        rows["acoustic step"] = min(rows["acoustic step"], best_us(env_step, args.steps, 1))
        rows["rig physics"] = min(rows["rig physics"], best_us(
            lambda: mujoco.mj_step(model, data, nstep=substeps), args.steps, 1))
        rows["measurement model"] = min(rows["measurement model"], best_us(
            measure, calls, 1, per=count))
        rows["its normal variates"] = min(rows["its normal variates"], best_us(
            lambda: rng.standard_normal(normals, dtype=np.float32), calls, 1, per=count))
    rows["step without its block"] = without_block(env, action, args.steps, args.repeats)
    model_us = rows["rig physics"] + rows["measurement model"]
    rest = rows["acoustic step"] - model_us
    reference = rows["HalfCheetah-v5 step"]
    print(f"AcousticTracking-v2 measurements at {args.difficulty!r}: {kept} detections in "
          f"a block of {count} periods; rig {substeps} physics steps a period\n")
    print("| part | us a step |")
    print("|---|---|")
    for name, us in rows.items():
        print(f"| {name} | {us:.1f} |")
    print(f"| the rest of the acoustic step (its Python) | {rest:.1f} |")
    print("(the step without its block is part of the rest)")
    print(f"\nratio now: {reference / rows['acoustic step']:.2f}; ceiling (the rest "
          f"taking no time): {reference / model_us:.2f}; the rest the 0.8x target leaves: "
          f"{reference / 0.8 - model_us:.1f} us")


if __name__ == "__main__":
    main()
