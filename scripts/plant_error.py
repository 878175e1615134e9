"""How far the docking plant is from the converged solution of its own equations.

    python scripts/plant_error.py [--seeds 10] [--first-seed 93000] [--duration 10]
                                  [--envs ID ...] [--json PATH]

For every docking id (and, for comparison, the superseded ``-v0`` plant), calm
(``scenario="mismatch"``) and in the 0.3 m/s current (``scenario="current"``):
episodes on seeds N, N+1, ... start from the env's reset state, read through
``info``; the env and an independent reference (``tests/plant_reference.py``:
Fossen 2021 eq. 10.1 with full-matrix C(nu) from ``m2c``, quaternion kinematics,
RK4 at 2 ms) receive the same smooth full-range surge/sway/heave/yaw commands.
Per run the largest position, attitude and velocity errors over ``--duration``
seconds; the table gives their median and range over the seeds. Limits
(converged physics): 2 cm, 0.5 deg, 0.01 m/s. Runs use
``lights_lost_timeout=1e6`` so that no lights-lost failure cuts them short; a
run cut short by seabed contact or leaving the arena is reported as shorter.

``--acoustic`` measures the acoustic arm instead (MuJoCo's own fluid model,
for which no independent reference exists here): the end effector's largest
distance from a 16x finer integration of the same model over ``--duration``
seconds, per current level, at the shipped steps (two of 5 ms a 0.01 s period)
and at 4x finer ones.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import auv_envs  # noqa: E402
from tests.plant_reference import LIMITS, acoustic_truth, env_plant_error  # noqa: E402

DEFAULT_ENVS = (
    "auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2", "auv_envs/DockingStation-v0",
)


def measure(env_id: str, scenario: str, seeds: list[int], duration: float) -> dict:
    """Per-seed maximum errors of one env id and scenario."""
    env = gym.make(env_id, obs_mode="state", scenario=scenario, lights_lost_timeout=1e6)
    runs = []
    try:
        for seed in seeds:
            error = env_plant_error(env, seed=seed, command_seed=seed + 17, duration=duration)
            runs.append({
                "seed": seed, "position_m": error.position, "attitude_deg": error.attitude_deg,
                "velocity": error.velocity, "travel_m": error.travel,
                "seconds": error.steps * env.unwrapped.dt,
            })
    finally:
        env.close()
    return {"env_id": env_id, "scenario": scenario, "runs": runs}


def acoustic_table(seeds: list[int], duration: float) -> None:
    print(f"Acoustic end effector: largest distance from a 16x finer integration over "
          f"{duration:g} s, seeds {seeds[0]}-{seeds[-1]}\n")
    print("| current | seed | shipped steps m | 4x finer m | travel m |")
    print("|---|---|---|---|---|")
    for disturbance in ("low", "medium", "high"):
        for seed in seeds:
            runs = [acoustic_truth(disturbance, seed, duration, n) for n in (1, 4, 16)]
            shipped, finer = (np.linalg.norm(r - runs[2], axis=1).max() for r in runs[:2])
            travel = np.linalg.norm(runs[0] - runs[0][0], axis=1).max()
            print(f"| {disturbance} | {seed} | {shipped:.4f} | {finer:.5f} | {travel:.1f} |")


def _cell(runs: list[dict], key: str, fmt: str) -> str:
    values = np.array([run[key] for run in runs])
    return f"{np.median(values):{fmt}} ({values.min():{fmt}}-{values.max():{fmt}})"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=93000)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS),
                        choices=[*auv_envs.ENVIRONMENTS, *auv_envs.PREVIOUS_VERSIONS],
                        metavar="ID")
    parser.add_argument("--json", type=Path, help="write every run's figures here")
    parser.add_argument("--acoustic", action="store_true",
                        help="measure the acoustic arm against finer steps of itself instead")
    args = parser.parse_args(argv)

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    if args.acoustic:
        acoustic_table(seeds, args.duration)
        return
    results = [measure(env_id, scenario, seeds, args.duration)
               for env_id in args.envs for scenario in ("mismatch", "current")]
    print(f"Max error over {args.duration:g} s against the converged reference, median "
          f"(range) over seeds {seeds[0]}-{seeds[-1]}; limits {LIMITS}\n")
    print("| env | scenario | position m | attitude deg | velocity m/s, rad/s | travel m "
          "| seconds compared | within limits |")
    print("|---|---|---|---|---|---|---|---|")
    for result in results:
        runs = result["runs"]
        within = sum(all(run[key] < limit for key, limit in LIMITS.items()) for run in runs)
        print(f"| {result['env_id']} | {result['scenario']} | {_cell(runs, 'position_m', '.2g')} "
              f"| {_cell(runs, 'attitude_deg', '.2g')} | {_cell(runs, 'velocity', '.2g')} "
              f"| {_cell(runs, 'travel_m', '.1f')} | {_cell(runs, 'seconds', '.1f')} "
              f"| {within}/{len(runs)} |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"limits": LIMITS, "results": results}, indent=1))


if __name__ == "__main__":
    main()
