"""The compiled PPO (baselines.rl.compiled): its parts against independent references, its
export against its own JAX policy, and one tiny run end to end into the leaderboard's agent."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("optax")
pytest.importorskip("mujoco.mjx")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from stable_baselines3.common.running_mean_std import RunningMeanStd  # noqa: E402

import auv_envs  # noqa: E402,F401
from baselines.rl import compiled  # noqa: E402
from baselines.rl.agents import load_policy_agent, register_external_policy  # noqa: E402
from baselines.rl.policy import PolicyFileError  # noqa: E402

ENV_ID = "auv_envs/DockingStation-v1"


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
    batched = pytest.importorskip("auv_envs.batched.docking_env")
    env = batched.DockingMJX(ENV_ID, obs_mode="features")
    params, normalizer, observations, flat = _policy_and_normalizer(env)
    run = {"seed": 0, "n_timesteps": 0, "wall_time_s": 0.0, "difficulty": "paper",
           "settings": compiled.DEFAULT_SETTINGS._asdict(), "curve": []}
    manifest = compiled.export(env, params, normalizer, tmp_path / "policy", run)
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


def test_a_tiny_run_trains_writes_and_ranks(tmp_path):
    settings = compiled.Settings(num_envs=8, n_steps=8, n_minibatches=2, n_epochs=1)
    manifest = compiled.train(ENV_ID, "paper", 128, 0, tmp_path / "run", settings, evals=2,
                              checkpoints=True)
    assert manifest["n_timesteps"] == 128
    # The policy after the first of two iterations, with the wall time it had then.
    first = json.loads((tmp_path / "run" / "checkpoints" / "step_64" / "policy.json").read_text())
    assert first["n_timesteps"] == 64 and 0 < first["wall_time_s"] <= manifest["wall_time_s"]
    assert first["files"] != manifest["files"]
    assert not (tmp_path / "run" / "checkpoints" / "step_128").exists()  # that is the run
    # scripts/time_to_success.py reads them in training order, the run last.
    from scripts.time_to_success import checkpoint_loaders

    loaded = [load()[:2] for load in checkpoint_loaders(tmp_path / "run", "paper")]
    assert loaded == [(64, first["wall_time_s"]), (128, manifest["wall_time_s"])]
    assert manifest["env_kwargs"] == {"difficulty": "paper"}
    written = json.loads((tmp_path / "run" / "policy.json").read_text())
    assert written["files"] == manifest["files"]
    curve = (tmp_path / "run" / "eval_curve.csv").read_text().splitlines()
    assert curve[0].startswith("step,") and len(curve) == 3
    from scripts import plot_seeds  # the multi-seed plot reads it as a train.py curve

    assert sorted(plot_seeds.read_curve(tmp_path / "run")) == [64, 128]
    name = register_external_policy(tmp_path / "run")
    from baselines.registry import make_agent

    env = gym.make(ENV_ID, obs_mode="features", difficulty="paper")
    agent = make_agent(name, env)
    obs, info = env.reset(seed=1)
    action = agent.act(obs, info)
    assert env.action_space.contains(action)


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
    default = compiled.default_compilation_cache()
    assert default.parts[-2:] == ("auv_envs", "jax")
