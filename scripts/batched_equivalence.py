"""The batched JAX docking env against the MuJoCo CPU env: the equivalence figures.

* **Trajectories**: the CPU env and the batched env start from the same
  plant state and take the same actions (a fixed controller's, computed on
  the CPU run) for 20 s; the worst position difference (m), the worst light
  pixel difference (px) where both see the light, and the steps where the two
  disagree on which lights are in view.
* **Outcomes**: the same fixed controller, closed loop in each env from the
  same start states in the ``current`` scenario (0.3 m/s), on 100 seeds:
  how often both dock or both fail, and how often they fail the same way.

    python scripts/batched_equivalence.py [--seeds 100] [--first-seed 700]

``tests/test_batched_env.py`` asserts the targets (1 cm, 1 px, >= 95 %) with
these functions.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

import auv_envs  # noqa: F401
from auv_envs.batched.functional import FunctionalEnv
from auv_envs.tasks.docking.rules import failure_reason

LAYOUTS = ("auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2")


def line_of_sight_policy(obs: np.ndarray) -> np.ndarray:
    """A fixed proportional-derivative controller on the ``state`` observation (a batch).

    Steers along a line of sight towards the docking axis, holds depth and
    slows near the entrance: it docks in most calm episodes and fails in
    many with a 0.3 m/s current, which makes its outcomes a sharp test.
    """
    obs = np.atleast_2d(obs)
    x, y, z = obs[:, 0], obs[:, 1], obs[:, 2]
    yaw = np.arctan2(obs[:, 6], obs[:, 5])
    u, v, w, r = obs[:, 7], obs[:, 8], obs[:, 9], obs[:, 12]
    ahead = -1.0 - x  # CG target about 1 m before the entrance plane
    heading = np.arctan2(-y, np.maximum(ahead, 0.0) + 6.0) * np.clip(ahead / 3.0, 0.0, 1.0)
    heading_error = (heading - yaw + np.pi) % (2 * np.pi) - np.pi
    surge = np.clip(0.1 * np.hypot(ahead, y), 0.15, 0.5)
    action = np.stack([0.8 * (surge - u), -0.6 * np.cos(yaw) * y - 1.0 * v,
                       -1.5 * z - 1.5 * w, 1.5 * heading_error - 1.0 * r], axis=1)
    return np.clip(action, -1.0, 1.0).astype(np.float32)


def start(cpu, seed: int) -> tuple:
    """Reset the CPU env: its first ``state`` observation, plant state and current (polar)."""
    obs, info = cpu.reset(seed=seed)
    data = cpu.physics.data
    current = info["current"]
    polar = np.array([np.hypot(current[0], current[1]), np.arctan2(current[1], current[0])])
    return obs, data.qpos.copy(), data.qvel.copy(), polar


def trajectory_errors(env_id: str, seeds, steps: int = 200, **env_kwargs) -> dict:
    """Same start, same actions for ``steps`` steps: the largest differences."""
    state_env = gym.make(env_id, obs_mode="state", **env_kwargs).unwrapped
    features_env = gym.make(env_id, obs_mode="features", **env_kwargs).unwrapped
    batched = FunctionalEnv(env_id, obs_mode="features", auto_reset=False, **env_kwargs)
    starts = [start(state_env, seed) for seed in seeds]
    states = jax.jit(jax.vmap(batched.reset_to))(
        np.stack([s[1] for s in starts]), np.stack([s[2] for s in starts]),
        jax.random.split(jax.random.PRNGKey(0), len(starts)), np.stack([s[3] for s in starts]))
    logs = []  # the CPU runs the seeds one after the other
    for seed in seeds:
        obs, *_ = start(state_env, seed)
        features_env.reset(seed=seed)
        log = {"action": [], "position": [], "pixels": [], "visible": [], "ended": False}
        for _ in range(steps):
            action = line_of_sight_policy(obs)[0]
            obs, _, terminated, truncated, info = state_env.step(action)
            _, _, _, _, features_info = features_env.step(action)
            log["action"].append(action)
            log["position"].append(info["true_position"])
            log["pixels"].append(features_info["true_pixels"])
            log["visible"].append(features_info["true_visible"])
            if terminated or truncated:
                log["ended"] = True
                break
        logs.append(log)
    length = min(len(log["action"]) for log in logs)
    step = jax.jit(jax.vmap(batched.step))
    worst_position = worst_pixel = 0.0
    compared = mismatches = 0
    for k in range(length):
        states = step(states, jnp.asarray(np.stack([log["action"][k] for log in logs])))
        positions = np.asarray(states.plant["qpos"][:, :3])
        pixels = np.asarray(states.obs["pixels"])
        visible = np.asarray(states.obs["visible"]).astype(bool)
        for i, log in enumerate(logs):
            worst_position = max(worst_position,
                                 float(np.abs(positions[i] - log["position"][k]).max()))
            mismatches += int((visible[i] != log["visible"][k]).any())
            both = visible[i] & log["visible"][k]
            if both.any():
                worst_pixel = max(worst_pixel, float(np.abs(
                    pixels[i][both] - log["pixels"][k][both]).max()))
                compared += int(both.sum())
    return {"steps": length, "ended_early": sum(log["ended"] for log in logs),
            "worst_position_m": worst_position, "worst_pixel_px": worst_pixel,
            "pixels_compared": compared, "visibility_mismatch_steps": mismatches}


def outcome_agreement(env_id: str, seeds, **env_kwargs) -> dict:
    """The fixed controller closed loop in both envs from the same starts: outcomes."""
    env_kwargs = {"scenario": "current", **env_kwargs}
    cpu = gym.make(env_id, obs_mode="state", **env_kwargs).unwrapped
    starts, cpu_reasons = [], []
    for seed in seeds:
        obs, qpos, qvel, polar = start(cpu, seed)
        starts.append((qpos, qvel, polar))
        while True:
            obs, _, terminated, truncated, info = cpu.step(line_of_sight_policy(obs)[0])
            if terminated or truncated:
                break
        metrics = info["episode_metrics"]
        cpu_reasons.append("success" if metrics["success"] else metrics["failure_reason"])
    batched = FunctionalEnv(env_id, obs_mode="state", auto_reset=False, **env_kwargs)
    states = jax.jit(jax.vmap(batched.reset_to))(
        np.stack([s[0] for s in starts]), np.stack([s[1] for s in starts]),
        jax.random.split(jax.random.PRNGKey(1), len(starts)), np.stack([s[2] for s in starts]))
    step = jax.jit(jax.vmap(batched.step))
    done = np.zeros(len(starts), dtype=bool)
    reasons = [""] * len(starts)
    while not done.all():
        states = step(states, jnp.asarray(line_of_sight_policy(np.asarray(states.obs))))
        ended = np.asarray(states.done) & ~done
        for i in np.flatnonzero(ended):
            success = bool(states.episode.success[i])
            reasons[i] = "success" if success else failure_reason(
                int(states.episode.failure[i]), success)
        done |= ended
    cpu_success = np.array([r == "success" for r in cpu_reasons])
    success = np.array([r == "success" for r in reasons])
    return {"episodes": len(starts), "cpu_successes": int(cpu_success.sum()),
            "batched_successes": int(success.sum()),
            "success_agreement": int((cpu_success == success).sum()),
            "reason_agreement": sum(a == b for a, b in zip(cpu_reasons, reasons, strict=True)),
            "disagreements": [(seed, a, b) for seed, a, b in
                              zip(seeds, cpu_reasons, reasons, strict=True) if a != b]}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--first-seed", type=int, default=700)
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print("| env | steps | worst position m | worst pixel px | pixels compared "
          "| visibility mismatches | success agreement | same outcome |")
    print("|---|---|---|---|---|---|---|---|")
    for env_id in LAYOUTS:
        errors = trajectory_errors(env_id, list(seeds)[:10])
        outcomes = outcome_agreement(env_id, seeds)
        print(f"| {env_id} | {errors['steps']} | {errors['worst_position_m']:.2e} | "
              f"{errors['worst_pixel_px']:.2e} | {errors['pixels_compared']} | "
              f"{errors['visibility_mismatch_steps']} | {outcomes['success_agreement']}/"
              f"{outcomes['episodes']} (CPU docks {outcomes['cpu_successes']}, batched "
              f"{outcomes['batched_successes']}) | {outcomes['reason_agreement']}/"
              f"{outcomes['episodes']} |", flush=True)
        for seed, cpu_reason, reason in outcomes["disagreements"]:
            print(f"  seed {seed}: CPU {cpu_reason}, batched {reason}")


if __name__ == "__main__":
    main()
