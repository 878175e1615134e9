"""Per-control-step cost of the [OFNMPC] agents: observer update + NMPC solve (N = 20).

    PYTHONPATH=. python benchmarks/ofnmpc_speed.py [--steps 150] [--no-vm] [--ipopt]

Each agent flies one episode of ``DockingStation-v2`` in [OFNMPC]'s Scenario 2
(``scenario="current"``, current towards 90 deg, 5 px / 0.02 m/s noise) and
``agent.act`` is timed per step (the environment step is excluded; the first
step, which initialises the pose and builds the warm start, is dropped). Both
the wall clock and the process CPU time are reported — the machine is shared,
and the CPU time is what the agent itself costs. Each figure is also printed as
a ratio to the control period (the real-time factor: below 1 is faster than
real time), with the load average at the start for context.

Variants: the NLP functions compiled to C (the agents' default; compiled once
per problem and cached, so the build time printed is the compile on a first
run and the library load afterwards) and evaluated in CasADi's virtual machine
(``OFNMPCConfig(compile=False)``, what runs where no C compiler exists).
Targets: ``ofnmpc-ekf`` median <= 10 ms and p95 <= 25 ms, ``ofnmpc-mhe`` median <= 30 ms.
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np

import auv_envs  # noqa: F401
from baselines.docking.agents import OFNMPCAgent
from baselines.docking.control.ofnmpc import OFNMPCConfig

ENV_ID = "auv_envs/DockingStation-v2"
TARGETS_MS = {"ekf": (10.0, 25.0), "mhe": (30.0, None)}


def time_agent(observer: str, config: OFNMPCConfig, steps: int, seed: int) -> dict:
    """Per-step wall and CPU times (s) of ``act`` for one episode (at most ``steps``)."""
    env = gym.make(ENV_ID, obs_mode="features", scenario="current", current_direction=90.0)
    start = time.perf_counter()
    agent = OFNMPCAgent(env.unwrapped, observer, config)
    build = time.perf_counter() - start
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    wall, cpu = [], []
    for _ in range(steps):
        w0, c0 = time.perf_counter(), time.process_time()
        action = agent.act(obs, info)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
    return {
        "wall": np.array(wall[1:]), "cpu": np.array(cpu[1:]), "build": build,
        "compiled": agent.controller.compiled, "stats": agent.stats(),
        "success": bool(info.get("is_success", False)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--seed", type=int, default=100_000)
    parser.add_argument("--no-vm", action="store_true",
                        help="skip the uncompiled (CasADi virtual machine) variant")
    parser.add_argument("--ipopt", action="store_true",
                        help="also time ofnmpc-ekf with IPOPT instead of FATROP")
    args = parser.parse_args()
    period = gym.make(ENV_ID, obs_mode="features").unwrapped.calibration.control_period
    print(f"control period {1000 * period:.0f} ms; load average {os.getloadavg()[0]:.2f} "
          f"on {os.cpu_count()} cores")
    print("| agent | NLP functions | steps | median ms (wall / CPU) | p95 ms (wall / CPU) "
          "| median / period (CPU) | p95 / period (CPU) | observer mean ms (wall) "
          "| target (median, p95) |")
    print("|---|---|---|---|---|---|---|---|---|")
    variants = [OFNMPCConfig()] + ([] if args.no_vm else [OFNMPCConfig(compile=False)])
    runs = [(o, c) for o in ("ekf", "mhe") for c in variants]
    if args.ipopt:
        runs.insert(1, ("ekf", OFNMPCConfig(solver="ipopt", compile=False)))
    for observer, config in runs:
        r = time_agent(observer, config, args.steps, args.seed)
        wall, cpu = 1000 * r["wall"], 1000 * r["cpu"]
        med_w, p95_w = np.median(wall), np.percentile(wall, 95)
        med_c, p95_c = np.median(cpu), np.percentile(cpu, 95)
        target_med, target_p95 = TARGETS_MS[observer]
        kind = f"{config.solver}, " + (f"compiled (build {r['build']:.0f} s)"
                                       if r["compiled"] else "CasADi VM")
        target = f"<= {target_med:g}" + (f", <= {target_p95:g}" if target_p95 else "")
        print(f"| ofnmpc-{observer} | {kind} | {len(wall)} | {med_w:.1f} / {med_c:.1f} "
              f"| {p95_w:.1f} / {p95_c:.1f} | {med_c / (1000 * period):.3f} "
              f"| {p95_c / (1000 * period):.3f} | {r['stats']['mean_observer_ms']:.2f} "
              f"| {target} |")


if __name__ == "__main__":
    main()
