"""Record episodes as MP4 and GIF clips, and a command that records one episode of an agent.

    python -m auv_envs.record --env DockingStation-v2 --agent ofnmpc-ekf --seed 100000
    auv-record --env LARSCapture-v0 --agent ckf-pd --seed 7 --out videos --size 640x480

:class:`EpisodeRecorder` is Gymnasium's ``RecordVideo`` (which writes the MP4
through MoviePy) with three additions a benchmark needs: it keeps every
``frame_stride``-th frame and always the episode's last one, held for
:data:`HOLD_SECONDS` and to at least :data:`MIN_CLIP_SECONDS` (so a clip plays
faster than real time and still shows how the episode ended), it plays at
``speed`` times real time, and it writes a GIF next to each MP4. The packages
are in the ``video`` extra (``pip install "auv_envs[video]"``).

Agents come from *agent providers*: installed packages that declare, in the
``auv_envs.agents`` entry-point group, a callable ``name -> spec`` where the
spec has ``factory(env) -> agent`` (an object with ``reset(seed)`` and
``act(observation, info) -> action``), ``modes_for(env_id)`` (the observation
modes it can act on, preferred first; empty where it does not apply) and
``env_kwargs`` (constructor arguments its env needs), raising ``KeyError`` for
a name it does not know. This package's ``baselines`` is one
(``baselines.registry:agent_spec``); ``auv_envs`` itself never imports it.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RecordVideo

#: The entry-point group of agent providers.
AGENT_PROVIDERS = "auv_envs.agents"
#: Frames per second a clip aims at: the frame stride is chosen for it.
TARGET_FPS = 20.0
#: With ``speed=None``, a clip plays a full-length episode in this many seconds
#: (never slower than real time).
CLIP_SECONDS = 20.0
#: Every clip holds its episode's last frame this long, s (how it ended stays in view)...
HOLD_SECONDS = 1.0
#: ... and lasts at least this long, s: a LARS capture of 6-12 frames would otherwise
#: flash by in half a second (the player shows "0:00").
MIN_CLIP_SECONDS = 3.0


def auto_speed(env: gym.Env) -> float:
    """Playback speed at which ``env``'s full-length episode lasts :data:`CLIP_SECONDS`."""
    unwrapped = env.unwrapped
    return max(1.0, unwrapped.max_episode_steps * unwrapped.dt / CLIP_SECONDS)


