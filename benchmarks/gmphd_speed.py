"""Per-step cost of the seed 004 tracking agents on AcousticTracking-v0.

Times ``agent.act`` alone (the environment step is excluded) on Q = 10 bands
with the default clutter, after a warm-up, and prints ms/step.

    PYTHONPATH=. python benchmarks/gmphd_speed.py [--steps 2000] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym

import auv_envs  # noqa: F401
from baselines.registry import make_agent

AGENTS = ("gmphd-gci", "gmphd-single", "ls-kf")


def time_agent(name: str, steps: int, seed: int) -> float:
    """Mean wall time of ``act`` in ms over ``steps`` steps (after 100 warm-up steps)."""
    env = gym.make("auv_envs/AcousticTracking-v0", time_limit=(steps + 200) / 100.0)
    agent = make_agent(name, env)
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    total = 0.0
    for k in range(steps + 100):
        t0 = time.perf_counter()
        action = agent.act(obs, info)
        if k >= 100:
            total += time.perf_counter() - t0
        obs, _, _, _, info = env.step(action)
    return 1000.0 * total / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for name in AGENTS:
        print(f"{name:13s} {time_agent(name, args.steps, args.seed):6.2f} ms/step")


if __name__ == "__main__":
    main()
