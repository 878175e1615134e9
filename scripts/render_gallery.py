"""The pictures of docs/watching.md: one render of each environment family mid-episode.

    python scripts/render_gallery.py [--out docs/images] [--size 640x480]

Each picture is a seeded episode of a baseline agent, drawn at a fixed
fraction of its length (run once to learn the length, once to render: the
episodes are deterministic).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import imageio.v3 as iio

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.record import parse_size
from baselines.evaluation import run_episode
from baselines.registry import agent_spec

#: file name -> (env id, env arguments, agent, seed, fraction of the episode).
GALLERY = {
    "docking_chase.png": ("auv_envs/DockingStation-v2", {}, "pd-state", 100_000, 0.75),
    "lars_side.png": ("auv_envs/LARSCapture-v0", {"sea_state": "severe"}, "ltat-ckf-pd",
                      100_001, 0.5),
    "acoustic.png": ("auv_envs/AcousticTracking-v2", {"time_limit": 12.0}, "gmphd-gci",
                     100_000, 1.0),
    "lamp_array.png": ("auv_envs/LampArrayDocking-v2", {"render_camera": "onboard"},
                       "pd-state", 100_000, 0.5),
    "mission.png": ("auv_envs/DockingMission-v0", {"render_camera": "onboard"},
                    "homing-pd-state", 100_000, 0.9),
}


def render(env_id: str, kwargs: dict, agent: str, seed: int, fraction: float,
           size: tuple[int, int]):
    """The frame ``fraction`` of the way through the seeded episode of ``agent``."""
    spec = agent_spec(agent)
    arguments = dict(obs_mode=spec.modes_for(env_id)[0], render_mode="rgb_array",
                     render_size=size, **{**spec.env_kwargs, **kwargs})

    def episode(**limit) -> tuple[gym.Env, int]:
        env = gym.make(env_id, **arguments, **limit)
        return env, run_episode(env, spec.factory(env.unwrapped), seed, env_id, agent).length

    env, length = episode()  # the whole episode, for its length
    env.close()
    # The same episode again, cut by gym.make's TimeLimit at the step to draw.
    env, _ = episode(max_episode_steps=max(1, round(fraction * length)))
    try:
        return env.render()
    finally:
        env.close()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/images"))
    parser.add_argument("--size", type=parse_size, default=(640, 480))
    parser.add_argument("--only", nargs="+", choices=sorted(GALLERY), default=None,
                        metavar="FILE", help="render these pictures only (default: all)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for name, (env_id, kwargs, agent, seed, fraction) in GALLERY.items():
        if args.only and name not in args.only:
            continue
        iio.imwrite(args.out / name, render(env_id, kwargs, agent, seed, fraction, args.size))
        print(args.out / name)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