def check_speed(speed: float) -> float:
    """``speed`` when it is a positive finite number, else ``ValueError``."""
    if not (isinstance(speed, int | float) and math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be a positive number, got {speed!r}")
    return float(speed)


def parse_image_size(text: str) -> tuple[int, int]:
    """``"WIDTHxHEIGHT"`` -> ``(width, height)``, both positive (an argparse type)."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from exc
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"sizes must be positive, got {text!r}")
    return width, height


def parse_size(text: str) -> tuple[int, int]:
    """``"WIDTHxHEIGHT"`` -> ``(width, height)``; both even and at least 16 (H.264)."""
    width, height = parse_image_size(text)
    if width < 16 or height < 16 or width % 2 or height % 2:
        raise argparse.ArgumentTypeError(f"sizes must be even and at least 16, got {text!r}")
    return width, height


def clip_timing(render_fps: float, speed: float, target_fps: float = TARGET_FPS
                ) -> tuple[int, int]:
    """``(frame_stride, fps)`` that play an env rendered at ``render_fps`` at about
    ``speed`` x real time, near ``target_fps`` frames per second.

    The frame rate is a whole number (GIF delays are whole hundredths of a
    second and players show whole rates), so the speed is met to within a few
    per cent.
    """
    speed = check_speed(speed)
    stride = max(1, round(render_fps * speed / target_fps))
    return stride, max(1, round(render_fps * speed / stride))


class EpisodeRecorder(RecordVideo):
    """``RecordVideo`` that records every episode, every ``frame_stride``-th frame plus
    the last, at ``speed`` times real time, and writes a GIF beside each MP4.

    Files: ``<video_folder>/<name_prefix>-episode-<k>.mp4`` (and ``.gif``), written
    when the next episode starts or the wrapper closes. The env must render
    ``rgb_array`` frames of even width and height (H.264 needs them).

    Args:
        env: the environment, built with ``render_mode="rgb_array"``.
        video_folder: where the clips go (created if missing).
        name_prefix: start of each file name.
        speed: playback speed relative to real time (the env's ``render_fps``);
            None: :func:`auto_speed` (a full-length episode plays in 20 s).
        gif: also write a GIF of the same frames, at ``gif_scale`` times the size.
    """

    def __init__(self, env: gym.Env, video_folder: str | Path, name_prefix: str = "episode",
                 speed: float | None = None, gif: bool = True, gif_scale: float = 0.5):
        if not 0 < gif_scale <= 1:
            raise ValueError(f"gif_scale must be in (0, 1], got {gif_scale}")
        speed = auto_speed(env) if speed is None else speed
        self.frame_stride, fps = clip_timing(env.metadata.get("render_fps", 30), speed)
        with warnings.catch_warnings():
            # Files are named per episode; an existing folder is not overwritten.
            warnings.filterwarnings("ignore", message=".*Overwriting existing videos")
            super().__init__(env, str(video_folder), episode_trigger=lambda _: True,
                             name_prefix=name_prefix, fps=fps)
        self.gif = gif
        self.gif_scale = gif_scale
        self._frames_seen = 0
        self._last_skipped = False
        #: Paths of the files written so far.
        self.written: list[Path] = []

    def reset(self, *, seed=None, options=None):
        self._frames_seen = 0
        self._last_skipped = False
        return super().reset(seed=seed, options=options)

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        if (terminated or truncated) and self.recording and self._last_skipped:
            self._frames_seen = 0  # the episode's last frame is always kept
            self._capture_frame()
        return obs, reward, terminated, truncated, info

    def _capture_frame(self):
        keep = self._frames_seen % self.frame_stride == 0
        self._frames_seen += 1
        self._last_skipped = not keep
        if keep:
            frame = self.env.render()
            if isinstance(frame, np.ndarray) and (frame.shape[0] % 2 or frame.shape[1] % 2):
                raise ValueError(f"frames must have even width and height for H.264, "
                                 f"got {frame.shape[1]}x{frame.shape[0]}")
            self.recorded_frames.append(frame)

    def discard(self) -> None:
        """Stop the current recording without writing it (e.g. the episode failed)."""
        self.recorded_frames = []
        self.recording = False

    def stop_recording(self):
        if self.recorded_frames:  # hold the last frame (HOLD_SECONDS, MIN_CLIP_SECONDS)
            fps = self.frames_per_sec
            total = max(len(self.recorded_frames) + math.ceil(HOLD_SECONDS * fps),
                        math.ceil(MIN_CLIP_SECONDS * fps))
            self.recorded_frames += [self.recorded_frames[-1]] * (total
                                                                  - len(self.recorded_frames))
        frames, name = list(self.recorded_frames), self._video_name
        super().stop_recording()
        if not frames:
            return
        folder = Path(self.video_folder)
        self.written.append(folder / f"{name}.mp4")
        if self.gif:
            from moviepy import ImageSequenceClip

            path = folder / f"{name}.gif"
            clip = ImageSequenceClip(frames, fps=self.frames_per_sec)
            if self.gif_scale != 1:
                clip = clip.resized(self.gif_scale)
            clip.write_gif(str(path), logger=None)
            clip.close()
            self.written.append(path)


# ------------------------------------------------------------------ agents
def agent_providers() -> list[Callable]:
    """The installed agent providers (``auv_envs.agents`` entry points), loaded."""
    return [point.load() for point in entry_points(group=AGENT_PROVIDERS)]


def find_agent(name: str):
    """The spec of agent ``name`` from the first provider that knows it.

    Raises:
        KeyError: no provider knows ``name``.
    """
    for provider in agent_providers():
        try:
            return provider(name)
        except KeyError:
            continue
    raise KeyError(f"unknown agent {name!r}: no installed agent provider "
                   f"({AGENT_PROVIDERS} entry points) knows it")


# --------------------------------------------------------------- recording
def record_episode(env_id: str, agent: str, seed: int, out_dir: str | Path,
                   obs_mode: str | None = None, env_kwargs: dict | None = None,
                   size: tuple[int, int] = (640, 480), speed: float | None = None,
                   gif: bool = True) -> tuple[list[Path], dict]:
    """Run one seeded episode of ``agent`` and record it; ``(files, last info)``.

    Raises:
        KeyError: unknown agent; ValueError: the agent does not apply to ``env_id``.
    """
    spec = find_agent(agent)
    modes = tuple(spec.modes_for(env_id))
    if not modes:
        raise ValueError(f"agent {agent!r} does not apply to {env_id}")
    mode = obs_mode or modes[0]
    if mode not in modes:
        raise ValueError(f"agent {agent!r} acts on {', '.join(modes)}, not {mode!r}")
    kwargs = {**spec.env_kwargs, **(env_kwargs or {})}
    env = gym.make(env_id, obs_mode=mode, render_mode="rgb_array", render_size=tuple(size),
                   **kwargs)
    prefix = f"{env_id.split('/')[-1]}_{agent}_seed{seed}"
    recorder = EpisodeRecorder(env, out_dir, name_prefix=prefix, speed=speed, gif=gif)
    try:
        policy = spec.factory(env.unwrapped)
        obs, info = recorder.reset(seed=seed)
        policy.reset(seed)
        done = False
        while not done:
            obs, _, terminated, truncated, info = recorder.step(policy.act(obs, info))
            done = terminated or truncated
    finally:
        recorder.close()
    return recorder.written, info


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="auv-record", description="Record one seeded episode of an agent as MP4 and GIF.")
    parser.add_argument("--env", required=True,
                        help="environment id, or its name without 'auv_envs/'")
    parser.add_argument("--agent", default="random",
                        help="agent name (default random; `auv-evaluate --list` lists them)")
    parser.add_argument("--seed", type=int, default=0, help="episode seed (default 0)")
    parser.add_argument("--obs-mode", default=None, help="default: the agent's own mode")
    parser.add_argument("--out", default="videos", help="output directory (default videos)")
    parser.add_argument("--size", type=parse_size, default=(640, 480),
                        help="frame size WIDTHxHEIGHT, both even (default 640x480)")
    parser.add_argument("--speed", type=float, default=None,
                        help="playback speed relative to real time (default: a full-length "
                             f"episode plays in {CLIP_SECONDS:.0f} s)")
    parser.add_argument("--no-gif", action="store_true", help="write the MP4 only")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    import auv_envs

    parser = build_parser()
    args = parser.parse_args(argv)
    env_id = args.env if "/" in args.env else f"auv_envs/{args.env}"
    if env_id not in gym.registry:
        parser.error(f"unknown environment {args.env!r}; registered: "
                     f"{', '.join(auv_envs.ENVIRONMENTS)}")
    try:
        files, info = record_episode(env_id, args.agent, args.seed, args.out, args.obs_mode,
                                     size=args.size, speed=args.speed, gif=not args.no_gif)
    except (KeyError, ValueError) as exc:
        parser.error(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
    summary = info.get("episode_metrics", {})
    print(f"{env_id} {args.agent} seed {args.seed}: success={summary.get('success')}, "
          f"{summary.get('steps')} steps", file=sys.stderr)
    for path in files:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
