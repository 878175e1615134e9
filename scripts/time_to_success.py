"""When did a training run first reach a success rate on fresh seeds? Its checkpoints.

Each checkpoint is loaded as the policy it was at that step and run
deterministically on ``--episodes`` seeds from ``--first-seed`` (default:
300000, seeds no training or leaderboard run uses) at ``--difficulty``. It
prints the training steps, the training wall time recorded with the
checkpoint and the success, and the first checkpoint at or above
``--target``: the figure that compares the compiled PPO's wall time with
Stable-Baselines3's. Two kinds of run:

* a ``train.py`` run (``--set checkpoint_freq=N --set keep_checkpoints=K``
  keeps its checkpoints): each is the model and its frozen ``VecNormalize``
  statistics;
* a compiled-PPO run (``python train.py --algo cppo ... --set checkpoints=true``):
  each of ``RUN_DIR/checkpoints/step_<N>`` is a policy directory, and
  ``RUN_DIR/final`` is the last.

    python scripts/time_to_success.py RUN_DIR [--difficulty paper] [--episodes 20]
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import gymnasium as gym
import yaml

import auv_envs  # noqa: F401
from baselines.rl.agents import evaluation_env_kwargs, load_policy_agent
from baselines.rl.checkpoint import MODEL, STATE
from baselines.rl.envs import front_ends_of
from baselines.rl.policy import PolicyAgent, load_model, read_manifest


def train_py_checkpoint(run: Path, checkpoint: Path, difficulty: str) -> tuple:
    """``(steps, wall time s, env, agent)`` of one ``train.py`` checkpoint."""
    resolved = yaml.safe_load((run / "config.yml").read_text())
    with open(checkpoint / STATE, "rb") as handle:
        state = pickle.load(handle)  # our own checkpoint (train.py wrote it)
    env_id, obs_mode = resolved["env_id"], resolved["run"]["obs_mode"]
    env = gym.make(env_id, obs_mode=obs_mode, difficulty=difficulty,
                   **evaluation_env_kwargs(resolved["run"]["env_kwargs"]))
    agent = PolicyAgent(env, load_model(resolved["algo"], checkpoint / MODEL),
                        state["normalizer"], bool(resolved["run"]["flatten_obs"]),
                        front_ends_of(resolved["run"]))
    extra = state["extra"]
    return int(extra["step"]), float(extra["wall_time_s"]), env, agent


def policy_checkpoint(directory: Path, difficulty: str) -> tuple:
    """``(steps, wall time s, env, agent)`` of one policy directory (its manifest's)."""
    manifest = read_manifest(directory)
    env = gym.make(manifest["env_id"], obs_mode=manifest["obs_mode"], difficulty=difficulty,
                   **evaluation_env_kwargs(manifest.get("env_kwargs")))
    agent = load_policy_agent(directory, env)
    return int(manifest["n_timesteps"]), float(manifest["wall_time_s"]), env, agent


def successes(env, agent, seeds) -> int:
    """Episodes of ``seeds`` that end in success."""
    count = 0
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        while True:
            obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
            if terminated or truncated:
                break
        count += bool(info["episode_metrics"]["success"])
    return count


def checkpoint_loaders(run: Path, difficulty: str) -> list:
    """One loader per checkpoint of ``run``, in training order."""
    train_py = sorted((run / "checkpoints").glob("step-*"))
    if train_py:
        return [lambda c=c: train_py_checkpoint(run, c, difficulty) for c in train_py]
    compiled = [*(run / "checkpoints").glob("step_*"), run / "final", run]
    compiled = [c for c in compiled if (c / "policy.json").is_file()]
    compiled.sort(key=lambda c: read_manifest(c)["n_timesteps"])
    return [lambda c=c: policy_checkpoint(c, difficulty) for c in compiled]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--difficulty", default="paper")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=300000)
    parser.add_argument("--target", type=float, default=0.9)
    args = parser.parse_args(argv)
    loaders = checkpoint_loaders(args.run, args.difficulty)
    if not loaders:
        parser.error(f"{args.run} has no checkpoints")
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    print("| steps | training wall time s | success |")
    print("|---|---|---|")
    first = None
    for load in loaders:
        steps, wall, env, agent = load()
        count = successes(env, agent, seeds)
        env.close()
        print(f"| {steps} | {wall:.0f} | {count}/{args.episodes} |", flush=True)
        if first is None and count >= args.target * args.episodes:
            first = (steps, wall)
    if first is None:
        print(f"no checkpoint reached {args.target:.0%}")
    else:
        print(f"first at or above {args.target:.0%}: {first[0]} steps, {first[1]:.0f} s")


if __name__ == "__main__":
    main()
