"""The corridor teacher (``homing-pd-corridor``) acting in the CPU docking mission.

The distillation's teacher (:class:`baselines.rl.teachers.CorridorHomingTeacher`) labels
the batched twin, whose hull has no contacts; this script flies its law
(:func:`baselines.docking.control.homing.corridor_action`) from the true state in the CPU
environment, where MuJoCo's contacts hold a hull that meets the station. It prints the
success rate with its 95 % Wilson interval per level, and each failure with its reason,
the heading error and the hull's contacts at the end. ``--beyond`` and ``--zone`` set the
corridor's end past the docking point and the distance within which any heading is in
(``--beyond 0 --zone 0``: a corridor that ends at the docking point and counts the heading
everywhere).

    PYTHONPATH=. python scripts/corridor_teacher.py [--difficulty paper hard]
        [--seeds 700000-700099] [--beyond 1.0] [--zone 2.0]
"""

from __future__ import annotations

import argparse
import math

import gymnasium as gym
import numpy as np

import auv_envs  # noqa: F401  (registers the ids)
from baselines.commands.evaluate import parse_seeds
from baselines.docking.control.homing import (
    CORRIDOR_BEYOND,
    STATION_ZONE,
    HomingGains,
    corridor_action,
)
from baselines.stats import wilson_interval

ENV_ID = "auv_envs/DockingMission-v0"


def episode(env, gains: HomingGains, seed: int, beyond: float, zone: float) -> dict:
    """One seeded episode of the corridor teacher; its outcome."""
    obs, info = env.reset(seed=seed)
    while True:
        action = corridor_action(gains, obs, np, beyond=beyond, zone=zone)
        obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
        if terminated or truncated:
            return {"seed": seed, "success": bool(info["is_success"]),
                    "reason": info["failure_reason"] or "time_limit",
                    "heading_deg": math.degrees(info["heading_error"]),
                    "distance": float(info["distance_to_entrance"]),
                    "contacts": int(env.unwrapped.physics.data.ncon)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--difficulty", nargs="+", default=["paper", "hard"])
    parser.add_argument("--seeds", type=parse_seeds, default=parse_seeds("700000-700099"),
                        help="'A-B' (inclusive) or 'A,B,C'")
    parser.add_argument("--beyond", type=float, default=CORRIDOR_BEYOND)
    parser.add_argument("--zone", type=float, default=STATION_ZONE)
    args = parser.parse_args()
    for level in args.difficulty:
        env = gym.make(ENV_ID, obs_mode="state", difficulty=level)
        gains = HomingGains.from_calibration(env.unwrapped.calibration)
        rows = [episode(env, gains, seed, args.beyond, args.zone) for seed in args.seeds]
        env.close()
        docked = sum(row["success"] for row in rows)
        low, high = wilson_interval(docked, len(rows))
        print(f"{level}: docked {docked}/{len(rows)} = {docked / len(rows):.0%} "
              f"[{low:.0%}, {high:.0%}] (beyond {args.beyond} m, zone {args.zone} m)")
        for row in rows:
            if not row["success"]:
                print(f"  seed {row['seed']}: {row['reason']}, {row['distance']:.2f} m from "
                      f"the entrance, heading {row['heading_deg']:.0f} deg, "
                      f"{row['contacts']} hull contacts")


if __name__ == "__main__":
    main()
