"""Cost of one cubature Kalman filter step (predict + update) as ``ckf-pd`` runs it.

[LTAT]'s filter: 6 states, 3 measured, eq. 8's heave/surge model, a
per-fix measurement covariance and the innovation gate. Target: a
step <= 100 us. Also prints the step's share of the LARS control period and
the whole agent's ``act`` (perception geometry + CKF + planning + IK + PD)
for context, and the CKF's ratio to a plain Kalman filter step timed in the
same run (the machine is shared, so absolute times drift with its load). Wall
and CPU time are both printed: CPU time leaves out waiting for a core.

    PYTHONPATH=. python benchmarks/ckf_speed.py [--steps 20000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import gymnasium as gym
import numpy as np

import auv_envs  # noqa: F401
from baselines.lars.agents import GATE_3DOF, CKFPDAgent
from baselines.lars.estimation.ckf import (
    CubatureKalmanFilter,
    HeaveSurgeModel,
    position_measurement,
    white_acceleration_noise,
)

ENV_ID = "auv_envs/LARSCapture-v0"
TARGET_US = 100.0
#: The filter's problem: heave/surge model, process noise, prior, fix noise.
OMEGA, Z_MEAN = 0.9, -0.05
ACCEL_STD = (0.02, 0.02, 0.05)
X0 = (0.0, 2.0, -0.05, 0.1, 0.0, 0.18)
P0_DIAG = [1e-4] * 3 + [0.04] * 3
FIX_STD = (0.002, 0.002, 0.01)


def control_period() -> float:
    """Seconds per LARS env step (the filter's sampling interval), from the env's calibration."""
    env = gym.make(ENV_ID, obs_mode="features")
    try:
        return float(env.unwrapped.calibration.control_period)
    finally:
        env.close()


def ckf_step_us(steps: int, dt: float, seed: int = 0) -> tuple[float, float]:
    """Mean wall and CPU time (us) of ``predict(); update(z, R, gate)`` over ``steps`` steps.

    CPU time (``time.process_time``) leaves out the time the process waited
    for a core, which on an oversubscribed machine is most of the wall time.
    """
    model = HeaveSurgeModel(dt, OMEGA, Z_MEAN)
    ckf = CubatureKalmanFilter(model, position_measurement,
                               white_acceleration_noise(dt, ACCEL_STD), np.eye(3))
    ckf.initialise(np.array(X0), np.diag(P0_DIAG))
    rng = np.random.default_rng(seed)
    state = ckf.mean.copy()
    zs, noise = [], np.diag(FIX_STD) ** 2
    for _ in range(steps):
        state = model(state)
        zs.append(state[:3] + rng.normal(0.0, FIX_STD))
    start, cpu = time.perf_counter(), time.process_time()
    for z in zs:
        ckf.predict()
        ckf.update(z, noise, GATE_3DOF)
    return (1e6 * (time.perf_counter() - start) / steps,
            1e6 * (time.process_time() - cpu) / steps)


def kalman_step_us(steps: int, dt: float, seed: int = 0) -> tuple[float, float]:
    """Same-run reference: a plain numpy Kalman filter step on the same linear model.

    The CKF is exact on this linear model, so the two do the same job; the
    ratio says what the cubature points cost and stays meaningful when the
    shared machine is loaded.
    """
    model = HeaveSurgeModel(dt, OMEGA, Z_MEAN)
    f, q = model.matrix, white_acceleration_noise(dt, ACCEL_STD)
    x = np.array(X0)
    p = np.diag(P0_DIAG)
    rng = np.random.default_rng(seed)
    noise = np.diag(FIX_STD) ** 2
    zs = [x[:3] + rng.normal(0.0, FIX_STD) for _ in range(steps)]
    start, cpu = time.perf_counter(), time.process_time()
    for z in zs:
        x, p = model(x), f @ p @ f.T + q
        s = p[:3, :3] + noise
        solved = np.linalg.solve(s, np.column_stack((z - x[:3], p[:3])))
        gain = solved[:, 1:].T
        x, p = x + gain @ (z - x[:3]), p - gain @ s @ gain.T
    return (1e6 * (time.perf_counter() - start) / steps,
            1e6 * (time.process_time() - cpu) / steps)


def agent_act_us(steps: int, dt: float, seed: int = 0) -> float:
    """Mean wall time (us) of ``ckf-pd``'s ``act`` in a tracking episode (env step excluded)."""
    env = gym.make(ENV_ID, obs_mode="features", time_limit=steps * dt + 1)
    try:
        agent = CKFPDAgent(env.unwrapped, strike=False)
        obs, info = env.reset(seed=seed)
        agent.reset(seed)
        total = 0.0
        for _ in range(steps):
            start = time.perf_counter()
            action = agent.act(obs, info)
            total += time.perf_counter() - start
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                obs, info = env.reset(seed=seed)
                agent.reset(seed)
        return 1e6 * total / steps
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--agent-steps", type=int, default=500)
    args = parser.parse_args()
    load = os.getloadavg()[0]
    print(f"machine: {os.cpu_count()} cores, 1-minute load average {load:.1f} at the start")
    dt = control_period()
    ckf_step_us(200, dt)  # warm-up
    runs, refs = [], []
    for seed in range(args.repeats):  # interleaved, so both see the same machine load
        runs.append(ckf_step_us(args.steps, dt, seed))
        refs.append(kalman_step_us(args.steps, dt, seed))
    period_us = dt * 1e6
    for k, clock in enumerate(("wall", "CPU")):
        step = statistics.median(r[k] for r in runs)
        ref = statistics.median(r[k] for r in refs)
        print(f"CKF step (predict + update), {clock} time: median {step:.1f} us over "
              f"{args.repeats} x {args.steps} steps")
        print(f"  ratio to the 100 us target: {step / TARGET_US:.2f} "
              f"({'met' if step <= TARGET_US else 'MISSED'})")
        print(f"  ratio to the {dt * 1e3:.0f} ms control period: {step / period_us:.5f}")
        print(f"  ratio to a plain Kalman filter step in the same run ({ref:.1f} us): "
              f"{step / ref:.2f}")
    act = agent_act_us(args.agent_steps, dt)
    print(f"ckf-pd act (whole agent): {act:.0f} us/step = {act / period_us:.3f} of the period")


if __name__ == "__main__":
    main()
