"""A tiny ``train.py`` run from a shipped YAML, exported and replayed (the front-end tests)."""

from __future__ import annotations

import json
from pathlib import Path

import train as train_cli
from baselines.rl.export import export_policy


def train_and_export(tmp_path: Path, env: str, config_dir: Path, steps: int, env_kwargs: str,
                     name: str) -> tuple[Path, dict]:
    """Train ``steps`` steps (one env, two rollouts, one held-out episode at each) and export
    the run as policy ``name``; returns the policy directory and its manifest."""
    run_dir = tmp_path / "run"
    rc = train_cli.main([
        "--algo", "ppo", "--env", env, "--hyperparams-dir", str(config_dir),
        "--seed", "1", "--n-timesteps", str(steps), "--run-dir", str(run_dir),
        "--set", "n_envs=1", "--set", f"n_steps={steps // 2}",
        "--set", f"batch_size={steps // 4}", "--set", f"env_kwargs={env_kwargs}",
        "--set", "n_eval_episodes=1", "--set", f"eval_freq={steps // 2}", "--no-progress-bar",
    ])
    assert rc == 0
    path = export_policy(run_dir, name, tmp_path)
    return path, json.loads((path / "policy.json").read_text())
