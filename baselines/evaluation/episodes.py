"""One episode: its row, its runner, and the task that names it and runs it in a fresh env.

:func:`run_episode` plays one seeded episode of an agent in an environment and
scores it (an :class:`EpisodeRow`). An :class:`EpisodeTask` (environment id,
obs mode, environment arguments, agent name, seed) is everything that
determines a result; :func:`run_task` builds a fresh environment and agent for
it and runs it, so a result never depends on the worker or on the order of
the episodes. An agent that raises (while being built or during an episode)
gives a *failed* row carrying the error (:func:`failed_row`).
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import importlib
import json
import math
import re
import time
import traceback
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import auv_envs
from baselines.evaluation.fingerprint import CACHE_FORMAT, code_fingerprint
from baselines.registry import agent_spec


@dataclasses.dataclass(frozen=True)
class EpisodeRow:
    """One evaluated episode.

    ``status`` is ``"ok"`` or ``"failed"`` (the agent or the environment raised;
    ``error`` says what, the numbers are then NaN/empty). ``scenario`` labels
    the environment arguments of the run (``"default"`` when none).
    """

    env_id: str
    agent: str
    seed: int
    obs_mode: str
    scenario: str
    episode_return: float
    length: int
    success: bool
    failure_reason: str
    metrics: dict
    wall_time_s: float
    status: str = "ok"
    error: str = ""
    env_kwargs: dict = dataclasses.field(default_factory=dict)
    #: The metrics whose value was a float NaN or inf (stored as JSON ``null``): counted
    #: as such by the summary, not mistaken for a metric that does not apply.
    nan_metrics: tuple[str, ...] = ()


def jsonable(value):
    """``value`` as JSON data: NumPy scalars and arrays to Python, NaN/inf to ``None``."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    return value


def is_number(value) -> bool:
    """Whether ``value`` is a Python or NumPy number (booleans included)."""
    return isinstance(value, int | float | np.integer | np.floating | np.bool_)


def _estimate_error(estimate, info: dict) -> float | None:
    """Euclidean error of an agent's ``position_estimate()`` against ``info["true_position"]``."""
    if estimate is None:
        return None
    est = np.asarray(estimate, dtype=float)
    if est.shape != (3,) or not np.all(np.isfinite(est)):
        raise ValueError(f"position_estimate() must return a finite (3,) array or None, "
                         f"got {estimate!r}")
    if "true_position" not in info:
        raise ValueError("the environment's info has no 'true_position' to score "
                         "position_estimate() against")
    return float(np.linalg.norm(est - np.asarray(info["true_position"], dtype=float)))


def run_episode(env: gym.Env, agent, seed: int, env_id: str, agent_name: str,
                scenario: str | None = None) -> EpisodeRow:
    """One seeded episode of ``agent`` in ``env``; exceptions propagate.

    Metrics: the environment's ``info["episode_metrics"]`` at the last step,
    plus

    * ``<key>_steps`` for every boolean ``info["violation_<...>"]`` key: the
      number of steps on which that constraint was violated;
    * ``estimate_error_mean`` / ``estimate_error_max`` when the agent has
      ``position_estimate()``: after each ``act``, its (3,) world-frame
      estimate (or ``None``: no estimate yet) is compared with the
      ``info["true_position"]`` that came with the observation it acted on;
      ``estimate_steps`` counts the steps with an estimate;
    * ``agent_<key>`` for every numeric value of the agent's ``stats()`` at
      the end of the episode.
    """
    start = time.perf_counter()
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    estimate = getattr(agent, "position_estimate", None)
    errors: list[float] = []
    violations: collections.Counter = collections.Counter()
    total, length, done = 0.0, 0, False
    while not done:
        action = agent.act(obs, info)
        if callable(estimate):
            error = _estimate_error(estimate(), info)
            if error is not None:
                errors.append(error)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        length += 1
        for key, value in info.items():
            if key.startswith("violation_"):
                violations[key] += int(bool(np.any(value)))
        done = terminated or truncated
    raw = dict(info.get("episode_metrics", {}))
    metrics = jsonable(raw)
    metrics.update({f"{key}_steps": count for key, count in violations.items()})
    if callable(estimate):
        metrics["estimate_steps"] = len(errors)
        if errors:
            metrics["estimate_error_mean"] = float(np.mean(errors))
            metrics["estimate_error_max"] = float(np.max(errors))
    if callable(getattr(agent, "stats", None)):
        for key, value in agent.stats().items():
            if is_number(value):
                raw[f"agent_{key}"] = value
                metrics[f"agent_{key}"] = jsonable(float(value))
    nan_metrics = tuple(sorted(key for key, value in raw.items()
                               if is_number(value) and not math.isfinite(float(value))))
    unwrapped = env.unwrapped
    return EpisodeRow(
        env_id=env_id,
        agent=agent_name,
        seed=int(seed),
        obs_mode=getattr(unwrapped, "obs_mode", ""),
        scenario=scenario if scenario is not None else getattr(unwrapped, "scenario", ""),
        episode_return=total,
        length=length,
        success=bool(info.get("is_success", False)),
        failure_reason=str(metrics.get("failure_reason", "")),
        metrics=metrics,
        wall_time_s=time.perf_counter() - start,
        nan_metrics=nan_metrics,
    )


