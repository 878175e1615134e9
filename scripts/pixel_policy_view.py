"""What a pixel policy sees: its camera images through one seeded episode per level.

    python scripts/pixel_policy_view.py [--agent distill-docking-image-s0] [--seed 100000]
        [--levels paper hard] [--frames 6] [--out docs/images/pixel_policy_view.png]

One row per difficulty level: the agent's own ``image`` observations (drawn
pixel for pixel, without smoothing) at evenly spaced steps of the episode it
acts in, each titled with the time, the distance to the entrance and the
lights in view; the row is labelled with the episode's outcome.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import auv_envs  # noqa: E402,F401  (registers the ids)
from auv_envs.core.difficulty import LEVELS  # noqa: E402
from baselines.registry import agent_spec, make_agent  # noqa: E402


def episode_frames(agent_name: str, level: str, seed: int) -> tuple[list, list, dict]:
    """The agent's image observations, their step infos and the episode's metrics."""
    spec = agent_spec(agent_name)
    if spec.obs_mode != "image":
        raise ValueError(f"{agent_name} acts on {spec.obs_mode!r}, not on images")
    env = gym.make(spec.env_ids[0], obs_mode="image", difficulty=level, **spec.env_kwargs)
    try:
        agent = make_agent(agent_name, env)
        observation, info = env.reset(seed=seed)
        agent.reset(seed)
        frames, infos = [observation["image"]], [info]
        while True:
            observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
            frames.append(observation["image"])
            infos.append(info)
            if terminated or truncated:
                return frames, infos, info["episode_metrics"]
    finally:
        env.close()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agent", default="distill-docking-image-s0")
    parser.add_argument("--seed", type=int, default=100_000)
    parser.add_argument("--levels", nargs="+", default=["paper", "hard"], choices=LEVELS)
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--out", type=Path, default=Path("docs/images/pixel_policy_view.png"))
    args = parser.parse_args(argv)
    if args.frames < 2:
        parser.error("--frames must be at least 2")
    figure, axes = plt.subplots(len(args.levels), args.frames, squeeze=False,
                                figsize=(2.2 * args.frames, 2.5 * len(args.levels)))
    for row, level in zip(axes, args.levels, strict=True):
        frames, infos, metrics = episode_frames(args.agent, level, args.seed)
        last = len(frames) - 1
        for axis, k in zip(row, [round(i * last / (args.frames - 1))
                                 for i in range(args.frames)], strict=True):
            info = infos[k]
            axis.imshow(frames[k], interpolation="nearest")
            axis.set_title(f"t {info['time']:.1f} s, {info['distance_to_entrance']:.1f} m\n"
                           f"{int(info['lights_visible'])} lights in line of sight", fontsize=8)
            axis.set_xticks([])
            axis.set_yticks([])
        outcome = "docked" if metrics["success"] else f"failed ({metrics['failure_reason']})"
        row[0].set_ylabel(f"{level}: {outcome}", fontsize=9)
    height, width = frames[0].shape[:2]
    figure.suptitle(f"{args.agent}: its {width}x{height} camera images, seed {args.seed}",
                    fontsize=10)
    figure.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
