"""train.py and the RL agents: config, exact resume, checkpoints, signals, shipped policies."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import MultiInputActorCriticPolicy

import train as train_cli
from baselines.evaluation import EVAL_SEED_BASE, run_episode
from baselines.parsing import parse_value
from baselines.registry import agent_spec, make_agent
from baselines.rl import agents, training
from baselines.rl.checkpoint import CheckpointError, latest_checkpoint
from baselines.rl.config import (
    TRAIN_EVAL_SEED_BASE,
    ConfigError,
    parse_overrides,
    resolve_config,
)
from baselines.rl.export import export_policy
from baselines.rl.policy import PolicyAgent, PolicyFileError, load_model
from tests.conftest import ENV_IDS, make_env

ROOT = Path(__file__).resolve().parents[1]
DOCKING = "auv_envs/DockingStation-v2"

#: A few hundred PPO steps on short docking episodes (10 s = 100 steps).
PPO_SMALL = {
    "n_timesteps": 768, "n_envs": 2, "n_steps": 64, "batch_size": 64, "n_epochs": 2,
    "checkpoint_freq": 256, "eval_freq": 256, "n_eval_episodes": 1,
    "env_kwargs": {"time_limit": 10.0}, "policy_kwargs": {"net_arch": [32, 32]},
}


class SignalAt(BaseCallback):
    """Sends this process ``signum`` once training reaches ``step`` (a real signal)."""

    def __init__(self, step: int, signum: int = signal.SIGINT):
        super().__init__()
        self.step, self.signum, self.sent = step, signum, False

    def _on_step(self) -> bool:
        if not self.sent and self.num_timesteps >= self.step:
            self.sent = True
            os.kill(os.getpid(), self.signum)
        return True


def tensors(model) -> dict:
    """Every tensor of a model: parameters and optimiser states."""
    out = {}

    def walk(node, prefix):
        if isinstance(node, dict):
            for key, value in node.items():
                walk(value, f"{prefix}{key}.")
        elif torch.is_tensor(node):
            out[prefix] = node

    walk(model.get_parameters(), "")
    return out


def assert_same_model(path_a: Path, path_b: Path, algo: str) -> None:
    a, b = tensors(load_model(algo, path_a)), tensors(load_model(algo, path_b))
    assert a.keys() == b.keys() and len(a) > 4
    different = [k for k in a if not torch.equal(a[k], b[k])]
    assert not different, different


@pytest.fixture(scope="module")
def ppo_runs(tmp_path_factory):
    """One uninterrupted PPO run, and the same run stopped by SIGINT and resumed."""
    root = tmp_path_factory.mktemp("ppo")
    config = resolve_config("ppo", DOCKING, seed=7, overrides=PPO_SMALL)
    whole = training.train(config, root / "whole", "pytest whole", progress_bar=False,
                           echo=False)
    stopped = training.train(config, root / "split", "pytest split", progress_bar=False,
                             echo=False, callbacks=[SignalAt(300)])
    resumed = training.resume(root / "split", "pytest resume", progress_bar=False, echo=False)
    return config, whole, stopped, resumed


# -------------------------------------------------------------------- config
def test_values_are_parsed_as_literals_never_code():
    assert parse_value("3e-4") == pytest.approx(3e-4)
    assert parse_value("[64, 64]") == [64, 64]
    assert parse_value("true") is True and parse_value("None") is None
    assert parse_value("tanh") == "tanh"
    assert parse_value("__import__('os').getcwd()") == "__import__('os').getcwd()"
    assert parse_overrides(["a.b=1", "c = {'x': 2}"]) == {"a.b": 1, "c": {"x": 2}}


def test_config_layers_default_env_entry_and_overrides(tmp_path):
    (tmp_path / "ppo.yml").write_text(
        "default: {n_steps: 128, gamma: 0.9, policy_kwargs: {net_arch: [8]}}\n"
        f"{DOCKING}: {{gamma: 0.95, obs_mode: features}}\n"
    )
    config = resolve_config("ppo", DOCKING, 3, {"policy_kwargs.activation_fn": "relu"},
                            hyperparams_dir=tmp_path)
    assert config.hyperparams["n_steps"] == 128 and config.hyperparams["gamma"] == 0.95
    assert config.hyperparams["policy_kwargs"] == {"net_arch": [8], "activation_fn": "relu"}
    assert config.run["obs_mode"] == "features" and config.seed == 3
    other = resolve_config("ppo", "auv_envs/LARSCapture-v0", hyperparams_dir=tmp_path)
    assert other.hyperparams["gamma"] == 0.9 and other.run["obs_mode"] == "state"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"bogus": 1}, "unknown setting 'bogus'"),
        ({"n_steps": "many"}, "n_steps must be an integer"),
        ({"learning_rate": "3e-4"}, "learning_rate"),
        ({"n_envs": 0}, r"n_envs must be an integer in \[1, inf\), got 0"),
        ({"policy": "Transformer"}, "unknown policy"),
        ({"normalize": "yes"}, "normalize must be"),
    ],
)
def test_bad_overrides_give_clear_errors(overrides, message):
    with pytest.raises(ConfigError, match=message):
        resolve_config("ppo", DOCKING, overrides=overrides)


def test_bad_input_clear_errors(tmp_path, capsys):
    with pytest.raises(ConfigError, match="seed must be in"):
        resolve_config("ppo", DOCKING, seed=TRAIN_EVAL_SEED_BASE)
    with pytest.raises(ConfigError, match="unknown algorithm"):
        resolve_config("dqn", DOCKING)
    with pytest.raises(ConfigError, match="unknown env id"):
        resolve_config("ppo", "auv_envs/Nope-v0")
    with pytest.raises(ConfigError, match="key=value"):
        parse_overrides(["n_steps"])
    (tmp_path / "ppo.yml").write_text("default: {learning_rate: 3e-4}\n")
    with pytest.raises(ConfigError, match="write 3.0e-4"):
        resolve_config("ppo", DOCKING, hyperparams_dir=tmp_path)
    rc = train_cli.main(["--algo", "ppo", "--env", "DockingStation-v2", "--set", "bogus=1",
                         "--run-dir", str(tmp_path / "run")])
    assert rc == 2 and "unknown setting 'bogus'" in capsys.readouterr().err
    rc = train_cli.main(["--algo", "ppo", "--env", "DockingStation-v2", "--set",
                         "env_kwargs.bogus=1", "--run-dir", str(tmp_path / "run")])
    assert rc == 2 and "unknown argument(s) bogus" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
    with pytest.raises(ConfigError, match="config file missing"):
        training.resume(tmp_path / "nowhere")


# ------------------------------------------------------- training and resume
def test_run_directory_records_config_command_seed_checkpoint(ppo_runs):
    config, whole, stopped, resumed = ppo_runs
    run = training.RunDirectory(whole.run_dir)
    assert whole.finished and whole.steps == 768
    assert training.read_config(run.config) == config
    info = json.loads(run.info.read_text())
    assert info["command"] == "pytest whole" and info["seed"] == 7
    assert info["package_version"] and info["status"] == "finished"
    assert latest_checkpoint(run.checkpoints).name == "step-0000000768"
    assert (run.final / "model.zip").is_file() and (run.final / "vecnormalize.pkl").is_file()
    steps = [int(line.split(",")[0]) for line in run.eval_curve.read_text().splitlines()[1:]]
    assert steps == [0, 256, 512, 768]
    assert list(run.logs.glob("segment-*/events.out.tfevents.*"))


def test_interrupt_then_resume_equals_uninterrupted_run(ppo_runs):
    config, whole, stopped, resumed = ppo_runs
    # SIGINT at step 300 -> checkpoint at the next rollout start (step 384), then stop.
    assert not stopped.finished and stopped.stopped_by == "SIGINT" and stopped.steps == 384
    assert resumed.finished and resumed.steps == whole.steps
    split = training.RunDirectory(resumed.run_dir)
    info = json.loads(split.info.read_text())
    assert [s["status"] for s in info["segments"]] == ["interrupted", "finished"]
    full = training.RunDirectory(whole.run_dir)
    assert_same_model(full.final / "model.zip", split.final / "model.zip", "ppo")
    assert split.eval_curve.read_text() == full.eval_curve.read_text()
    assert split.train_episodes.read_text() == full.train_episodes.read_text()


def test_off_policy_resume_restores_replay_buffer_and_rescaled_actions(tmp_path):
    # SAC on the acoustic env: a Box action space over the tank, rescaled to [-1, 1].
    overrides = {
        "n_timesteps": 240, "learning_starts": 40, "batch_size": 32, "buffer_size": 1000,
        "checkpoint_freq": 100, "n_eval_episodes": 0,
        "env_kwargs": {"time_limit": 0.5, "error_clip": 400.0},
        "policy_kwargs": {"net_arch": [16, 16]},
    }
    config = resolve_config("sac", "auv_envs/AcousticTracking-v2", 1, overrides)
    whole = training.train(config, tmp_path / "whole", progress_bar=False, echo=False)
    stopped = training.train(config, tmp_path / "split", progress_bar=False, echo=False,
                             callbacks=[SignalAt(70, signal.SIGTERM)])
    assert stopped.stopped_by == "SIGTERM" and stopped.steps == 70
    assert (stopped.checkpoint / "replay_buffer.pkl").is_file()
    resumed = training.resume(tmp_path / "split", progress_bar=False, echo=False)
    assert resumed.finished
    assert_same_model(tmp_path / "whole/final/model.zip", tmp_path / "split/final/model.zip",
                      "sac")
    assert whole.steps == resumed.steps == 240


def test_cli_sigint_checkpoints_and_resume_finishes(tmp_path):
    run_dir = tmp_path / "run"
    command = [
        sys.executable, str(ROOT / "train.py"), "--algo", "ppo", "--env", "LARSCapture-v0",
        "--n-timesteps", "1000000", "--set", "n_steps=64", "--set", "n_envs=1",
        "--set", "checkpoint_freq=64", "--set", "n_eval_episodes=0", "--run-dir", str(run_dir),
        "--no-progress-bar",
    ]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (run_dir / "checkpoints" / "latest").exists():
            assert proc.poll() is None, proc.stdout.read()
            assert time.monotonic() < deadline, "no checkpoint within 120 s"
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGINT, out
    assert "--resume" in out
    step = int(latest_checkpoint(run_dir / "checkpoints").name.split("-")[1])
    assert step > 0
    for name in ("config.yml", "run.json"):
        assert (run_dir / name).is_file()
    assert json.loads((run_dir / "run.json").read_text())["status"] == "interrupted"
    rc = train_cli.main(["--resume", str(run_dir), "--n-timesteps", str(step + 128),
                         "--no-progress-bar"])
    assert rc == 0
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "finished" and info["steps"] == step + 128
    assert "--resume" in info["segments"][-1]["command"]
    # Every run (interrupted or finished) gets its learning curve as a picture.
    assert (run_dir / "curve.png").stat().st_size > 1000


def test_evaluate_ranks_a_run_directory_beside_the_built_in_agents(ppo_runs, tmp_path):
    import evaluate

    _, whole, _, _ = ppo_runs
    name = agents.external_policy_name(whole.run_dir)
    assert name.startswith("whole@") and len(name) == len("whole@") + 8
    code = evaluate.main(["--envs", "DockingStation-v2", "--agents", "random", "--policy",
                          str(whole.run_dir), "--seeds", "100000", "--workers", "1",
                          "--difficulty", "easy", "--no-progress", "--no-video",
                          "--out", str(tmp_path / "lb")])
    assert code == 0
    rows = json.loads((tmp_path / "lb" / "leaderboard.json").read_text())
    by_agent = {r["agent"]: r for r in rows}
    assert set(by_agent) == {"random", name}
    assert by_agent[name]["episodes"] == 1 and by_agent[name]["failed"] == 0
    # Evaluated at the full episode length, not the training's 10 s episodes.
    episodes = json.loads((tmp_path / "lb" / "episodes.json").read_text())
    mine = next(e for e in episodes if e["agent"] == name)
    assert mine["env_kwargs"] == {"difficulty": "easy"} and mine["status"] == "ok"


def test_evaluate_policy_names_follow_the_weights_and_bad_paths_fail(tmp_path, capsys):
    import evaluate

    root = agents.policies_root()
    for shipped in ("ppo-docking-features-s0", "ppo-lamp-array-features-s0"):
        shutil.copytree(root / shipped, tmp_path / "mine" / shipped)
    first = agents.external_policy_name(tmp_path / "mine" / "ppo-docking-features-s0")
    second = agents.external_policy_name(tmp_path / "mine" / "ppo-lamp-array-features-s0")
    assert first.split("@")[1] != second.split("@")[1]  # other weights, other name
    with pytest.raises(SystemExit):
        evaluate.main(["--policy", str(tmp_path / "nothing-here"), "--out", str(tmp_path)])
    assert "neither a policy directory" in capsys.readouterr().err


def test_corrupt_or_mismatched_checkpoint_is_refused(ppo_runs, tmp_path):
    config, whole, _, _ = ppo_runs
    run = tmp_path / "run"
    shutil.copytree(whole.run_dir, run)
    with pytest.raises(ConfigError, match="already reached"):
        training.resume(run, progress_bar=False, echo=False)
    with pytest.raises(ConfigError, match="does not match"):
        other = resolve_config("ppo", DOCKING, seed=7, overrides={**PPO_SMALL, "gamma": 0.5})
        training.resume(run, expected=other, n_timesteps=1024, progress_bar=False)
    # A checkpoint written by another configuration.
    config_text = (run / "config.yml").read_text()
    (run / "config.yml").write_text(config_text.replace("n_epochs: 2", "n_epochs: 3"))
    with pytest.raises(CheckpointError, match="different hyperparameters"):
        training.resume(run, n_timesteps=1024, progress_bar=False, echo=False)
    (run / "config.yml").write_text(config_text)
    # A corrupt file.
    model = latest_checkpoint(run / "checkpoints") / "model.zip"
    data = bytearray(model.read_bytes())
    data[len(data) // 2] ^= 0xFF
    model.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="corrupt"):
        training.resume(run, n_timesteps=1024, progress_bar=False, echo=False)
    (run / "checkpoints" / "latest").write_text("{not json")
    with pytest.raises(CheckpointError, match="corrupt"):
        training.resume(run, n_timesteps=1024, progress_bar=False, echo=False)
    (run / "checkpoints" / "latest").unlink()
    with pytest.raises(CheckpointError, match="no checkpoint"):
        training.resume(run, n_timesteps=1024, progress_bar=False, echo=False)
    with pytest.raises(ConfigError, match="already holds a run"):
        training.train(config, run, progress_bar=False)


def test_image_mode_trains_with_multi_input_policy(tmp_path):
    overrides = {
        "obs_mode": "image", "n_timesteps": 64, "n_envs": 1, "n_steps": 32, "batch_size": 32,
        "n_epochs": 1, "n_eval_episodes": 1, "eval_freq": 64, "checkpoint_freq": 64,
        "env_kwargs": {"image_size": [64, 48], "time_limit": 2.0},
    }
    config = resolve_config("ppo", DOCKING, 0, overrides)
    result = training.train(config, tmp_path / "img", progress_bar=False, echo=False)
    assert result.finished
    model = load_model("ppo", tmp_path / "img/final/model.zip")
    assert isinstance(model.policy, MultiInputActorCriticPolicy)


@pytest.mark.parametrize(
    ("algo", "overrides"),
    [
        ("a2c", {"n_steps": 8, "n_envs": 2}),
        ("td3", {"learning_starts": 32, "batch_size": 16}),
        ("ddpg", {"learning_starts": 32, "batch_size": 16}),
    ],
)
def test_other_algorithms_train_on_dict_observations(algo, overrides, tmp_path):
    config = resolve_config(algo, "auv_envs/LARSCapture-v0", 0, {
        **overrides, "obs_mode": "features", "n_timesteps": 64, "n_eval_episodes": 1,
        "eval_freq": 64, "checkpoint_freq": 32, "policy_kwargs": {"net_arch": [8, 8]},
    })
    result = training.train(config, tmp_path / algo, progress_bar=False, echo=False)
    assert result.finished and result.steps >= 64
    spec = agents.policy_spec(tmp_path / algo / "final")
    env = make_env("auv_envs/LARSCapture-v0", "features")
    row = run_episode(env, spec.factory(env.unwrapped), TRAIN_EVAL_SEED_BASE,
                      "auv_envs/LARSCapture-v0", algo)
    assert row.length > 0
    env.close()


# -------------------------------------------------------------------- agents
def test_exported_policy_acts_as_in_training(ppo_runs, tmp_path):
    """The exported agent reproduces the final held-out evaluation of training exactly."""
    _, whole, _, _ = ppo_runs
    path = export_policy(whole.run_dir, "ppo-test", tmp_path)
    manifest = json.loads((path / "policy.json").read_text())
    for key in ("command", "seed", "budget_steps", "wall_time_s", "package_version"):
        assert manifest[key] is not None, key
    for name in ("model.zip", "vecnormalize.pkl", "config.yml", "eval_curve.csv", "curve.png"):
        assert (path / name).is_file(), name
    spec = agents.policy_spec(path)
    assert spec.obs_mode == "state" and spec.env_ids == (DOCKING,)
    env = make_env(DOCKING, "state", time_limit=10.0)
    agent = spec.factory(env.unwrapped)
    row = run_episode(env, agent, TRAIN_EVAL_SEED_BASE, DOCKING, spec.name)
    final = manifest["final_heldout_eval"]
    assert row.episode_return == pytest.approx(float(final["mean_return"]), abs=1e-9)
    env.close()


def test_training_level_and_episode_length_do_not_bind_the_evaluation(ppo_runs, tmp_path):
    """A policy trained at one difficulty level (or episode length) is evaluated at any;
    its other environment arguments (e.g. LARS control) still bind."""
    _, whole, _, _ = ppo_runs
    path = export_policy(whole.run_dir, "ppo-test-level", tmp_path)
    manifest = json.loads((path / "policy.json").read_text())
    manifest["env_kwargs"] = {"difficulty": "paper", "time_limit": 10.0, "scenario": "current"}
    (path / "policy.json").write_text(json.dumps(manifest))
    spec = agents.policy_spec(path)
    assert spec.env_kwargs == {"scenario": "current"}


def test_exported_seed_carries_its_group(ppo_runs, tmp_path):
    _, whole, _, _ = ppo_runs
    path = export_policy(whole.run_dir, "ppo-test-s7", tmp_path, group="ppo-test")
    assert json.loads((path / "policy.json").read_text())["group"] == "ppo-test"
    assert agents.policy_spec(path).group == "ppo-test"
    plain = export_policy(whole.run_dir, "ppo-test", tmp_path)
    assert "group" not in json.loads((plain / "policy.json").read_text())
    assert agents.policy_spec(plain).group is None
    with pytest.raises(ValueError, match="group"):
        export_policy(whole.run_dir, "ppo-test-s8", tmp_path, group="Bad Group")


def test_policy_files_are_checked(ppo_runs, tmp_path):
    _, whole, _, _ = ppo_runs
    path = export_policy(whole.run_dir, "ppo-check", tmp_path)
    env = make_env(DOCKING, "state")
    with pytest.raises(PolicyFileError, match="obs_mode"):
        PolicyAgent.from_directory(make_env(DOCKING, "features"), path)
    (path / "vecnormalize.pkl").write_bytes(b"truncated")
    with pytest.raises(PolicyFileError, match="corrupt"):
        PolicyAgent.from_directory(env, path)
    (path / "model.zip").unlink()
    with pytest.raises(PolicyFileError, match="missing"):
        PolicyAgent.from_directory(env, path)
    (path / "policy.json").write_text("{")
    with pytest.raises(PolicyFileError, match="corrupt"):
        agents.policy_spec(path)
    env.close()


def test_every_environment_has_a_shipped_policy():
    shipped = {agent_spec(name).env_ids[0] for name in agents.SHIPPED}
    assert shipped == set(ENV_IDS)


@pytest.mark.parametrize("name", agents.SHIPPED)
def test_shipped_policies_load_and_act_in_bounds(name):
    spec = agent_spec(name)
    env = make_env(spec.env_ids[0], spec.obs_mode, **spec.env_kwargs)  # e.g. its image size
    agent = make_agent(name, env)
    obs, info = env.reset(seed=EVAL_SEED_BASE)
    agent.reset(EVAL_SEED_BASE)
    space = env.action_space
    for _ in range(20):
        action = agent.act(obs, info)
        assert action.shape == space.shape and np.all(np.isfinite(action))
        assert np.all(action >= space.low) and np.all(action <= space.high)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
