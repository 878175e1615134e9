"""The LARS front end for RL (baselines/rl/marker_estimate.py): estimate, policy, training."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import PPO

from baselines.evaluation import run_episode
from baselines.rl import agents
from baselines.rl.config import TRAIN_EVAL_SEED_BASE, ConfigError, resolve_config
from baselines.rl.envs import wrap_env
from baselines.rl.marker_estimate import SIZE, SLICES, JointResidualPolicy, MarkerEstimate
from tests.conftest import make_env
from tests.rl_helpers import train_and_export

ROOT = Path(__file__).resolve().parents[1]
LARS = "auv_envs/LARSCapture-v0"
CONFIG_DIR = ROOT / "baselines/rl/hyperparams/lars-features"


def _wrapped(**kwargs):
    env = make_env(LARS, "features", difficulty="paper", control="position", **kwargs)
    return wrap_env(env.unwrapped, front_ends=("marker_estimate",))


def test_estimate_follows_the_true_capture_offset():
    """Holding still, the estimated capture point minus tip tracks the env's ground truth, and
    the joint-unit vectors are the Cartesian ones through the arm's Jacobian."""
    env = _wrapped()
    base = env.unwrapped
    arm = base.calibration.arm
    limits = np.asarray(arm.joint_limits)
    half = 0.5 * (limits[:, 1] - limits[:, 0])
    obs, _ = env.reset(seed=11)
    assert env.observation_space.shape == (SIZE,) and env.observation_space.contains(obs)
    settled = 0
    for _ in range(30):
        obs, _, terminated, truncated, info = env.step(obs[SLICES["hold_target"]].copy())
        assert not (terminated or truncated)
        q = limits.mean(axis=1) + obs[SLICES["hold_target"]] * half
        np.testing.assert_allclose(q, base.physics.data.qpos[:3], atol=1e-5)
        if obs[SLICES["estimate"]][0] == 1.0:
            settled += 1
            np.testing.assert_allclose(obs[SLICES["offset"]], info["capture_offset"], atol=0.03)
        jac = arm.jacobian(q)
        for joint, cartesian in (("joint_offset", "offset"),
                                 ("joint_relative_velocity", "relative_velocity"),
                                 ("joint_offset_ahead", "offset_ahead")):
            np.testing.assert_allclose(jac @ (obs[SLICES[joint]] * half), obs[SLICES[cartesian]],
                                       atol=1e-5)
    assert settled >= 15
    # The hold target holds: the joints barely move over the 30 steps.
    assert np.abs(obs[SLICES["joint_velocity"]]).max() < 0.02


def test_clear_starts_the_estimate_afresh():
    env = _wrapped()
    first, _ = env.reset(seed=4)
    for _ in range(5):
        env.step(first[SLICES["hold_target"]].copy())
    again, _ = env.reset(seed=4)
    np.testing.assert_array_equal(first, again)
    assert again[SLICES["estimate"]][0] == 0.0  # not settled on its first fix


def test_front_end_needs_lars_features():
    with pytest.raises(ConfigError, match="marker_estimate"):
        MarkerEstimate(make_env(LARS, "state"))
    with pytest.raises(ConfigError, match="marker_estimate"):
        MarkerEstimate(make_env("auv_envs/DockingStation-v2", "features"))
    with pytest.raises(ConfigError, match="unknown front end"):
        wrap_env(make_env(LARS, "features").unwrapped, front_ends=("kalman",))


def test_untrained_policy_is_the_servo():
    """Untrained, the mean is the hold target plus the servo's gain times the joint offset
    (the MLP's correction starts at zero), whatever the seed; with no gain the arm holds
    still."""
    env = _wrapped()
    obs, _ = env.reset(seed=2)
    for _ in range(15):  # until the estimate has settled and the offset is non-zero
        obs, *_ = env.step(obs[SLICES["hold_target"]].copy())
    assert np.abs(obs[SLICES["joint_offset"]]).max() > 0.05
    hold = obs[SLICES["hold_target"]]
    for gain in (0.0, 0.3):
        model = PPO(JointResidualPolicy, env, seed=int(gain * 10), device="cpu",
                    policy_kwargs={"net_arch": [16, 16], "servo_gain": gain})
        action, _ = model.predict(obs, deterministic=True)
        np.testing.assert_allclose(action, hold + gain * obs[SLICES["joint_offset"]], atol=1e-6)
    with pytest.raises(ConfigError, match="JointResidualPolicy reads"):
        PPO(JointResidualPolicy, make_env(LARS, "state"), device="cpu")


def test_config_checks_policy_front_end_and_control_together():
    resolve_config("ppo", LARS, hyperparams_dir=CONFIG_DIR)
    for overrides, match in (
        ({"marker_estimate": False}, "marker_estimate: true"),
        ({"normalize": True}, "normalize: false"),
        ({"env_kwargs": {"difficulty": "paper"}}, "control: position"),
        ({"marker_estimate": "yes"}, "marker_estimate must be bool"),
    ):
        with pytest.raises(ConfigError, match=match):
            resolve_config("ppo", LARS, overrides=overrides, hyperparams_dir=CONFIG_DIR)
    with pytest.raises(ConfigError, match="PPO policy"):
        resolve_config("sac", LARS, overrides={"policy": "JointResidualPolicy",
                                               "marker_estimate": True})


def test_trains_exports_and_acts_as_in_training(tmp_path):
    """A tiny run from the shipped YAML; the exported agent reproduces training's final
    held-out evaluation, and the same episode twice in a row (the estimator is cleared)."""
    path, manifest = train_and_export(tmp_path, "LARSCapture-v0", CONFIG_DIR, 128,
                                      "{difficulty: paper, control: position, time_limit: 1.0}",
                                      "ppo-lars-test")
    assert manifest["marker_estimate"] is True and manifest["detection_fixes"] is False
    spec = agents.policy_spec(path)
    env = make_env(LARS, "features", difficulty="paper", control="position", time_limit=1.0)
    agent = spec.factory(env.unwrapped)
    row = run_episode(env, agent, TRAIN_EVAL_SEED_BASE, LARS, spec.name)
    final = manifest["final_heldout_eval"]
    assert row.episode_return == pytest.approx(float(final["mean_return"]), abs=1e-9)
    again = run_episode(env, agent, TRAIN_EVAL_SEED_BASE, LARS, spec.name)
    assert again.episode_return == row.episode_return
    env.close()
