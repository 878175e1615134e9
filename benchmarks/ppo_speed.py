"""PPO training throughput on the fast observation modes vs SB3 PPO on ``HalfCheetah-v5``.

Both sides train Stable-Baselines3 PPO with the same settings (vector env
size, rollout length, minibatch size, epochs, network, VecNormalize, one
PyTorch thread), measured in the same run and interleaved, since this shared
machine is noisy: each repeat times the reference and then every target, and
the reported ratio is the median over repeats of target / reference steps per
second (``learn`` wall time only; building the model is excluded); beside
it, the same median per CPU second of this process, which other users of
the machine disturb less (the target stays on wall clock). The
``auv_envs`` side goes through train.py's own stack
(:func:`baselines.rl.training.build_model`): ``Dict`` observations with
``MultiInputPolicy``, and, as a second row, ``flatten_obs`` with ``MlpPolicy``.

Target: >= 0.8x on a ``features`` environment.

    python benchmarks/ppo_speed.py [--steps N] [--repeats R] [--envs ID ...]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import auv_envs
from baselines.registry import env_obs_modes
from baselines.rl.config import resolve_config
from baselines.rl.training import algorithm_kwargs, build_model

#: Shared PPO settings (both sides).
SETTINGS = {
    "n_envs": 8, "n_steps": 256, "batch_size": 256, "n_epochs": 5, "learning_rate": 3e-4,
    "policy_kwargs": {"net_arch": [64, 64], "activation_fn": "tanh"},
}
FAST_MODES = ("features", "measurements")


def fast_modes(env_id: str) -> list[str]:
    return [m for m in env_obs_modes(env_id) or () if m in FAST_MODES]


def config_for(env_id: str, obs_mode: str, flatten: bool):
    overrides = {k: v for k, v in SETTINGS.items() if k != "n_envs"}
    overrides.update(n_envs=SETTINGS["n_envs"], obs_mode=obs_mode, normalize=True,
                     flatten_obs=flatten, n_eval_episodes=0)
    return resolve_config("ppo", env_id, 0, overrides)


def reference_model():
    env = VecNormalize(make_vec_env("HalfCheetah-v5", n_envs=SETTINGS["n_envs"], seed=0))
    config = config_for(*next((e, m) for e in auv_envs.ENVIRONMENTS for m in fast_modes(e)),
                        False)
    kwargs = algorithm_kwargs(config, env.action_space)
    return PPO("MlpPolicy", env, seed=0, device="cpu", verbose=0, **kwargs)


def steps_per_second(model, steps: int) -> tuple[float, float]:
    """Steps per wall-clock second and per CPU second of ``model.learn(steps)``."""
    start, start_cpu = time.perf_counter(), time.process_time()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start), steps / (time.process_time() - start_cpu)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=8192,
                        help="env steps per timing (a multiple of n_envs * n_steps = 2048)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--envs", nargs="+", default=list(auv_envs.ENVIRONMENTS),
                        choices=list(auv_envs.ENVIRONMENTS), metavar="ID")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)

    reference = reference_model()
    targets = {}
    for env_id in args.envs:
        for mode in fast_modes(env_id):
            for flatten in (False, True):
                model = build_model(config_for(env_id, mode, flatten))
                targets[(env_id, mode, type(model.policy).__name__)] = model
    for model in (reference, *targets.values()):  # warm-up: first rollout and update
        model.learn(2048)

    ref_rates, rates, cpu_rates = [], {key: [] for key in targets}, {key: [] for key in targets}
    for _ in range(args.repeats):
        ref, ref_cpu = steps_per_second(reference, args.steps)
        ref_rates.append(ref)
        for key, model in targets.items():
            rate, cpu = steps_per_second(model, args.steps)
            rates[key].append(rate / ref)
            cpu_rates[key].append(cpu / ref_cpu)

    print(f"SB3 PPO on HalfCheetah-v5 (reference): median {statistics.median(ref_rates):,.0f} "
          f"steps/s over {args.repeats} repeats of {args.steps} steps; settings {SETTINGS}\n")
    print("| env | obs_mode | policy | median ratio to HalfCheetah-v5 | min–max "
          "| median CPU ratio | target 0.8x |")
    print("|---|---|---|---|---|---|---|")
    for key, ratios in rates.items():
        env_id, mode, policy = key
        median = statistics.median(ratios)
        met = "yes" if median >= 0.8 else "NO"
        print(f"| {env_id} | {mode} | {policy} | {median:.2f} | "
              f"{min(ratios):.2f}–{max(ratios):.2f} | {statistics.median(cpu_rates[key]):.2f} "
              f"| {met} |")


if __name__ == "__main__":
    main()
