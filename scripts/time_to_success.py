"""When did a ``train.py`` run first reach a success rate on fresh seeds? Its checkpoints.

Each checkpoint of the run (``train.py --set checkpoint_freq=N --set
keep_checkpoints=K`` keeps them) is loaded as the policy it was at that step
(the model and its frozen ``VecNormalize`` statistics) and run
deterministically on ``--episodes`` seeds from ``--first-seed`` (default:
300000, seeds no training or leaderboard run uses) at ``--difficulty``. It
prints the training steps, the training wall time recorded in the checkpoint
and the success, and the first checkpoint at or above ``--target``: issue
21's reference for the compiled PPO's wall time.

    python scripts/time_to_success.py RUN_DIR [--difficulty paper] [--episodes 20]
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import gymnasium as gym
import yaml

import auv_envs  # noqa: F401
from baselines.rl.checkpoint import MODEL, STATE
from baselines.rl.policy import PolicyAgent, load_model


def checkpoint_success(run: Path, checkpoint: Path, difficulty: str, seeds) -> tuple:
    """``(steps, wall time s, successes)`` of one checkpoint on ``seeds``."""
    resolved = yaml.safe_load((run / "config.yml").read_text())
    with open(checkpoint / STATE, "rb") as handle:
        state = pickle.load(handle)  # our own checkpoint (train.py wrote it)
    env_id, obs_mode = resolved["env_id"], resolved["run"]["obs_mode"]
    env = gym.make(env_id, obs_mode=obs_mode, difficulty=difficulty)
    agent = PolicyAgent(env, load_model(resolved["algo"], checkpoint / MODEL),
                        state["normalizer"], bool(resolved["run"]["flatten_obs"]))
    successes = 0
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        while True:
            obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
            if terminated or truncated:
                break
        successes += bool(info["episode_metrics"]["success"])
    extra = state["extra"]
    return int(extra["step"]), float(extra["wall_time_s"]), successes


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--difficulty", default="paper")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=300000)
    parser.add_argument("--target", type=float, default=0.9)
    args = parser.parse_args(argv)
    checkpoints = sorted((args.run / "checkpoints").glob("step-*"))
    if not checkpoints:
        parser.error(f"{args.run} has no checkpoints")
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    print("| steps | training wall time s | success |")
    print("|---|---|---|")
    first = None
    for checkpoint in checkpoints:
        steps, wall, successes = checkpoint_success(args.run, checkpoint, args.difficulty, seeds)
        print(f"| {steps} | {wall:.0f} | {successes}/{args.episodes} |", flush=True)
        if first is None and successes >= args.target * args.episodes:
            first = (steps, wall)
    if first is None:
        print(f"no checkpoint reached {args.target:.0%}")
    else:
        print(f"first at or above {args.target:.0%}: {first[0]} steps, {first[1]:.0f} s")


if __name__ == "__main__":
    main()
