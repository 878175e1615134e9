"""Recording episodes: the RecordVideo subclass, the recorder command, clips of the leaderboard."""

from __future__ import annotations

import math

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np
import pytest
from PIL import Image

from auv_envs import record
from baselines.evaluation import EpisodeTask, VideoSpec, run_task

LARS = "auv_envs/LARSCapture-v0"


def _mp4_frames(path) -> np.ndarray:
    """Every frame of an MP4, decoded by ffmpeg (MoviePy's reader drops the last one)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    width, height = next(reader)["size"]
    return np.stack([np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in reader])


def test_clip_timing():
    assert record.clip_timing(10, 5.0) == (2, 25)  # docking: 10 Hz at 5x -> every 2nd frame
    assert record.clip_timing(25, 1.5) == (2, 19)  # 18.75 fps rounded to a whole number
    assert record.clip_timing(100, 1.0) == (5, 20)
    assert record.clip_timing(10, 0.5) == (1, 5)  # slower than real time: every frame
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="speed"):
            record.clip_timing(10, bad)


def test_auto_speed_plays_a_full_episode_in_20_s():
    for env_id, expected in ((LARS, 1.5), ("auv_envs/DockingStation-v2", 5.0)):
        env = gym.make(env_id)
        assert record.auto_speed(env) == pytest.approx(expected)
        env.close()
    short = gym.make(LARS, time_limit=4.0)
    assert record.auto_speed(short) == 1.0  # never slower than real time
    short.close()


def test_recorder_keeps_every_nth_frame_and_the_last(tmp_path):
    env = gym.make(LARS, render_mode="rgb_array", render_size=(64, 48), time_limit=1.0)
    recorder = record.EpisodeRecorder(env, tmp_path, name_prefix="clip", speed=3.0)
    assert recorder.frame_stride == 4  # 25 Hz at 3x, near 20 fps
    try:
        recorder.reset(seed=3)
        steps, done = 0, False
        while not done:
            *_, terminated, truncated, _ = recorder.step(np.zeros(3))
            steps += 1
            done = terminated or truncated
        last = env.render()
    finally:
        recorder.close()
    assert steps > 4
    mp4, gif = tmp_path / "clip-episode-0.mp4", tmp_path / "clip-episode-0.gif"
    assert recorder.written == [mp4, gif]
    frames = _mp4_frames(mp4)
    # Frames 0, 4, 8, ... of reset + steps, plus the last one when the stride skipped it,
    # then the last held for HOLD_SECONDS and up to MIN_CLIP_SECONDS in all.
    kept = len(range(0, steps + 1, 4)) + (steps % 4 != 0)
    fps = recorder.frames_per_sec
    expected = max(kept + math.ceil(record.HOLD_SECONDS * fps),
                   math.ceil(record.MIN_CLIP_SECONDS * fps))
    assert expected > kept and frames.shape == (expected, 48, 64, 3)
    assert len(frames) / fps >= record.MIN_CLIP_SECONDS
    # The held frames are the episode's end state (H.264 is lossy: compare loosely).
    for frame in frames[kept - 1:]:
        assert np.abs(frame.astype(int) - last.astype(int)).mean() < 6
    gif_frames = imageio.mimread(gif)
    assert gif_frames[0].shape[:2] == (24, 32)  # half size
    # The GIF merges repeated frames into longer delays: it lasts as long as the MP4.
    with Image.open(gif) as image:
        durations = []
        for index in range(image.n_frames):
            image.seek(index)
            durations.append(image.info["duration"])
    assert sum(durations) / 1000 == pytest.approx(expected / fps, abs=0.1)


def test_recorder_rejects_odd_frame_sizes(tmp_path):
    env = gym.make(LARS, render_mode="rgb_array", render_size=(63, 48))
    recorder = record.EpisodeRecorder(env, tmp_path, speed=1.0, gif=False)
    try:
        with pytest.raises(ValueError, match="even"):
            recorder.reset(seed=0)
    finally:
        recorder.discard()
        recorder.close()


def test_recording_does_not_change_the_episode(tmp_path):
    task = EpisodeTask(LARS, "features", "ckf-pd", 100_123)
    video = VideoSpec(str(tmp_path), size=(64, 48), gif=False)
    plain = run_task(task)
    recorded = run_task(task, video=video)
    assert plain.status == recorded.status == "ok"
    assert (recorded.episode_return, recorded.length, recorded.success) == \
        (plain.episode_return, plain.length, plain.success)
    assert recorded.metrics == plain.metrics
    assert video.path(task).exists() and not video.path(task).with_suffix(".gif").exists()


def test_a_failed_episode_leaves_no_clip(tmp_path):
    # pd-state does not act on the LARS env: building the agent fails.
    task = EpisodeTask(LARS, "state", "pd-state", 1)
    video = VideoSpec(str(tmp_path), size=(64, 48))
    row = run_task(task, video=video)
    assert row.status != "ok"
    assert list(tmp_path.iterdir()) == []


def test_agents_come_from_the_installed_provider():
    spec = record.find_agent("ckf-pd")
    assert spec.modes_for(LARS)[0] == "features"
    with pytest.raises(KeyError, match="no-such-agent"):
        record.find_agent("no-such-agent")


def test_record_command(tmp_path, capsys):
    code = record.main(["--env", "LARSCapture-v0", "--agent", "ckf-pd", "--seed", "100007",
                        "--out", str(tmp_path), "--size", "64x48"])
    assert code == 0
    printed = capsys.readouterr().out.split()
    names = sorted(p.split("/")[-1] for p in printed)
    assert names == ["LARSCapture-v0_ckf-pd_seed100007-episode-0.gif",
                     "LARSCapture-v0_ckf-pd_seed100007-episode-0.mp4"]
    assert len(_mp4_frames(tmp_path / names[1])) > 3


@pytest.mark.parametrize("argv, message", [
    (["--env", "Nope-v0"], "unknown environment"),
    (["--env", "LARSCapture-v0", "--agent", "no-such-agent"], "unknown agent"),
    (["--env", "LARSCapture-v0", "--agent", "pd-state"], "does not apply"),
    (["--env", "LARSCapture-v0", "--size", "65x48"], "even"),
    (["--env", "LARSCapture-v0", "--speed", "0"], "speed"),
])
def test_record_command_rejects_bad_input(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit) as exit_info:
        record.main([*argv, "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
