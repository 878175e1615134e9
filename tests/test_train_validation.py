"""train.py refuses every out-of-range hyperparameter up front, and a diverging run stops.

The ranges are the one table :data:`baselines.rl.config.RANGES`; a run whose model
becomes non-finite stops with :class:`baselines.rl.training.TrainingDiverged`, keeps its
last good checkpoint and resumes from it (with a smaller learning rate).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from stable_baselines3.common.callbacks import BaseCallback

import auv_envs
import train as train_cli
from baselines.commands.train import DIVERGED
from baselines.rl import training
from baselines.rl.checkpoint import CheckpointError, latest_checkpoint, verify_checkpoint
from baselines.rl.config import (
    COMPILED,
    COMPILED_ENV_IDS,
    HYPERPARAMS_DIR,
    RANGES,
    RUN_KEYS,
    TRAINERS,
    ConfigError,
    accepted_forms,
    algo_arguments,
    parse_overrides,
    read_config,
    resolve_config,
    run_keys,
)
from baselines.rl.policy import load_model

ROOT = Path(__file__).resolve().parents[1]
DOCKING = "auv_envs/DockingStation-v2"
ACOUSTIC = "auv_envs/AcousticTracking-v2"

#: One ``--set`` per out-of-range value: (algo, env, setting, the key the error names).
INVALID = [
    ("ppo", DOCKING, "clip_range=-1.0", "clip_range"),
    ("ppo", DOCKING, "clip_range=0", "clip_range"),
    ("ppo", DOCKING, "clip_range=lin_-0.2", "clip_range"),
    ("ppo", DOCKING, "clip_range_vf=0.0", "clip_range_vf"),
    ("ppo", DOCKING, "n_timesteps=0", "n_timesteps"),
    ("ppo", DOCKING, "n_steps=-1", "n_steps"),
    ("ppo", DOCKING, "n_steps=2.5", "n_steps"),
    ("ppo", DOCKING, "batch_size=0", "batch_size"),
    ("ppo", DOCKING, "batch_size=1", "batch_size"),  # SB3 asserts > 1 (normalize_advantage)
    ("ppo", DOCKING, "n_epochs=0", "n_epochs"),
    ("ppo", DOCKING, "gamma=2.0", "gamma"),
    ("ppo", DOCKING, "gamma=-0.1", "gamma"),
    ("ppo", DOCKING, "gamma=.nan", "gamma"),
    ("ppo", DOCKING, "gae_lambda=1.5", "gae_lambda"),
    ("ppo", DOCKING, "ent_coef=.nan", "ent_coef"),
    ("ppo", DOCKING, "ent_coef=-0.01", "ent_coef"),
    ("ppo", DOCKING, "ent_coef=auto", "ent_coef"),  # SAC's only
    ("ppo", DOCKING, "vf_coef=-1.0", "vf_coef"),
    ("ppo", DOCKING, "max_grad_norm=0", "max_grad_norm"),
    ("ppo", DOCKING, "learning_rate=0", "learning_rate"),
    ("ppo", DOCKING, "learning_rate=.inf", "learning_rate"),
    ("ppo", DOCKING, "learning_rate=lin_0", "learning_rate"),
    ("ppo", DOCKING, "target_kl=0.0", "target_kl"),
    ("ppo", DOCKING, "sde_sample_freq=0", "sde_sample_freq"),
    ("ppo", DOCKING, "normalize_advantage=1", "normalize_advantage"),
    ("a2c", DOCKING, "n_steps=0", "n_steps"),
    ("a2c", DOCKING, "rms_prop_eps=0.0", "rms_prop_eps"),
    ("a2c", DOCKING, "gamma=1.01", "gamma"),
    ("sac", ACOUSTIC, "tau=0", "tau"),
    ("sac", ACOUSTIC, "tau=1.5", "tau"),
    ("sac", ACOUSTIC, "buffer_size=0", "buffer_size"),
    ("sac", ACOUSTIC, "learning_starts=-1", "learning_starts"),
    ("sac", ACOUSTIC, "train_freq=0", "train_freq"),
    ("sac", ACOUSTIC, "train_freq=[1, 'epoch']", "train_freq"),
    ("sac", ACOUSTIC, "gradient_steps=0", "gradient_steps"),
    ("sac", ACOUSTIC, "ent_coef=auto_0", "ent_coef"),
    ("sac", ACOUSTIC, "ent_coef=.nan", "ent_coef"),
    ("sac", ACOUSTIC, "target_entropy=auto_1", "target_entropy"),
    ("sac", ACOUSTIC, "target_update_interval=0", "target_update_interval"),
    ("sac", ACOUSTIC, "n_steps=0", "n_steps"),
    ("td3", ACOUSTIC, "policy_delay=0", "policy_delay"),
    ("td3", ACOUSTIC, "target_policy_noise=-0.1", "target_policy_noise"),
    ("td3", ACOUSTIC, "target_noise_clip=.inf", "target_noise_clip"),
    ("ddpg", ACOUSTIC, "batch_size=0", "batch_size"),
    ("ddpg", ACOUSTIC, "action_noise={type: normal, sigma: -0.1}", "action_noise.sigma"),
    ("ddpg", ACOUSTIC, "action_noise={type: pink, sigma: 0.1}", "action_noise"),
    ("ppo", DOCKING, "policy_kwargs.log_std_init=.nan", "policy_kwargs.log_std_init"),
    ("ppo", DOCKING, "n_envs=0", "n_envs"),
    ("ppo", DOCKING, "eval_freq=0", "eval_freq"),
    ("ppo", DOCKING, "n_eval_episodes=-1", "n_eval_episodes"),
    ("ppo", DOCKING, "n_eval_episodes=10001", "n_eval_episodes"),
    ("ppo", DOCKING, "checkpoint_freq=0", "checkpoint_freq"),
    ("ppo", DOCKING, "keep_checkpoints=0", "keep_checkpoints"),
    ("ppo", DOCKING, "torch_threads=0", "torch_threads"),
    ("cppo", DOCKING, "gamma=2.0", "gamma"),
    ("cppo", DOCKING, "clip_range=0.0", "clip_range"),
    ("cppo", DOCKING, "learning_rate=.nan", "learning_rate"),
    ("cppo", DOCKING, "learning_rate=lin_3.0e-4", "learning_rate"),  # cppo: numbers only
    ("cppo", DOCKING, "max_grad_norm=0.0", "max_grad_norm"),
    ("cppo", DOCKING, "ent_coef=-1.0", "ent_coef"),
    ("cppo", DOCKING, "num_envs=0", "num_envs"),
    ("cppo", DOCKING, "n_minibatches=0", "n_minibatches"),
    ("cppo", DOCKING, "n_timesteps=0", "n_timesteps"),
    ("cppo", DOCKING, "evals=-1", "evals"),
]


#: What the message gives as the allowed values where it is not the key's interval.
ALLOWED = {"batch_size=1": "at least 2 with normalize_advantage",
           "normalize_advantage=1": "must be bool",
           "action_noise={type: pink, sigma: 0.1}": "{type: normal|ornstein-uhlenbeck",
           "target_entropy=auto_1": "must be a finite number or 'auto'",
           "policy_kwargs.log_std_init=.nan": "must be a finite number,"}


@pytest.mark.parametrize(("algo", "env_id", "setting", "key"), INVALID,
                         ids=[f"{a}-{s}" for a, _, s, _ in INVALID])
def test_out_of_range_values_are_refused_before_anything_runs(algo, env_id, setting, key,
                                                              tmp_path, capsys):
    value = next(iter(parse_overrides([setting]).values()))
    if key == "action_noise.sigma":
        value = value["sigma"]
    with pytest.raises(ConfigError) as info:
        resolve_config(algo, env_id, 0, parse_overrides([setting]))
    message = str(info.value)
    allowed = ALLOWED.get(setting) or RANGES[key].interval  # the table's own words
    assert key in message and f"got {value!r}" in message and allowed in message, message
    run_dir = tmp_path / "run"
    rc = train_cli.main(["--algo", algo, "--env", env_id, "--set", setting,
                         "--run-dir", str(run_dir), "--no-progress-bar"])
    err = capsys.readouterr().err
    assert rc == 2 and key in err and "Traceback" not in err
    assert not run_dir.exists()


def test_sb3_refusals_that_need_the_env_are_config_errors_before_the_run_dir(tmp_path):
    # n-step returns on Dict observations: only the built env's space tells.
    config = resolve_config("sac", "auv_envs/LARSCapture-v0", 0, {
        "obs_mode": "features", "n_steps": 3, "buffer_size": 100, "n_timesteps": 64})
    with pytest.raises(ConfigError, match="Stable-Baselines3 SAC refuses"):
        training.train(config, tmp_path / "run", progress_bar=False, echo=False)
    assert not (tmp_path / "run").exists()


def test_every_numeric_argument_has_one_row_and_every_default_is_in_it():
    for algo in TRAINERS:
        for name, param in algo_arguments(algo).items():
            numeric = (isinstance(param.default, int | float)
                       and not isinstance(param.default, bool)) or any(
                t in str(param.annotation) for t in ("float", "int"))
            if not numeric:
                continue
            assert name in RANGES, f"{algo}.{name} has no row in RANGES"
            RANGES[name].check(name, param.default, accepted_forms(algo, name, param.default))
        for key, default in run_keys(algo).items():
            if isinstance(default, int) and not isinstance(default, bool):
                assert key in RANGES, key
                RANGES[key].check(key, default)
    assert set(RANGES) >= {k for k, v in RUN_KEYS.items()
                           if isinstance(v, int) and not isinstance(v, bool)}


def test_values_that_were_valid_stay_valid():
    resolve_config("sac", ACOUSTIC, 0, {"ent_coef": "auto_0.1", "train_freq": [4, "step"],
                                        "gradient_steps": -1, "gamma": 0.0})
    resolve_config("td3", ACOUSTIC, 0, {"learning_rate": "lin_1.0e-3", "gamma": 1})
    resolve_config("ppo", DOCKING, 0, {"clip_range": "lin_0.2", "clip_range_vf": None,
                                       "target_kl": 0.02, "ent_coef": 0})
    resolve_config("sac", ACOUSTIC, 0, {"train_freq": [1, "episode"], "n_envs": 1})
    with pytest.raises(ConfigError, match="train_freq in episodes needs n_envs 1"):
        resolve_config("sac", ACOUSTIC, 0, {"train_freq": [1, "episode"], "n_envs": 2})


def _shipped_entries():
    for path in sorted(HYPERPARAMS_DIR.rglob("*.yml")):
        table = yaml.safe_load(path.read_text())
        named = [k for k in table if k != "default"]
        if path.parent == HYPERPARAMS_DIR:  # the default entry serves every env
            named += COMPILED_ENV_IDS if path.stem == COMPILED else list(auv_envs.ENVIRONMENTS)
        for env_id in sorted(set(named)):
            yield path, env_id


@pytest.mark.parametrize(("path", "env_id"), list(_shipped_entries()),
                         ids=[f"{p.relative_to(HYPERPARAMS_DIR)}-{e.split('/')[1]}"
                              for p, e in _shipped_entries()])
def test_shipped_hyperparameters_validate(path, env_id):
    resolve_config(path.stem, env_id, 0, hyperparams_dir=path.parent)


def test_shipped_policies_configs_validate():
    configs = sorted((ROOT / "assets" / "policies").glob("*/config.yml"))
    assert configs
    for path in configs:
        read_config(path)


# ---------------------------------------------------------------- divergence
#: A tiny PPO: 64-step rollouts on 5 s docking episodes, a checkpoint every rollout.
TINY = ["--algo", "ppo", "--env", "DockingStation-v2", "--seed", "3", "--n-timesteps", "384",
        "--set", "n_envs=1", "--set", "n_steps=64", "--set", "batch_size=32",
        "--set", "n_epochs=2", "--set", "checkpoint_freq=64", "--set", "keep_checkpoints=5",
        "--set", "n_eval_episodes=0", "--set", "env_kwargs={time_limit: 5.0}",
        "--set", "policy_kwargs={net_arch: [8]}", "--no-progress-bar"]


def _finite_model(path: Path) -> bool:
    model = load_model("ppo", path)
    return all(torch.isfinite(p).all() for p in model.policy.parameters())


def test_huge_learning_rate_diverges_then_resumes_with_a_smaller_one(tmp_path, capsys):
    run_dir = tmp_path / "run"
    rc = train_cli.main([*TINY, "--set", "learning_rate=1.0e4", "--run-dir", str(run_dir)])
    err = capsys.readouterr().err
    assert rc == DIVERGED == 3, err
    assert "training diverged at step 64" in err and "Traceback" not in err
    assert f"--resume {run_dir} --set learning_rate=1.0e+03" in err
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "diverged" and info["steps"] == 0
    config = read_config(run_dir / "config.yml")
    last = latest_checkpoint(run_dir / "checkpoints")  # the initial model, intact
    assert last.name == "step-0000000000" and sorted(p.name for p in last.parent.iterdir()) \
        == ["latest", "step-0000000000"]
    verify_checkpoint(last, config)
    assert _finite_model(last / "model.zip") and not (run_dir / "final").exists()
    # Only the settings in RESUMABLE may change on resume.
    assert train_cli.main(["--resume", str(run_dir), "--set", "n_steps=32"]) == 2
    assert "may change only learning_rate" in capsys.readouterr().err
    rc = train_cli.main(["--resume", str(run_dir), "--set", "learning_rate=3.0e-4",
                         "--no-progress-bar"])
    assert rc == 0, capsys.readouterr().err
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "finished" and info["steps"] == 384
    assert [s["status"] for s in info["segments"]] == ["diverged", "finished"]
    assert read_config(run_dir / "config.yml").hyperparams["learning_rate"] == 3.0e-4
    model = load_model("ppo", run_dir / "final" / "model.zip")
    assert model.policy.optimizer.param_groups[0]["lr"] == pytest.approx(3.0e-4)
    assert _finite_model(run_dir / "final" / "model.zip")


class PoisonAt(BaseCallback):
    """Writes NaN into one weight of the policy once training reaches ``step`` (mid-rollout,
    as an overflowing update would leave it)."""

    def __init__(self, step: int, parameter: str):
        super().__init__()
        self.step, self.parameter, self.done = step, parameter, False

    def _on_step(self) -> bool:
        if not self.done and self.num_timesteps >= self.step:
            self.done = True
            with torch.no_grad():
                dict(self.model.policy.named_parameters())[self.parameter][0] = math.nan
        return True


@pytest.mark.parametrize("parameter", ["action_net.weight", "value_net.weight"])
def test_nan_parameters_stop_the_run_and_keep_the_last_good_checkpoint(parameter, tmp_path):
    overrides = parse_overrides([s for s in TINY[TINY.index("--set"):-1] if s != "--set"])
    config = resolve_config("ppo", DOCKING, 3, {**overrides, "n_timesteps": 384})
    run_dir = tmp_path / "run"
    with pytest.raises(training.TrainingDiverged) as info:
        training.train(config, run_dir, progress_bar=False, echo=False,
                       callbacks=[PoisonAt(150, parameter)])
    error = info.value
    # A NaN action mean fails inside the rollout; a NaN value shows in the rollout's returns.
    assert 150 <= error.step <= 192 and parameter in error.what, error.what
    assert error.checkpoint == run_dir / "checkpoints" / "step-0000000128"
    assert f"the last good checkpoint, {error.checkpoint}, is kept" in str(error)
    assert latest_checkpoint(run_dir / "checkpoints") == error.checkpoint
    assert not (run_dir / "checkpoints" / "step-0000000192").exists()
    verify_checkpoint(error.checkpoint, config)
    assert _finite_model(error.checkpoint / "model.zip")
    assert json.loads((run_dir / "run.json").read_text())["status"] == "diverged"
    result = training.resume(run_dir, progress_bar=False, echo=False)
    assert result.finished and result.steps == 384


def test_non_finite_losses_and_statistics_are_named(tmp_path):
    config = resolve_config("ppo", DOCKING, 0, {
        "n_envs": 1, "n_steps": 16, "batch_size": 8, "normalize": True,
        "env_kwargs": {"time_limit": 1.0}, "policy_kwargs": {"net_arch": [4]}})
    model = training.build_model(config)
    from stable_baselines3.common.logger import configure

    model.set_logger(configure(str(tmp_path), []))
    assert training.non_finite(model) == []
    model.logger.record("train/value_loss", math.inf)
    model.logger.record("train/explained_variance", math.nan)  # NaN there is legitimate
    model.get_vec_normalize_env().obs_rms.var[0] = np.nan
    assert training.non_finite(model) == ["observation normalisation statistics",
                                          "train/value_loss"]
    with torch.no_grad():
        model.policy.log_std.fill_(-200.0)
    assert "the action std exp(log_std) (underflowed to 0)" in training.non_finite(model)
    model.get_env().close()


def test_checkpoints_without_a_resumable_digest_still_need_their_exact_config(tmp_path):
    config = resolve_config("ppo", DOCKING, 0, {
        "n_envs": 1, "n_steps": 16, "batch_size": 8, "n_timesteps": 16, "n_eval_episodes": 0,
        "env_kwargs": {"time_limit": 1.0}, "policy_kwargs": {"net_arch": [4]}})
    training.train(config, tmp_path / "run", progress_bar=False, echo=False)
    path = latest_checkpoint(tmp_path / "run" / "checkpoints")
    lower = resolve_config("ppo", DOCKING, 0, {**config.hyperparams, **config.run,
                                               "learning_rate": 1.0e-5})
    verify_checkpoint(path, lower)  # a resume may lower the learning rate
    manifest = json.loads((path / "manifest.json").read_text())
    del manifest["resumable_digest"]  # as written before resumable_digest existed
    (path / "manifest.json").write_text(json.dumps(manifest))
    verify_checkpoint(path, config)
    with pytest.raises(CheckpointError, match="different hyperparameters"):
        verify_checkpoint(path, lower)


def test_compiled_ppo_names_its_non_finite_arrays():
    jnp = pytest.importorskip("jax.numpy")
    compiled = pytest.importorskip("baselines.rl.compiled")
    params = {"pi": [{"w": jnp.ones((2, 2)), "b": jnp.zeros(2)}],
              "log_std": jnp.array([0.0, jnp.inf])}
    normalizer = compiled.Normalizer(jnp.array([jnp.nan]), jnp.ones(1), jnp.float32(1.0))
    assert not bool(compiled._all_finite((params, normalizer)))
    assert compiled.non_finite_leaves({"policy": params, "normalizer": normalizer}) == [
        "normalizer.mean", "policy.log_std"]
    assert re.fullmatch(r"training diverged at step 64, not finite: policy\.log_std; "
                        r"no checkpoint was written before it",
                        str(training.TrainingDiverged(64, ["policy.log_std"], None,
                                                      resumable=False)))
