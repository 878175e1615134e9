"""AcousticTrackingTask's rgb_array render: size, content, motion, and no effect on the episode."""

from __future__ import annotations

import pickle

import cv2
import gymnasium as gym
import numpy as np
import pytest

from auv_envs.core.env import TaskEnv
from auv_envs.tasks.acoustic.env import AcousticTrackingTask
from auv_envs.tasks.acoustic.render import TankPlot

ENV_ID = "auv_envs/AcousticTracking-v2"
#: Where test_sample_frame_is_not_blank leaves a frame for a person to look at.
SAMPLE_FRAME = "/tmp/acoustic_render.png"


def tracker_action(info, rng):
    """A tracker 0.3 m off the truth: keeps the estimate, its error line and close-up in view."""
    return info["true_position"] + rng.normal(0.0, 0.3, 3)


def run(env, steps, seed=0, render_every=0):
    """Step a seeded episode; returns observations, rewards and infos (reset's first)."""
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    record = [(obs, 0.0, info)]
    for k in range(steps):
        if render_every and k % render_every == 0:
            frame = env.render()
            assert frame.dtype == np.uint8
        obs, reward, terminated, truncated, info = env.step(tracker_action(info, rng))
        record.append((obs, reward, info))
    return record


def not_blank(frame):
    grey = frame.astype(np.float64).mean(axis=-1)
    assert grey.std() > 20.0, grey.std()
    assert 120.0 < grey.mean() < 250.0, grey.mean()


@pytest.mark.parametrize("size", [(640, 480), (320, 240), (1000, 300), (8, 8)])
def test_frame_has_the_size_asked_for(size):
    env = TaskEnv(AcousticTrackingTask, render_mode="rgb_array", render_size=size, time_limit=2.0)
    run(env, 20)
    frame = env.render()
    assert frame.shape == (size[1], size[0], 3)
    assert frame.dtype == np.uint8
    if min(size) >= 100:
        not_blank(frame)
    env.close()


