"""What the docking plants cost: staged, compiled, and MuJoCo's step with a global callback.

The docking plant steps with :class:`auv_envs.core.plant.StagedIntegrator`
(MuJoCo's RK4 written out, the hull wrench added at every stage, no
process-global state). The reference is what ``-v1`` shipped with before
the staged integrator: MuJoCo's own ``mj_step`` with the same wrench in the global
``mjcb_passive`` callback, installed here only for the timing and removed
after. Both step one docking env's model from the same state with the same
held command, alternately in one process (best of ``--repeats`` each), and
give the same bits. Also timed, alternately with them: ``-v2``'s compiled plant
(:class:`auv_envs.core.plant.FreeBodyPlant`, the same equations compiled by
CasADi, equal to round-off where no contact acts) on the same state and command;
and the wrench alone and ``mj_forward`` alone.

    python benchmarks/plant_cost.py [--steps N] [--repeats R] [--env ID]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import mujoco
from throughput import best_us  # benchmarks/ is the script's path

import auv_envs  # noqa: F401  (registers the environments)
from auv_envs.core.plant import FreeBodyPlant


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--env", default="auv_envs/DockingStation-v2")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.repeats < 1:
        parser.error("--steps and --repeats must be >= 1")
    env = gym.make(args.env, obs_mode="state")
    try:
        unwrapped = env.unwrapped
        env.reset(seed=0)
        physics, hull = unwrapped.physics, unwrapped.hull
        model, data = physics.model, physics.data
        start = (data.qpos.copy(), data.qvel.copy())
        tau, current = (20.0, 5.0, -3.0, 0.0, 0.0, 2.0), (0.1, 0.0, 0.0)
        hull.command(tau, current)

        def reset():
            data.qpos[:], data.qvel[:] = start
            mujoco.mj_forward(model, data)

        def callback_step():
            mujoco.mj_step(model, data)

        compiled_plant = FreeBodyPlant(unwrapped.vehicle, float(model.opt.timestep), 1)
        qpos, qvel = start[0].copy(), start[1].copy()

        def compiled_step():
            compiled_plant.advance(qpos, qvel, tau, current)

        staged, callback, compiled = float("inf"), float("inf"), float("inf")
        for _ in range(args.repeats):  # alternately
            staged = min(staged, best_us(unwrapped.integrator.step, args.steps, 1, reset=reset))
            compiled = min(compiled, best_us(compiled_step, args.steps, 1, reset=reset))
            mujoco.set_mjcb_passive(hull.passive_force)
            try:
                callback = min(callback, best_us(callback_step, args.steps, 1, reset=reset))
            finally:
                mujoco.set_mjcb_passive(None)
        wrench = best_us(lambda: hull.passive_force(model, data), args.steps, args.repeats,
                         reset=reset)
        forward = best_us(lambda: mujoco.mj_forward(model, data), args.steps, args.repeats,
                          reset=reset)
    finally:
        env.close()
    print(f"| {args.env}, one 0.1 s RK4 step | us |")
    print("|---|---|")
    print(f"| StagedIntegrator.step (no global state) | {staged:.1f} |")
    print(f"| mj_step + global mjcb_passive (reference) | {callback:.1f} |")
    print(f"| ratio staged / reference | {staged / callback:.2f} |")
    print(f"| FreeBodyPlant.advance (compiled, -v2 away from contacts) | {compiled:.1f} |")
    print(f"| ratio compiled / staged | {compiled / staged:.2f} |")
    print(f"| hull wrench alone (x4 a step) | {wrench:.1f} |")
    print(f"| mj_forward alone (x4 a step) | {forward:.1f} |")


if __name__ == "__main__":
    main()
