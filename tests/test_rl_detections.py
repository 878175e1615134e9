"""The acoustic detection-set encoder (baselines/rl/detections.py): fixes, invariance, training."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium.wrappers import RescaleAction

from baselines.acoustic.perception.positioning import LeastSquaresPositioner
from baselines.evaluation import run_episode
from baselines.rl import agents
from baselines.rl.config import TRAIN_EVAL_SEED_BASE, ConfigError, resolve_config
from baselines.rl.detection_fixes import DetectionTrack
from baselines.rl.detections import DetectionFixes, DetectionSetExtractor
from baselines.rl.envs import wrap_env
from tests.conftest import make_env
from tests.rl_helpers import train_and_export

ROOT = Path(__file__).resolve().parents[1]
ACOUSTIC = "auv_envs/AcousticTracking-v2"
CONFIG_DIR = ROOT / "baselines/rl/hyperparams/acoustic-measurements"


def _fixed_observations(level: str, steps: int, seed: int = 3, front_end=DetectionFixes):
    env = make_env(ACOUSTIC, "measurements", difficulty=level, time_limit=5.0)
    wrapped = front_end(env)
    raw, _ = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        out.append((raw, wrapped.observation(raw)))
        raw, *_ = env.step(env.action_space.sample())
    return env, wrapped, out


@pytest.mark.parametrize("level", ["paper", "hard"])
def test_fixes_are_the_positioners_in_the_learners_action_units(level):
    env, wrapped, pairs = _fixed_observations(level, 30)
    positioner = LeastSquaresPositioner(env.unwrapped.calibration, method="fused")
    rescale = RescaleAction(env, np.float32(-1.0), np.float32(1.0))
    valid_seen = 0
    for raw, obs in pairs:
        assert wrapped.observation_space.contains(obs)
        fixes = positioner.solve(raw["tdoa"], raw["azimuth"], raw["elevation"], raw["mask"],
                                 nodes=raw.get("node_mask"))
        valid = fixes.valid
        np.testing.assert_array_equal(obs["fix_valid"].astype(bool), valid)
        assert not (valid & ~raw["mask"].astype(bool)).any()
        valid_seen += valid.sum()
        # The action the learner would emit for a fix maps back onto the fix (RescaleAction).
        back = np.array([rescale.action(a) for a in obs["fix"][valid]])
        np.testing.assert_allclose(back, fixes.position[valid], atol=1e-3)
        std = np.sqrt(np.diagonal(fixes.covariance[valid], axis1=-2, axis2=-1))
        np.testing.assert_allclose(10.0 ** obs["fix_log_std"][valid], std, rtol=1e-4)
        np.testing.assert_allclose(np.exp(obs["fix_log_fit"][valid]),
                                   fixes.chi2[valid] / fixes.dof, rtol=1e-4)
        for key in ("fix", "fix_log_std", "fix_log_fit"):
            assert np.all(obs[key][~valid] == 0.0), key
    assert valid_seen > 0


def test_held_fixes_are_the_last_step_with_a_valid_fix_and_reset_forgets_them():
    env = make_env(ACOUSTIC, "measurements", difficulty="hard", time_limit=5.0)
    wrapped = DetectionFixes(env)
    obs, _ = wrapped.reset(seed=11)
    assert obs["held_age"][0] == 0.0 and not obs["held_fix_valid"].any()
    last, age, gaps = None, 0, 0
    raw = None
    for step in range(200):
        if last is not None:
            for key in ("fix", "fix_log_std", "fix_log_fit", "fix_valid"):
                np.testing.assert_array_equal(obs[f"held_{key}"], last[key])
            assert obs["held_age"][0] == pytest.approx(np.log1p(age))
        age += 1
        if obs["fix_valid"].any():
            last, age = obs, 1
        else:
            gaps += 1
        raw, *_ = env.step(env.action_space.sample())
        if step % 7 in (3, 4, 5):  # silence: nothing heard for three steps
            raw = {**raw, "mask": np.zeros_like(raw["mask"])}
        obs = wrapped.observation(raw)
    assert gaps >= 50
    obs, _ = wrapped.reset(seed=12)
    assert obs["held_age"][0] == 0.0 and not obs["held_fix_valid"].any()


def test_fixes_refuse_other_environments():
    with pytest.raises(ConfigError, match="measurements"):
        DetectionFixes(make_env(ACOUSTIC, "state"))
    with pytest.raises(ConfigError, match="AcousticTracking"):
        wrap_env(make_env("auv_envs/DockingStation-v2", "features").unwrapped,
                 front_ends=("detection_fixes",))


def _batch(observations):
    return {k: torch.as_tensor(np.stack([o[k] for o in observations]), dtype=torch.float32)
            for k in observations[0]}


@pytest.mark.parametrize("front_end", [DetectionFixes, DetectionTrack])
def test_extractor_ignores_order_and_padding_and_pools_inside_the_valid_fixes(front_end):
    """Over the fixes, and over the fixes with their track (each token with its deviation
    from the track, the track's token among the pooled ones)."""
    _, wrapped, pairs = _fixed_observations("hard", 20, front_end=front_end)
    track = front_end is DetectionTrack
    keys = ("fix", "fix_log_std", "fix_log_fit", "fix_valid", *(("fix_deviation",) if track
                                                                 else ()))
    prefixes = ("", "held_", *(("track_",) if track else ()))
    torch.manual_seed(0)
    extractor = DetectionSetExtractor(wrapped.observation_space)
    rng = np.random.default_rng(0)
    observations = [obs for _, obs in pairs]
    shuffled, padded = [], []
    q, k = observations[0]["fix_valid"].shape
    for obs in observations:
        permuted, noisy = dict(obs), {key: v.copy() for key, v in obs.items()}
        for prefix in ("", "held_"):  # each band's detections, in a new order
            order = np.stack([rng.permutation(k) for _ in range(q)])
            invalid = ~obs[f"{prefix}fix_valid"].astype(bool)
            for key in keys:
                v = obs[prefix + key]
                permuted[prefix + key] = np.take_along_axis(
                    v, order.reshape(order.shape + (1,) * (v.ndim - 2)), axis=1)
                if key != "fix_valid":
                    noisy[prefix + key][invalid] = rng.normal(size=v[invalid].shape)
        shuffled.append(permuted)
        padded.append(noisy)
    with torch.no_grad():
        base = extractor(_batch(observations))
        torch.testing.assert_close(extractor(_batch(shuffled)), base, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(extractor(_batch(padded)), base, atol=1e-5, rtol=1e-5)
    pooled = base[:, :3].numpy()
    for obs, p in zip(observations, pooled, strict=True):
        fixes = np.concatenate([obs[f"{prefix}fix"][obs[f"{prefix}fix_valid"].astype(bool)]
                                for prefix in prefixes])
        if len(fixes):  # a convex combination of the valid fixes
            assert np.all(p >= fixes.min(axis=0) - 1e-6) and np.all(p <= fixes.max(axis=0) + 1e-6)
        else:
            np.testing.assert_array_equal(p, 0.0)
    empty = {k: np.zeros_like(v) for k, v in observations[0].items()}
    with torch.no_grad():
        out = extractor(_batch([empty]))
    assert torch.isfinite(out).all() and torch.all(out[0, :3] == 0.0)


def test_extractor_needs_the_fix_keys():
    env = make_env(ACOUSTIC, "measurements")
    with pytest.raises(ConfigError, match="detection_fixes"):
        DetectionSetExtractor(env.observation_space)


def test_config_checks_policy_and_fixes_together():
    resolve_config("ppo", ACOUSTIC, hyperparams_dir=CONFIG_DIR)
    with pytest.raises(ConfigError, match="detection_fixes: true"):
        resolve_config("ppo", ACOUSTIC, overrides={"detection_fixes": False},
                       hyperparams_dir=CONFIG_DIR)
    with pytest.raises(ConfigError, match="PPO policy"):
        resolve_config("sac", ACOUSTIC, overrides={"policy": "DetectionSetPolicy",
                                                   "detection_fixes": True})
    with pytest.raises(ConfigError, match="detection_fixes must be bool"):
        resolve_config("ppo", ACOUSTIC, overrides={"detection_fixes": "yes"},
                       hyperparams_dir=CONFIG_DIR)


def test_trains_exports_and_acts_as_in_training(tmp_path):
    """A tiny run from the shipped YAML: the untrained policy starts from the pooled fix, and
    the exported agent reproduces training's final held-out evaluation."""
    path, manifest = train_and_export(tmp_path, "AcousticTracking-v2", CONFIG_DIR, 256,
                                      "{difficulty: paper, time_limit: 1.0}", "ppo-acoustic-test")
    assert manifest["detection_fixes"] is True and manifest["obs_mode"] == "measurements"
    spec = agents.policy_spec(path)
    env = make_env(ACOUSTIC, "measurements", difficulty="paper", time_limit=1.0)
    agent = spec.factory(env.unwrapped)
    row = run_episode(env, agent, TRAIN_EVAL_SEED_BASE, ACOUSTIC, spec.name)
    final = manifest["final_heldout_eval"]
    assert row.episode_return == pytest.approx(float(final["mean_return"]), abs=1e-9)
    obs, info = env.reset(seed=5)
    action = agent.act(obs, info)
    assert env.action_space.contains(action)
    # The agent forgets the held fixes between episodes: the same seed twice, the same episode.
    again = run_episode(env, agent, TRAIN_EVAL_SEED_BASE, ACOUSTIC, spec.name)
    assert again.episode_return == row.episode_return
    env.close()
