"""The compiled PPO (baselines.rl.compiled): its parts against independent references, its
export against its own JAX policy, and one tiny run end to end into the leaderboard's agent."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import yaml

pytest.importorskip("jax")
pytest.importorskip("optax")
pytest.importorskip("mujoco.mjx")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from stable_baselines3.common.running_mean_std import RunningMeanStd  # noqa: E402

import auv_envs  # noqa: E402,F401
from baselines.rl import compiled  # noqa: E402
from baselines.rl.agents import load_policy_agent, register_external_policy  # noqa: E402
from baselines.rl.marker_track import MarkerTrack  # noqa: E402
from baselines.rl.policy import PolicyFileError  # noqa: E402

ENV_ID = "auv_envs/DockingStation-v2"


def _features_observations(n: int, **kwargs) -> tuple[gym.Env, list]:
    env = gym.make(ENV_ID, obs_mode="features", scenario="current", **kwargs).unwrapped
    obs, _ = env.reset(seed=3)
    observations = [obs]
    for _ in range(n - 1):
        obs, *_ = env.step(np.array([0.4, 0.1, -0.1, 0.05], np.float32))
        observations.append(obs)
    return env, observations


def test_flattening_is_gymnasiums():
    env, observations = _features_observations(5)
    keys = tuple(env.observation_space.spaces)
    for obs in observations:
        expected = gym.spaces.flatten(env.observation_space, obs)
        got = compiled.flatten_observation({k: jnp.asarray(v) for k, v in obs.items()}, keys)
        np.testing.assert_array_equal(np.asarray(got), expected.astype(np.float32))


def test_normalizer_is_sb3s_running_mean_std():
    rng = np.random.default_rng(0)
    reference = RunningMeanStd(shape=(3,))
    ours = compiled.Normalizer.create(3)
    for scale in (1.0, 5.0, 0.1):
        batch = rng.normal(2.0, scale, size=(64, 3))
        reference.update(batch)
        ours = ours.update(jnp.asarray(batch, jnp.float32))
    np.testing.assert_allclose(np.asarray(ours.mean), reference.mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(ours.var), reference.var, rtol=1e-4)
    assert float(ours.count) == pytest.approx(reference.count)


def _policy_and_normalizer(env):
    size = int(gym.spaces.flatdim(env.observation_space))
    params = compiled.init_params(jax.random.PRNGKey(1), size, 4)
    # A head far from SB3's near-zero start, so the check sees every layer.
    params["pi"][-1]["w"] = params["pi"][-1]["w"] * 300.0
    _, observations = _features_observations(40)
    keys = tuple(env.observation_space.spaces)
    flat = jnp.stack([compiled.flatten_observation(o, keys) for o in observations])
    normalizer = compiled.Normalizer.create(size).update(flat)
    return params, normalizer, observations, flat


def test_export_is_an_sb3_policy_acting_as_the_jax_one(tmp_path):
    functional = pytest.importorskip("auv_envs.batched.functional")
    env = functional.FunctionalEnv(ENV_ID, obs_mode="features")
    params, normalizer, observations, flat = _policy_and_normalizer(env)
    run = {"env_id": ENV_ID, "obs_mode": "features", "seed": 0, "n_timesteps": 0,
           "wall_time_s": 0.0, "difficulty": "paper",
           "settings": compiled.DEFAULT_SETTINGS._asdict(), "curve": []}
    manifest = compiled.export(params, normalizer, tmp_path / "policy", run)
    assert manifest["algo"] == "ppo" and manifest["flatten_obs"] is True
    cpu = gym.make(ENV_ID, obs_mode="features").unwrapped
    agent = load_policy_agent(tmp_path / "policy", cpu)
    expected = np.clip(np.asarray(compiled._mlp(params["pi"], normalizer(flat))), -1.0, 1.0)
    acted = np.stack([agent.act(obs, {}) for obs in observations])
    assert np.abs(expected).max() > 0.05  # the actions are not all near zero
    np.testing.assert_allclose(acted, expected, atol=2e-5)
    # A corrupt weight file is refused by name.
    (tmp_path / "policy" / "model.zip").write_bytes(b"not a zip")
    with pytest.raises(PolicyFileError, match="model.zip"):
        load_policy_agent(tmp_path / "policy", cpu)


#: A run small enough for a test: two iterations of 8 envs x 8 steps.
TINY = ["--set", "num_envs=8", "--set", "n_steps=8", "--set", "n_minibatches=2",
        "--set", "n_epochs=1", "--n-timesteps", "128", "--no-compilation-cache"]


def test_train_py_trains_writes_exports_and_ranks_a_cppo_run(tmp_path, capsys):
    import train as train_cli

    run_dir = tmp_path / "run"
    argv = ["--algo", "cppo", "--env", "DockingStation-v2", "--seed", "3", "--run-dir",
            str(run_dir), *TINY, "--set", "evals=2", "--set", "checkpoints=true"]
    assert train_cli.main(argv) == 0
    info = json.loads((run_dir / "run.json").read_text())
    assert (info["status"], info["steps"], info["seed"], info["algo"]) == (
        "finished", 128, 3, "cppo")
    assert info["command"].startswith("python train.py --algo cppo")
    config = yaml.safe_load((run_dir / "config.yml").read_text())
    assert config["hyperparams"]["num_envs"] == 8 and config["run"]["n_timesteps"] == 128
    assert config["run"]["env_kwargs"] == {"difficulty": "paper"}  # cppo.yml's default
    manifest = json.loads((run_dir / "final" / "policy.json").read_text())
    assert manifest["n_timesteps"] == 128 and manifest["command"] == info["command"]
    # The policy after the first of two iterations, with the wall time it had then.
    first = json.loads((run_dir / "checkpoints" / "step_64" / "policy.json").read_text())
    assert first["n_timesteps"] == 64 and 0 < first["wall_time_s"] <= manifest["wall_time_s"]
    assert first["files"] != manifest["files"]
    assert not (run_dir / "checkpoints" / "step_128").exists()  # that is final/
    # scripts/time_to_success.py reads them in training order, final/ last.
    from scripts.time_to_success import checkpoint_loaders

    loaded = [load()[:2] for load in checkpoint_loaders(run_dir, "paper")]
    assert loaded == [(64, first["wall_time_s"]), (128, manifest["wall_time_s"])]
    curve = (run_dir / "eval_curve.csv").read_text().splitlines()
    assert curve[0].startswith("step,") and len(curve) == 3
    assert (run_dir / "curve.png").stat().st_size > 0
    from scripts import plot_seeds  # the multi-seed plot reads it as a train.py curve

    assert sorted(plot_seeds.read_curve(run_dir)) == [64, 128]
    # The run directory ranks as it is; exported, the policy keeps its group.
    name = register_external_policy(run_dir)
    from baselines.registry import make_agent

    env = gym.make(ENV_ID, obs_mode="features", difficulty="paper")
    agent = make_agent(name, env)
    obs, info = env.reset(seed=1)
    assert env.action_space.contains(agent.act(obs, info))
    assert train_cli.main(["--export", str(run_dir), "--export-policy", "tiny-s3",
                           "--export-group", "tiny", "--policies-dir", str(tmp_path)]) == 0
    shipped = json.loads((tmp_path / "tiny-s3" / "policy.json").read_text())
    assert shipped["group"] == "tiny" and shipped["files"] == manifest["files"]
    assert shipped["versions"]["jax"] == jax.__version__
    assert "compiled in JAX" in shipped["description"]
    # A compiled run cannot be resumed, and a used run directory is refused.
    capsys.readouterr()
    assert train_cli.main(["--resume", str(run_dir)]) == 2
    assert "cannot be resumed" in capsys.readouterr().err
    assert train_cli.main(argv) == 2
    assert "already holds a run" in capsys.readouterr().err


def test_sigterm_writes_the_cppo_policy_so_far(tmp_path, monkeypatch):
    import signal

    import train as train_cli

    real_train = compiled.train

    def signalled(*args, stop, **kwargs):
        def ask():  # SIGTERM arrives during the first iteration, as `kill` would send it
            signal.raise_signal(signal.SIGTERM)
            return stop()

        return real_train(*args, stop=ask, **kwargs)

    monkeypatch.setattr(compiled, "train", signalled)
    run_dir = tmp_path / "run"
    code = train_cli.main(["--algo", "cppo", "--env", "LampArrayDocking-v2", "--run-dir",
                           str(run_dir), *TINY, "--set", "evals=1"])
    assert code == 128 + signal.SIGTERM
    info = json.loads((run_dir / "run.json").read_text())
    assert (info["status"], info["steps"]) == ("interrupted", 64)
    manifest = json.loads((run_dir / "final" / "policy.json").read_text())
    assert manifest["n_timesteps"] == 64
    env = gym.make("auv_envs/LampArrayDocking-v2", obs_mode="features")
    agent = load_policy_agent(run_dir / "final", env)  # the policy so far acts
    obs, info = env.reset(seed=2)
    assert env.action_space.contains(agent.act(obs, info))
    with pytest.raises(ValueError, match="has not finished"):
        from baselines.rl.export import export_policy

        export_policy(run_dir, "half", tmp_path / "policies")


def test_a_run_without_evaluations_ships_without_a_curve(tmp_path, capsys):
    """evals: 0 (the acoustic recipe): no batched evaluation, an empty eval_curve.csv and
    no empty plot, in the run nor in the shipped policy."""
    import train as train_cli

    run_dir = tmp_path / "run"
    argv = ["--algo", "cppo", "--env", "DockingStation-v2", "--seed", "3", "--run-dir",
            str(run_dir), *TINY, "--set", "evals=0", "--export-policy", "quiet",
            "--policies-dir", str(tmp_path / "policies")]
    assert train_cli.main(argv) == 0
    assert "no learning curve: nothing was evaluated" in capsys.readouterr().out
    assert (run_dir / "eval_curve.csv").read_text().splitlines() == ["step"]
    assert not (run_dir / "curve.png").exists()
    shipped = tmp_path / "policies" / "quiet"
    assert (shipped / "model.zip").is_file() and not (shipped / "curve.png").exists()
    assert json.loads((shipped / "policy.json").read_text())["final_heldout_eval"] is None


@pytest.mark.parametrize(("overrides", "message"), [
    ({"learning_rate": "3e-4"}, "write 3.0e-4"),
    ({"num_envs": 0}, r"num_envs must be an integer in \[1, inf\)"),
    ({"gamma": -0.1}, r"gamma must be a finite number in \[0, 1\]"),
    ({"n_epochs": 2.5}, "n_epochs must be an integer"),
    ({"obs_mode": "measurements"}, r"obs_mode \('state', 'features', 'nav', 'nav_features'\)"),
    ({"env_kwargs": {"difficulty": "extreme"}}, "difficulty must be one of"),
    ({"env_kwargs": {"sea_state": 3}}, "may set difficulty, control, time_limit only"),
    ({"policy": "CnnPolicy"}, "MlpPolicy, JointResidualPolicy or DetectionSetPolicy"),
    ({"policy": "DetectionSetPolicy", "normalize": False}, "detection_fixes: true"),
    ({"detection_fixes": True}, "AcousticTracking-v2's measurements front end"),
    ({"lstm_hidden_size": -1}, r"lstm_hidden_size must be an integer in \[0, 4096\]"),
    ({"lstm_hidden_size": 8, "policy": "JointResidualPolicy", "normalize": False,
      "marker_track": True}, "has none"),
    ({"lstm_hidden_size": 8, "num_envs": 12, "n_minibatches": 8, "n_steps": 2},
     "whole rollouts"),
    ({"teacher": "homing-pd", "privileged_critic": True}, "replaces the critic"),
    ({"teacher_fraction": 1.5}, r"teacher_fraction must be a finite number in \[0, 1\]"),
    ({"detection_fixes": True, "policy": "DetectionSetPolicy", "normalize": False},
     "AcousticTracking-v2's measurements front end"),
    ({"policy": "JointResidualPolicy", "normalize": False}, "set marker_track: true"),
    ({"marker_track": True}, "LARSCapture-v0's features front end"),
    ({"marker_track": "yes"}, "marker_track must be true or false"),
    ({"log_std_init": 5.0}, r"log_std_init must be a finite number in \[-20, 2\]"),
    ({"num_envs": 10, "n_minibatches": 48}, "must split into"),
    ({"evals": -1}, r"evals must be an integer in \[0, inf\)"),
    ({"checkpoints": "yes"}, "checkpoints must be true or false"),
    ({"policy_kwargs": {}}, "unknown setting 'policy_kwargs'"),
])
def test_cppo_configs_are_checked(overrides, message):
    from baselines.rl.config import ConfigError, resolve_config

    with pytest.raises(ConfigError, match=message):
        resolve_config("cppo", ENV_ID, 0, overrides)


def test_cppo_yml_holds_the_trainers_defaults_and_only_batched_envs():
    from baselines.rl.config import ConfigError, resolve_config

    budgets = {"auv_envs/DockingStation-v2": 1_500_000, "auv_envs/LampArrayDocking-v2": 3_000_000}
    for env_id, budget in budgets.items():  # the shipped policies' recipes
        config = resolve_config("cppo", env_id, 7)
        assert compiled.Settings(**config.hyperparams) == compiled.DEFAULT_SETTINGS
        assert config.run["n_timesteps"] == budget
        assert config.run["env_kwargs"] == {"difficulty": "paper"}
    acoustic = resolve_config("cppo", "auv_envs/AcousticTracking-v2", 0)
    assert acoustic.run["obs_mode"] == "measurements" and acoustic.run["detection_fixes"]
    assert acoustic.run["n_timesteps"] == 100_000 and acoustic.run["evals"] == 0
    assert compiled.Settings(**acoustic.hyperparams).policy == compiled.SET_POLICY
    lars = resolve_config("cppo", "auv_envs/LARSCapture-v0", 0)  # cppo-lars-features
    assert lars.run["marker_track"] and lars.run["n_timesteps"] == 300_000
    assert lars.run["env_kwargs"] == {"difficulty": "paper", "control": "position",
                                      "time_limit": 20.0}
    assert compiled.Settings(**lars.hyperparams).policy == compiled.RESIDUAL
    with pytest.raises(ConfigError, match="set env_kwargs: {control: position}"):
        resolve_config("cppo", "auv_envs/LARSCapture-v0", 0,
                       {"env_kwargs": {"difficulty": "paper", "control": "torque"}})
    with pytest.raises(ConfigError, match="unknown env id"):
        resolve_config("cppo", "auv_envs/LARSCapture-v9", 0)
    with pytest.raises(ConfigError, match="seed must be"):
        resolve_config("cppo", ENV_ID, -1)


def test_compilation_cache_keeps_compiled_programs(tmp_path):
    # A fresh process, as a training run: JAX's cache can be set once per process.
    import subprocess
    import sys

    code = (
        "import sys, jax, jax.numpy as jnp\n"
        "from pathlib import Path\n"
        "from baselines.rl.compiled import use_compilation_cache\n"
        "use_compilation_cache(Path(sys.argv[1]))\n"
        "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.0)\n"
        "print(float(jax.jit(lambda x: jnp.sin(x) * 3.0)(jnp.float32(0.5))))\n"
    )
    cache = tmp_path / "made" / "here"
    out = subprocess.run([sys.executable, "-c", code, str(cache)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert float(out.stdout.split()[-1]) == pytest.approx(3.0 * np.sin(0.5), rel=1e-6)
    assert any(cache.iterdir())  # the program was written
    # Asked for on the CPU, the cache is used with a warning of the loader's crashes.
    assert "RuntimeWarning" in out.stderr and "can crash" in out.stderr
    default = compiled.default_compilation_cache()
    assert default.parts[-3:-1] == ("auv_envs", "jax")


def test_another_host_never_shares_the_default_cache(monkeypatch):
    """The default cache is one directory per kind of host: a second host with other CPU
    features (faked) gets another directory, one with the same features the same."""
    from auv_envs.batched import compile_cache
    from auv_envs.core import cache

    here = compile_cache.default_compilation_cache()
    assert here.name == cache.host_key() and here.parent.name == "jax"
    features = cache.cpu_features()
    monkeypatch.setattr(cache, "cpu_features", lambda: features + " avx512f_fake")
    assert compile_cache.default_compilation_cache() != here
    monkeypatch.setattr(cache, "cpu_features", lambda: features)
    assert compile_cache.default_compilation_cache() == here


def test_the_default_cache_is_none_on_the_cpu():
    from auv_envs.batched.compile_cache import cache_for

    assert cache_for("cpu") is None
    assert cache_for("gpu") == cache_for("tpu") == compiled.default_compilation_cache()
    # train.py's default on this machine: the backend decides.
    expected = None if jax.default_backend() == "cpu" else compiled.default_compilation_cache()
    assert compiled.cache_for() == expected
    # Without a directory, nothing is set on the CPU.
    if not jax.config.jax_compilation_cache_dir:
        assert compiled.use_compilation_cache(platform="cpu") is None
        assert not jax.config.jax_compilation_cache_dir


@pytest.mark.parametrize("name", [*(f"cppo-{family}-features-s{seed}"
                                    for family in ("docking", "lamp-array", "lars")
                                    for seed in range(3)),
                                  *(f"cppo-acoustic-measurements-s{seed}" for seed in range(3))])
def test_shipped_cppo_policies_were_trained_from_cppo_yml(name):
    from baselines.rl.config import TrainConfig, resolve_config
    from baselines.rl.manifest import policies_root

    # read as train.py reads a config (run keys added since filled with their defaults)
    shipped = TrainConfig.from_dict(
        yaml.safe_load((policies_root() / name / "config.yml").read_text())).to_dict()
    assert shipped == resolve_config("cppo", shipped["env_id"], shipped["seed"]).to_dict()
    manifest = json.loads((policies_root() / name / "policy.json").read_text())
    assert manifest["command"].startswith("python train.py --algo cppo")
    assert manifest["group"] == name.rsplit("-s", 1)[0]


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("family, env_id, steps", [
    ("docking", "auv_envs/DockingStation-v2", 4_000_000),
    ("lamp-array", "auv_envs/LampArrayDocking-v2", 6_000_000),
])
def test_the_hard_level_policies_are_cppo_yml_at_hard(family, env_id, steps, seed):
    # cppo-*-features-hard: the shipped recipe with two overrides, as
    # docs/training.md gives the command.
    from baselines.rl.config import TrainConfig, resolve_config
    from baselines.rl.manifest import policies_root

    name = f"cppo-{family}-features-hard-s{seed}"
    shipped = TrainConfig.from_dict(
        yaml.safe_load((policies_root() / name / "config.yml").read_text())).to_dict()
    overrides = {"env_kwargs": {"difficulty": "hard"}, "n_timesteps": steps}
    assert shipped == resolve_config("cppo", env_id, seed, overrides).to_dict()
    manifest = json.loads((policies_root() / name / "policy.json").read_text())
    assert manifest["env_kwargs"] == {"difficulty": "hard"}
    assert manifest["group"] == f"cppo-{family}-features-hard"
    assert f"--set 'env_kwargs={{difficulty: hard}}' --n-timesteps {steps}" in manifest["command"]


def test_cppo_knows_every_batched_family_and_its_modes():
    """cppo trains every family of the table, in the modes its JAX task builds (the one
    batched shell refuses the others, and superseded ids)."""
    from auv_envs.families import FAMILIES
    from baselines.rl.config import COMPILED_ENV_IDS

    assert COMPILED_ENV_IDS == tuple(entry.env_id for entry in FAMILIES)
    from auv_envs.batched.functional import FunctionalEnv

    for entry in FAMILIES:
        entry.jax_task_class()  # importable
        assert entry.batched_mode in entry.batched_modes
        with pytest.raises(ValueError, match="obs_mode"):
            FunctionalEnv(entry.env_id, obs_mode="image")
        for old in entry.previous:
            with pytest.raises(ValueError, match="superseded"):
                FunctionalEnv(old, obs_mode=entry.batched_mode)


def test_the_residual_lars_policy_exports_as_sb3s_and_acts_as_on_jax(tmp_path):
    """cppo-lars-features' recipe: an iteration of 4 envs x 4 steps on the marker tracker's
    observation, then the JointResidualPolicy written and acting in the CPU env (through
    MarkerTrack) as the JAX policy acts; untrained, it is the servo exactly."""
    from baselines.rl.marker_track import SLICES

    kwargs = {"difficulty": "paper", "control": "position", "time_limit": 20.0}
    env = compiled.make_env("auv_envs/LARSCapture-v0", "features", kwargs, marker_track=True)
    settings = compiled.Settings(num_envs=4, n_steps=4, n_minibatches=2, n_epochs=1,
                                 policy=compiled.RESIDUAL, normalize=False, log_std_init=-5.0)
    trainer = compiled.Trainer(env, settings)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    obs = np.asarray(rollout.env.obs)
    servo = obs[:, SLICES["hold_target"]] + 0.3 * obs[:, SLICES["joint_offset"]]
    np.testing.assert_allclose(compiled.policy_mean(params, rollout.env.obs, rollout.env.obs),
                               servo, atol=1e-6)
    params, opt_state, normalizer, rollout, key, stats = trainer.iteration(
        params, opt_state, normalizer, rollout, key)
    assert bool(trainer.all_finite(params))
    params["pi"][-1]["w"] = params["pi"][-1]["w"] + 0.05  # a correction far from zero
    params["servo_gain"] = jnp.asarray([0.2, 0.4, 0.5])
    run = {"env_id": "auv_envs/LARSCapture-v0", "obs_mode": "features", "seed": 0,
           "n_timesteps": 16, "wall_time_s": 0.0, "difficulty": "paper", "env_kwargs": kwargs,
           "marker_track": True, "settings": settings._asdict(), "curve": []}
    manifest = compiled.export(params, normalizer, tmp_path / "policy", run)
    assert manifest["marker_track"] and manifest["env_kwargs"] == kwargs
    assert set(manifest["files"]) == {"model.zip"}  # no normaliser: the observation as it is
    cpu = gym.make("auv_envs/LARSCapture-v0", obs_mode="features", **kwargs).unwrapped
    agent = load_policy_agent(tmp_path / "policy", cpu)
    tracker = MarkerTrack(gym.make("auv_envs/LARSCapture-v0", obs_mode="features", **kwargs))
    for seed in (4, 5):  # one agent, two episodes: its tracker starts afresh with each
        obs, info = cpu.reset(seed=seed)
        agent.reset(seed)
        tracker.clear()
        for _ in range(20):  # the agent's own tracker and this one see the same observations
            vector = jnp.asarray(tracker.observation(obs))[None]
            expected = np.clip(np.asarray(compiled.policy_mean(params, vector, vector)[0]),
                               -1, 1)
            action = agent.act(obs, info)
            np.testing.assert_allclose(action, expected, atol=1e-5)
            obs, _, terminated, truncated, info = cpu.step(action)
            if terminated or truncated:
                break


def test_one_iteration_on_acoustic_exports_a_policy_for_its_cpu_env(tmp_path):
    """An iteration of 4 envs x 4 steps, then the policy written and acting in the CPU env
    as the JAX policy acts, through the action box's rescaling."""
    env_id, obs_mode = "auv_envs/AcousticTracking-v2", "measurements"
    env = compiled.make_env(env_id, obs_mode, "paper")
    settings = compiled.Settings(num_envs=4, n_steps=4, n_minibatches=2, n_epochs=1)
    trainer = compiled.Trainer(env, settings)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    params, opt_state, normalizer, rollout, key, stats = trainer.iteration(
        params, opt_state, normalizer, rollout, key)
    assert bool(trainer.all_finite((params, normalizer))) and int(stats["episodes"]) == 0
    params["pi"][-1]["w"] = params["pi"][-1]["w"] * 300.0  # actions far from zero
    run = {"env_id": env_id, "obs_mode": obs_mode, "seed": 0, "n_timesteps": 16,
           "wall_time_s": 0.0, "difficulty": "paper", "settings": settings._asdict(),
           "curve": []}
    compiled.export(params, normalizer, tmp_path / "policy", run)
    cpu = gym.make(env_id, obs_mode=obs_mode, difficulty="paper").unwrapped
    agent = load_policy_agent(tmp_path / "policy", cpu)
    obs, info = cpu.reset(seed=4)
    flat = compiled.flatten_observation({k: jnp.asarray(v) for k, v in obs.items()},
                                        trainer.keys)
    unit = np.clip(np.asarray(compiled._mlp(params["pi"], normalizer(flat[None]))[0]),
                   -1.0, 1.0)
    # The batched env's action from the unit action is the CPU policy's action.
    np.testing.assert_allclose(agent.act(obs, info), np.asarray(env._action(unit)),
                               rtol=1e-5, atol=1e-4)
    assert cpu.action_space.contains(agent.act(obs, info))


