"""Pixel policies distilled from a features policy (baselines.rl.distill)."""

from __future__ import annotations

import json
import shutil

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from baselines.registry import agent_spec, make_agent
from baselines.rl import distill
from baselines.rl.agents import register_external_policy
from baselines.rl.manifest import policies_root

ENV_ID = "auv_envs/DockingStation-v2"


def test_the_teacher_sees_what_a_features_env_reports_at_the_same_state():
    # One camera at two resolutions: the lamps the image env reports, scaled, are the
    # features env's lamp pixels (both noise-free at the release level).
    features = gym.make(ENV_ID, obs_mode="features")
    image = gym.make(ENV_ID, obs_mode="image", image_size=(84, 63))
    scale = distill.camera_scale(features, image)
    np.testing.assert_allclose(scale, [640 / 84, 480 / 63])
    rng = np.random.default_rng(0)
    (big, _), (small, info) = features.reset(seed=11), image.reset(seed=11)
    seen = 0
    for _ in range(40):
        teacher = distill.teacher_observation(small, info, scale)
        np.testing.assert_array_equal(teacher["visible"], big["visible"])
        np.testing.assert_allclose(teacher["pixels"], big["pixels"], atol=1e-3)
        for key in distill.SENSORS:
            np.testing.assert_array_equal(teacher[key], small[key])
        assert features.observation_space.contains(teacher)
        seen += int(big["visible"].sum())
        action = rng.uniform(-0.3, 1.0, 4).astype(np.float32)
        (big, *_), (small, _, _, _, info) = features.step(action), image.step(action)
    assert seen > 40  # lamps were in view, so the comparison had pixels to compare


def test_the_student_image_keeps_the_teacher_cameras_aspect_ratio():
    features = gym.make(ENV_ID, obs_mode="features")
    square = gym.make(ENV_ID, obs_mode="image", image_size=(84, 84))
    with pytest.raises(ValueError, match="aspect ratio"):
        distill.camera_scale(features, square)


def test_a_short_distillation_fits_the_teacher_and_ranks_from_pixels(tmp_path):
    settings = distill.DistillSettings(rounds=2, episodes=1, epochs=3, eval_episodes=1)
    manifest = distill.distill("cppo-docking-features-s0", ENV_ID, (84, 63), "paper", 1,
                               tmp_path / "pixels", settings, group="pixels")
    curve = manifest["curve"]
    assert [row["round"] for row in curve] == [0, 1] and curve[0]["beta"] == 1.0
    assert curve[0]["rollout_success"] == 1.0  # round 0 is the teacher alone: it docks
    for row in curve:  # fitting lowers the error against the teacher's actions
        assert row["loss_after_fit"] < row["loss_before_fit"]
    assert manifest["n_timesteps"] == curve[-1]["frames"] > curve[0]["frames"]
    written = json.loads((tmp_path / "pixels" / "policy.json").read_text())
    assert written["env_kwargs"] == {"image_size": [84, 63], "difficulty": "paper"}
    name = register_external_policy(tmp_path / "pixels")
    spec = agent_spec(name)
    assert spec.obs_mode == "image" and spec.env_kwargs == {"image_size": [84, 63]}
    env = gym.make(ENV_ID, obs_mode="image", image_size=(84, 63), difficulty="paper")
    agent = make_agent(name, env)
    obs, info = env.reset(seed=3)
    assert env.action_space.contains(agent.act(obs, info))


def test_only_a_features_teacher_of_the_same_env_is_taken(tmp_path):
    # A teacher on the privileged state: a shipped policy's directory, its manifest edited.
    state_teacher = tmp_path / "state-teacher"
    shutil.copytree(policies_root() / "ppo-docking-features-s0", state_teacher)
    manifest = json.loads((state_teacher / "policy.json").read_text())
    (state_teacher / "policy.json").write_text(json.dumps({**manifest, "obs_mode": "state"}))
    with pytest.raises(ValueError, match="must act on 'features'"):
        distill.distill(state_teacher, ENV_ID, (84, 63), "paper", 0, tmp_path / "x")
    with pytest.raises(SystemExit):  # no such policy: the command line says so
        distill.main(["--teacher", "no-such-policy", "--out", str(tmp_path / "x")])
    with pytest.raises(ValueError, match="was trained on"):
        distill.distill("cppo-lamp-array-features-s0", ENV_ID, (84, 63), "paper", 0,
                        tmp_path / "x")


def test_the_pixel_view_shows_the_agents_own_observations(tmp_path):
    from scripts import pixel_policy_view

    frames, infos, metrics = pixel_policy_view.episode_frames(
        "distill-docking-image-s0", "paper", 7)
    env = gym.make(ENV_ID, obs_mode="image", image_size=(84, 63), difficulty="paper")
    first, _ = env.reset(seed=7)
    np.testing.assert_array_equal(frames[0], first["image"])  # the reset's own image
    assert len(frames) == len(infos) >= 2 and frames[-1].shape == (63, 84, 3)
    assert "success" in metrics
    out = tmp_path / "view.png"
    pixel_policy_view.main(["--levels", "paper", "--frames", "3", "--seed", "7",
                            "--out", str(out)])
    assert out.stat().st_size > 1000
    with pytest.raises(ValueError, match="not on images"):
        pixel_policy_view.episode_frames("ofnmpc-ekf", "paper", 7)