@dataclasses.dataclass(frozen=True)
class EpisodeTask:
    """One episode to run: everything that determines its result.

    ``env_kwargs`` are sorted ``(name, value)`` pairs (hashable); they are the
    run's environment arguments, not the ones the agent's spec adds.
    """

    env_id: str
    obs_mode: str
    agent: str
    seed: int
    env_kwargs: tuple[tuple[str, Any], ...] = ()

    @property
    def kwargs(self) -> dict:
        return dict(self.env_kwargs)

    @property
    def scenario(self) -> str:
        return scenario_label(self.kwargs)

    def identity(self) -> dict:
        """What the cache key is made of (the package version and code included)."""
        return {
            "format": CACHE_FORMAT,
            "version": auv_envs.__version__,
            "code": code_fingerprint(),
            "env_id": self.env_id,
            "obs_mode": self.obs_mode,
            "agent": self.agent,
            "seed": self.seed,
            "env_kwargs": jsonable(self.kwargs),
        }

    def key(self) -> str:
        text = json.dumps(self.identity(), sort_keys=True, default=repr)
        return hashlib.sha256(text.encode()).hexdigest()[:24]


def scenario_label(env_kwargs: Mapping[str, Any]) -> str:
    """``"k=v, k=v"`` of a run's environment arguments (``"default"`` when none)."""
    return ", ".join(f"{k}={v}" for k, v in sorted(env_kwargs.items())) or "default"


def short_env_id(env_id: str) -> str:
    """The part of an environment id after ``auv_envs/``."""
    return env_id.split("/", 1)[-1]


@dataclasses.dataclass(frozen=True)
class VideoSpec:
    """Record an episode while it is evaluated (:class:`auv_envs.record.EpisodeRecorder`).

    Rendering does not change an episode: its row is the same with or without
    a recording (tested).

    Attributes:
        directory: where the clips go.
        size: frame size (W, H), both even.
        speed: playback speed relative to real time; None: a full-length
            episode plays in 20 s (:func:`auv_envs.record.auto_speed`).
        gif: also write a GIF.
    """

    directory: str
    size: tuple[int, int] = (320, 240)
    speed: float | None = None
    gif: bool = True

    def stem(self, task: EpisodeTask) -> str:
        """The clip's file name prefix: environment, agent, obs mode, scenario, seed."""
        scenario = re.sub(r"[^A-Za-z0-9_.=-]+", "-", task.scenario).strip("-")
        return (f"{short_env_id(task.env_id)}_{task.agent}_{task.obs_mode}_{scenario}"
                f"_seed{task.seed}")

    def path(self, task: EpisodeTask) -> Path:
        """Where the MP4 of ``task``'s episode is (RecordVideo numbers episodes from 0)."""
        return Path(self.directory) / f"{self.stem(task)}-episode-0.mp4"


def failed_row(task: EpisodeTask, exc: BaseException, wall_time_s: float = 0.0) -> EpisodeRow:
    """The row of an episode that raised: status ``failed`` and the error with its location."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(frames[-1].filename).name}:{frames[-1].lineno} in " \
            f"{frames[-1].name})" if frames else ""
    return EpisodeRow(
        env_id=task.env_id, agent=task.agent, seed=task.seed, obs_mode=task.obs_mode,
        scenario=task.scenario, episode_return=math.nan, length=0, success=False,
        failure_reason="error", metrics={}, wall_time_s=wall_time_s, status="failed",
        error=f"{type(exc).__name__}: {exc}{where}", env_kwargs=jsonable(task.kwargs),
    )


#: Prefix of an ``agent_modules`` entry that registers a trained policy
#: (``policy:PATH``, :func:`baselines.rl.agents.register_external_policy`).
POLICY_PREFIX = "policy:"


def import_agent_modules(modules: Sequence[str]) -> None:
    """Import modules whose import registers agents (also done in every worker).

    An entry ``policy:PATH`` registers the trained policy at PATH instead.
    """
    for module in modules:
        if module.startswith(POLICY_PREFIX):
            from baselines.rl.agents import register_external_policy

            register_external_policy(module.removeprefix(POLICY_PREFIX))
        else:
            importlib.import_module(module)


def run_task(task: EpisodeTask, agent_modules: Sequence[str] = (),
             video: VideoSpec | None = None) -> EpisodeRow:
    """Build a fresh env and agent for ``task`` and run it; any exception -> a failed row.

    With ``video``, the episode is recorded as it runs (MP4 and GIF at
    ``video.path(task)``); a failed episode leaves no clip.
    """
    start = time.perf_counter()
    env = None
    recorder = None
    try:
        import_agent_modules(agent_modules)
        spec = agent_spec(task.agent)
        kwargs = {**spec.env_kwargs, **task.kwargs}  # plan() skips conflicting values
        if video is not None:
            kwargs.update(render_mode="rgb_array", render_size=tuple(video.size))
        env = gym.make(task.env_id, obs_mode=task.obs_mode, **kwargs)
        if video is not None:
            from auv_envs.record import EpisodeRecorder

            env = recorder = EpisodeRecorder(env, video.directory, video.stem(task),
                                             speed=video.speed, gif=video.gif)
        agent = spec.factory(env.unwrapped)
        row = run_episode(env, agent, task.seed, task.env_id, task.agent, task.scenario)
        return dataclasses.replace(row, env_kwargs=jsonable(task.kwargs))
    except Exception as exc:  # an agent's failure is a result, not a crash of the run
        if recorder is not None:
            recorder.discard()  # no clip of a failed episode
        return failed_row(task, exc, time.perf_counter() - start)
    finally:
        if env is not None:
            env.close()