@pytest.mark.parametrize("front_end", ["detection_fixes", "detection_track"])
def test_the_set_policy_exports_as_sb3s_and_acts_as_on_jax(tmp_path, front_end):
    """cppo-acoustic-measurements' recipe: an iteration of 4 envs x 4 steps on the detection
    fixes (or the fixes and their track), then the DetectionSetPolicy written and acting in
    the CPU env (through the CPU front end) as the JAX set encoder acts."""
    from baselines.rl.detection_fixes import DetectionFixes, DetectionTrack

    env_id, kwargs = "auv_envs/AcousticTracking-v2", {"difficulty": "hard", "time_limit": 20.0}
    env = compiled.make_env(env_id, "measurements", kwargs, **{front_end: True})
    settings = compiled.Settings(num_envs=4, n_steps=4, n_minibatches=2, n_epochs=1,
                                 policy=compiled.SET_POLICY, normalize=False,
                                 log_std_init=-6.0, gamma=0.0)
    trainer = compiled.Trainer(env, settings)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    params, opt_state, normalizer, rollout, key, stats = trainer.iteration(
        params, opt_state, normalizer, rollout, key)
    assert bool(trainer.all_finite(params))
    # scores far from their start, so that the weights differ from token to token
    params["set"]["score"]["w"] = params["set"]["score"]["w"] * 20.0
    run = {"env_id": env_id, "obs_mode": "measurements", "seed": 0, "n_timesteps": 16,
           "wall_time_s": 0.0, "difficulty": "hard", "env_kwargs": kwargs,
           front_end: True, "settings": settings._asdict(), "curve": []}
    manifest = compiled.export(params, normalizer, tmp_path / "policy", run)
    assert manifest[front_end] and not manifest["flatten_obs"]
    assert set(manifest["files"]) == {"model.zip"}
    cpu = gym.make(env_id, obs_mode="measurements", **kwargs).unwrapped
    agent = load_policy_agent(tmp_path / "policy", cpu)
    front = {"detection_fixes": DetectionFixes, "detection_track": DetectionTrack}[front_end](
        gym.make(env_id, obs_mode="measurements", **kwargs))
    space = front.observation_space
    obs, info = cpu.reset(seed=6)
    agent.reset(6)
    front.clear()
    departures = []
    for _ in range(30):
        tokens = front.observation(obs)
        flat = compiled.flatten_observation({k: jnp.asarray(v) for k, v in tokens.items()},
                                            tuple(space.spaces))
        features = compiled.set_features(params["set"],
                                         compiled.unflatten_observation(flat, space))
        unit = np.clip(np.asarray(features[:3]), -1.0, 1.0)
        action = agent.act(obs, info)
        np.testing.assert_allclose(action, np.asarray(env._action(unit)), rtol=1e-5, atol=1e-3)
        valid = np.concatenate([tokens["fix"][tokens["fix_valid"] > 0],
                                tokens["held_fix"][tokens["held_fix_valid"] > 0]])
        if len(valid) > 1:  # how far the weights took the pooled fix from the plain mean
            plain = np.asarray(env._action(valid.mean(axis=0)))
            departures.append(float(np.max(np.abs(action - plain))))
        obs, _, terminated, truncated, info = cpu.step(action)
    assert departures and max(departures) > 0.01  # metres: the weights were compared