def test_sample_frame_is_not_blank():
    env = TaskEnv(AcousticTrackingTask, render_mode="rgb_array")
    run(env, 600, seed=3)
    frame = env.render()
    assert frame.shape == (480, 640, 3)
    not_blank(frame)
    # Rays, truth and estimate are coloured: the frame is not just grey lines.
    saturation = frame.max(axis=-1).astype(int) - frame.min(axis=-1)
    assert np.count_nonzero(saturation > 80) > 1000
    cv2.imwrite(SAMPLE_FRAME, cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    env.close()


def test_pixels_change_where_the_source_moves():
    env = TaskEnv(AcousticTrackingTask, render_mode="rgb_array", time_limit=30.0)
    rng = np.random.default_rng(1)
    obs, info = env.reset(seed=1)
    before = env.render()
    start = info["true_position"]
    for _ in range(2000):  # 20 s: the carrier moves metres to tens of metres
        obs, reward, terminated, truncated, info = env.step(tracker_action(info, rng))
    after = env.render()
    end = info["true_position"]
    assert np.linalg.norm(end[:2] - start[:2]) > 5.0  # a move the top view resolves

    plot = env.plot
    changed = np.any(before != after, axis=-1)
    left, top, right, bottom = plot.panel_box("top")
    inside = changed[top:bottom, left:right]
    assert inside.sum() > 500
    # Around the end effector now (the marker, where the rays meet), almost every pixel changed.
    col, row = np.round(plot.to_pixel("top", end[:2])).astype(int)
    assert changed[row - 3 : row + 4, col - 3 : col + 4].mean() > 0.5
    col, row = np.round(plot.to_pixel("side", end[::2])).astype(int)
    assert changed[row - 2 : row + 3, col - 2 : col + 3].mean() > 0.5
    # The legend (right column, below the close-up) is static.
    c_left, _, c_right, c_bottom = plot.panel_box("closeup")
    legend = changed[c_bottom + 25 : c_bottom + 95, c_left - 40 : c_right]
    assert not legend.any()
    env.close()


def test_render_changes_no_observation_reward_info_or_random_draw():
    plain = TaskEnv(AcousticTrackingTask, time_limit=3.0)
    drawn = TaskEnv(AcousticTrackingTask, render_mode="rgb_array", time_limit=3.0)
    a = run(plain, 300, seed=11)
    b = run(drawn, 300, seed=11, render_every=3)
    assert drawn.render().shape == (480, 640, 3)  # the last step, after truncation
    for (obs_a, reward_a, info_a), (obs_b, reward_b, info_b) in zip(a, b, strict=True):
        for key in obs_a:
            np.testing.assert_array_equal(obs_a[key], obs_b[key])
        assert reward_a == reward_b
        np.testing.assert_equal(info_a, info_b)
    assert "episode_metrics" in b[-1][2]
    assert plain.np_random.bit_generator.state == drawn.np_random.bit_generator.state
    plain.close()
    drawn.close()


def test_state_observations_are_unchanged_too():
    plain = TaskEnv(AcousticTrackingTask, obs_mode="state", time_limit=1.0)
    drawn = TaskEnv(AcousticTrackingTask, obs_mode="state", render_mode="rgb_array", time_limit=1.0)
    a = run(plain, 100, seed=5)
    b = run(drawn, 100, seed=5, render_every=7)
    for (obs_a, reward_a, _), (obs_b, reward_b, _) in zip(a, b, strict=True):
        np.testing.assert_array_equal(obs_a, obs_b)
        assert reward_a == reward_b


@pytest.mark.parametrize(
    "size", [(0, 480), (640, 7), (640,), (640, 480, 3), "abc", None, 640, ("w", "h")]
)
def test_bad_render_size_raises_value_error(size):
    with pytest.raises(ValueError, match="render_size"):
        TaskEnv(AcousticTrackingTask, render_mode="rgb_array", render_size=size)


def test_no_render_mode_renders_none():
    env = TaskEnv(AcousticTrackingTask, time_limit=1.0)
    env.reset(seed=0)
    assert env.render() is None
    assert env.plot is None
    env.close()


def test_render_before_reset_draws_the_empty_tank():
    env = TaskEnv(AcousticTrackingTask, render_mode="rgb_array")
    frame = env.render()
    assert frame.shape == (480, 640, 3)
    not_blank(frame)
    env.reset(seed=0)
    assert not np.array_equal(env.render(), frame)  # the episode's first detections
    env.close()


def test_through_gym_make():
    env = gym.make(ENV_ID, render_mode="rgb_array", render_size=(320, 240))
    with pytest.raises(gym.error.ResetNeeded):  # Gymnasium's order enforcing, as documented
        env.render()
    env.reset(seed=0)
    env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (240, 320, 3)
    not_blank(frame)
    env.close()
    assert env.unwrapped.plot is None


def test_close_then_close_and_render_again():
    env = TaskEnv(AcousticTrackingTask,
                  render_mode="rgb_array", render_size=(320, 240), time_limit=1.0)
    run(env, 10)
    first = env.render()
    env.close()
    assert env.plot is None
    env.close()  # twice: no error
    np.testing.assert_array_equal(env.render(), first)  # a fresh plot, the same picture
    env.close()


def test_pickled_env_renders_the_same_frame():
    env = TaskEnv(AcousticTrackingTask,
                  render_mode="rgb_array", render_size=(320, 240), time_limit=2.0)
    run(env, 120, seed=4)
    frame = env.render()
    copy = pickle.loads(pickle.dumps(env))
    assert copy.render().shape == (240, 320, 3)
    np.testing.assert_array_equal(copy.render(), frame)
    action = np.array([150.0, 150.0, -15.0])
    for _ in range(60):  # and steps on identically
        out_a, out_b = env.step(action), copy.step(action)
        for key in out_a[0]:
            np.testing.assert_array_equal(out_a[0][key], out_b[0][key])
    np.testing.assert_array_equal(copy.render(), env.render())
    env.close()
    copy.close()


def test_tank_plot_alone():
    """TankPlot needs only the calibration; a frame with no detections still draws."""
    env = TaskEnv(AcousticTrackingTask)
    plot = TankPlot(env.calibration, (400, 300))
    frame = plot.frame(time=1.0, trail=[[100.0, 100.0, -10.0], [101.0, 100.0, -10.0]],
                       estimate=[101.5, 100.0, -10.0], azimuth=np.zeros((0, 8)),
                       elevation=np.zeros((0, 8)), origin=np.zeros(0, dtype=int),
                       error=0.5, rmse=0.5)
    assert frame.shape == (300, 400, 3)
    not_blank(frame)
    plot.close()
