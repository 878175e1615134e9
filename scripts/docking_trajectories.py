"""A digest of seeded docking trajectories: run it on two commits to show they agree bit for bit.

    python scripts/docking_trajectories.py [--steps 250] [--ids ID ...] [--modes MODE ...]

By default plays both docking layouts (and the ``-v0`` plant), ``state`` and ``features``, every
``difficulty`` level and both scenarios, seeds 1-3, with the same random actions
(uniform in [-1.3, 1.3], so clipping is exercised) for up to ``--steps`` steps: 108
trajectories. Every observation, reward, end flag and ``info`` entry (the episode
summary included) is hashed in order; the script prints the SHA-256 per
(id, mode) and of everything. A refactoring that claims to leave the environments
unchanged must leave the digest unchanged. The navigation modes and the mission:

    python scripts/docking_trajectories.py --ids auv_envs/DockingStation-v2 \
        auv_envs/LampArrayDocking-v2 auv_envs/DockingMission-v0 --modes nav nav_features

(and ``--ids auv_envs/DockingMission-v0 --modes state features`` for the mission's others).
"""

from __future__ import annotations

import argparse
import hashlib
import warnings

import gymnasium as gym
import numpy as np

import auv_envs  # noqa: F401

IDS = ("auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2", "auv_envs/DockingStation-v0")


def _feed(digest, value) -> None:
    """Hash ``value`` with its structure and types (dict keys in order, arrays by bytes)."""
    if isinstance(value, dict):
        for key, item in value.items():
            digest.update(f"<{key}>".encode())
            _feed(digest, item)
    elif isinstance(value, list | tuple):
        digest.update(f"[{type(value).__name__}{len(value)}".encode())
        for item in value:
            _feed(digest, item)
    elif isinstance(value, np.ndarray):
        digest.update(f"{value.dtype}{value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    else:
        digest.update(f"{type(value).__name__}:{value!r}".encode())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=250)
    parser.add_argument("--ids", nargs="+", default=IDS, help="environment ids")
    parser.add_argument("--modes", nargs="+", default=("state", "features"),
                        help="observation modes")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*out of date")
    total = hashlib.sha256()
    for env_id in args.ids:
        for mode in args.modes:
            digest = hashlib.sha256()
            for level in ("easy", "paper", "hard"):
                for scenario in ("mismatch", "current"):
                    env = gym.make(env_id, obs_mode=mode, difficulty=level, scenario=scenario)
                    rng = np.random.default_rng(7)
                    for seed in (1, 2, 3):
                        _feed(digest, env.reset(seed=seed))
                        for _ in range(args.steps):
                            step = env.step(rng.uniform(-1.3, 1.3, 4))
                            _feed(digest, step)
                            if step[2] or step[3]:
                                break
                    env.close()
            print(f"{env_id} {mode}: {digest.hexdigest()}")
            total.update(digest.digest())
    print(f"all: {total.hexdigest()}")


if __name__ == "__main__":
    main()
