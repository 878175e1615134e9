"""Brax's PPO trains on a batched family through MuJoCo Playground's wrappers, unchanged.

What a JAX RL researcher would write, and nothing else: the functional env from
:func:`auv_envs.batched.load`, Playground's ``wrap_for_brax_training``, Brax's
``ppo.train`` with its default networks. Prints the evaluation reward (the mean return of
``--eval-envs`` episodes of ``episode_length`` steps, Brax's ``eval/episode_reward``) at
each evaluation, with the wall time, so the reward can be seen rising.

    python scripts/brax_ppo.py [--env auv_envs/DockingStation-v2] [--obs-mode state]
        [--timesteps 300000] [--envs 64] [--episode-length 200] [--evals 6] [--seed 0]

The sizes are Brax's example values scaled down for two CPU cores; everything else is
``ppo.train``'s default (networks, learning rate, entropy cost, discounting).
"""

from __future__ import annotations

import argparse
import time

from brax.training.agents.ppo import train as ppo
from mujoco_playground import wrapper

import auv_envs.batched


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="auv_envs/DockingStation-v2")
    parser.add_argument("--obs-mode", default="state")
    parser.add_argument("--difficulty", default=None)
    parser.add_argument("--timesteps", type=int, default=300_000)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--episode-length", type=int, default=200,
                        help="Brax's time limit in steps (the env's own: env.episode_length)")
    parser.add_argument("--evals", type=int, default=6)
    parser.add_argument("--eval-envs", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    kwargs = {"obs_mode": args.obs_mode}
    if args.difficulty is not None:
        kwargs["difficulty"] = args.difficulty
    env = auv_envs.batched.load(args.env, **kwargs)
    print(f"{args.env} {kwargs}: observation {env.observation_size}, action "
          f"{env.action_size}, episode_length {args.episode_length} (the env's "
          f"{env.episode_length})")
    start = time.perf_counter()
    print("| env steps | eval episode reward | wall s |\n|---|---|---|")

    def progress(steps, metrics):
        print(f"| {steps:,} | {float(metrics['eval/episode_reward']):.3f} | "
              f"{time.perf_counter() - start:.0f} |", flush=True)

    ppo.train(environment=env, num_timesteps=args.timesteps,
              episode_length=args.episode_length, wrap_env_fn=wrapper.wrap_for_brax_training,
              num_envs=args.envs, batch_size=args.envs, num_minibatches=4, unroll_length=20,
              num_updates_per_batch=4, num_evals=args.evals, num_eval_envs=args.eval_envs,
              seed=args.seed, progress_fn=progress)


if __name__ == "__main__":
    main()
