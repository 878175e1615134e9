"""Stable-Baselines3 training on the ``auv_envs`` environments (the logic behind ``train.py``).

A run directory records everything needed to understand and continue a run::

    <run>/config.yml          the resolved config (baselines.rl.config.TrainConfig)
    <run>/run.json            command(s), seed, package versions, segments, wall time
    <run>/eval_curve.csv      held-out evaluation (seeds 90000+) every eval_freq steps
    <run>/train_episodes.csv  every finished training episode (step, return, length, success)
    <run>/logs/               TensorBoard events and SB3's progress.csv, one folder per segment
    <run>/checkpoints/        step-<n>/ checkpoints and the ``latest`` pointer
    <run>/final/              model.zip, vecnormalize.pkl, policy.json (loadable as an agent)

Training seeds: vector env ``i`` is first reset with ``seed + i`` and SB3 is
seeded with ``seed`` (PyTorch, NumPy, Python, action space). Evaluation during
training runs the deterministic policy through :class:`PolicyAgent` (the same
code the shipped agents use) on seeds ``90000 ...``: held out from training
and below the leaderboard's ``EVAL_SEED_BASE`` = 100000.

SIGINT / SIGTERM ask for a checkpoint at the next safe point, after which the
run stops (a second signal aborts at once); ``resume`` continues from the
latest checkpoint exactly as the uninterrupted run would have
(:mod:`baselines.rl.checkpoint`). A fresh run checkpoints its initial model
too, so every run has a checkpoint to resume from.

Divergence: before every rollout (the safe point) the parameters, the
observation-normalisation statistics and the losses of the last update are
checked, and after every on-policy rollout its rewards, returns and advantages.
Anything non-finite stops the run with :class:`TrainingDiverged` before it is
evaluated or checkpointed, so the latest checkpoint is always a finite model;
``resume`` continues from it, with a smaller learning rate if asked
(:data:`baselines.rl.config.RESUMABLE`).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import platform
import signal
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np
import stable_baselines3
import torch
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.utils import LinearSchedule

import auv_envs
from auv_envs.core.assets import sha256_file
from baselines.evaluation import run_episode
from baselines.fileio import atomic_write
from baselines.registry import LazyFactory
from baselines.rl import checkpoint as ckpt
from baselines.rl.config import (
    ALGORITHMS,
    COMPILED,
    CUSTOM_POLICIES,
    FRONT_ENDS,
    RESUMABLE,
    TRAIN_EVAL_SEED_BASE,
    ConfigError,
    TrainConfig,
    read_config,
    resumed,
    save_config,
    schedule_initial_value,
    validate,
)
from baselines.rl.envs import front_ends_of, make_vec_env
from baselines.rl.manifest import MANIFEST_FILE, MODEL_FILE, NORMALIZER_FILE
from baselines.rl.policy import PolicyAgent

#: ``policy_kwargs.activation_fn`` names (a YAML file cannot name a class safely).
ACTIVATIONS = {
    "tanh": torch.nn.Tanh, "relu": torch.nn.ReLU, "elu": torch.nn.ELU,
    "leaky_relu": torch.nn.LeakyReLU, "gelu": torch.nn.GELU,
}
ACTION_NOISE = {"normal": NormalActionNoise, "ornstein-uhlenbeck": OrnsteinUhlenbeckActionNoise}

EVAL_FIELDS = ("step", "mean_return", "std_return", "success_rate", "mean_length", "episodes")
EPISODE_FIELDS = ("step", "return", "length", "success")


@dataclasses.dataclass(frozen=True)
class RunDirectory:
    """Paths inside a run directory (see the module docstring)."""

    path: Path

    def __post_init__(self):
        object.__setattr__(self, "path", Path(self.path))

    config = property(lambda self: self.path / "config.yml")
    info = property(lambda self: self.path / "run.json")
    eval_curve = property(lambda self: self.path / "eval_curve.csv")
    train_episodes = property(lambda self: self.path / "train_episodes.csv")
    logs = property(lambda self: self.path / "logs")
    checkpoints = property(lambda self: self.path / "checkpoints")
    final = property(lambda self: self.path / "final")


@dataclasses.dataclass(frozen=True)
class TrainResult:
    """What one call of :func:`train` or :func:`resume` did.

    Attributes:
        run_dir: the run directory.
        steps: environment steps trained so far (all segments).
        finished: True when ``n_timesteps`` was reached.
        stopped_by: the signal name that stopped the run, else None.
        checkpoint: the latest checkpoint directory.
        wall_time_s: training wall time up to ``steps`` (all segments).
    """

    run_dir: Path
    steps: int
    finished: bool
    stopped_by: str | None
    checkpoint: Path | None
    wall_time_s: float


class TrainingDiverged(RuntimeError):
    """Training produced non-finite values; the run stopped before using or saving them.

    Attributes:
        step: environment steps trained when it was found.
        what: what became non-finite (parameter names, losses, statistics).
        checkpoint: the last good checkpoint, kept (None: the run wrote none).
        run_dir: the run directory.
    """

    def __init__(self, step: int, what: Sequence[str], checkpoint: Path | None,
                 run_dir: Path | None = None, resumable: bool = True):
        self.step, self.what, self.checkpoint, self.run_dir = step, list(what), checkpoint, run_dir
        shown = ", ".join(self.what[:6]) + (f" and {len(self.what) - 6} more"
                                            if len(self.what) > 6 else "")
        if checkpoint is None:
            kept = "no checkpoint was written before it"
        elif resumable:
            kept = f"the last good checkpoint, {checkpoint}, is kept; resume from it"
        else:
            kept = f"the policies written before it are kept ({checkpoint})"
        super().__init__(f"training diverged at step {step}, not finite: {shown}; {kept}")


# --------------------------------------------------------------- model set-up
def choose_policy(observation_space: spaces.Space, requested: str = "auto") -> str:
    """``auto``: ``MultiInputPolicy`` for ``Dict``, ``CnnPolicy`` for images, else ``MlpPolicy``."""
    if requested != "auto":
        return requested
    if isinstance(observation_space, spaces.Dict):
        return "MultiInputPolicy"
    if is_image_space(observation_space, check_channels=False):
        return "CnnPolicy"
    return "MlpPolicy"


def _schedule(key: str, value):
    if isinstance(value, str):
        return LinearSchedule(schedule_initial_value(key, value), 0.0, 1.0)
    return value


def algorithm_kwargs(config: TrainConfig, action_space: spaces.Space) -> dict:
    """The config's hyperparameters as SB3 constructor arguments (schedules, classes, noise)."""
    kwargs = {k: _schedule(k, v) for k, v in config.hyperparams.items()}
    policy_kwargs = dict(kwargs.get("policy_kwargs") or {})
    if "activation_fn" in policy_kwargs:
        name = policy_kwargs["activation_fn"]
        if name not in ACTIVATIONS:
            raise ConfigError(
                f"unknown activation_fn {name!r}; valid: {', '.join(ACTIVATIONS)}"
            )
        policy_kwargs["activation_fn"] = ACTIVATIONS[name]
    if policy_kwargs:
        kwargs["policy_kwargs"] = policy_kwargs
    if isinstance(kwargs.get("train_freq"), list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    noise = kwargs.get("action_noise")
    if noise is not None:  # its form and sigma are checked by validate()
        n = int(np.prod(action_space.shape))
        kwargs["action_noise"] = ACTION_NOISE[noise["type"]](
            mean=np.zeros(n), sigma=float(noise["sigma"]) * np.ones(n)
        )
    return kwargs


def custom_objects(config: TrainConfig) -> dict:
    """Settings taken from the config, not the checkpoint, when a checkpoint is loaded:
    schedules (rebuilt, not unpickled) and what a resume may change (:data:`RESUMABLE`)."""
    out = {}
    for key in (*RESUMABLE, "clip_range_vf"):
        if key in config.hyperparams:
            out[key] = _schedule(key, config.hyperparams[key])
    return out


def build_model(config: TrainConfig):
    """A new SB3 model on a new, seeded training vector env.

    What Stable-Baselines3 still refuses once :func:`validate` passed (a relation with
    the environment's spaces, e.g. n-step returns on ``Dict`` observations) is a
    :class:`ConfigError`, not an assertion.
    """
    vec_env = make_vec_env(config)
    try:
        policy = choose_policy(vec_env.observation_space, config.run["policy"])
        if policy in CUSTOM_POLICIES:
            policy = LazyFactory(CUSTOM_POLICIES[policy]).resolve()
        return ALGORITHMS[config.algo](
            policy, vec_env, seed=config.seed, device="cpu", verbose=0,
            **algorithm_kwargs(config, vec_env.action_space),
        )
    except ConfigError:
        vec_env.close()
        raise
    except (AssertionError, ValueError) as exc:
        vec_env.close()
        raise ConfigError(f"Stable-Baselines3 {config.algo.upper()} refuses these settings on "
                          f"{config.env_id}: {exc}") from exc
    except BaseException:
        vec_env.close()
        raise


# ---------------------------------------------------------------- bookkeeping
def eval_seeds(config: TrainConfig) -> list[int]:
    return list(range(TRAIN_EVAL_SEED_BASE, TRAIN_EVAL_SEED_BASE + config.run["n_eval_episodes"]))


def _append_row(path: Path, fields: Sequence[str], row: dict) -> None:
    new = not path.is_file()
    with open(path, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        if new:
            writer.writeheader()
        writer.writerow(row)


def _truncate_rows(path: Path, last_step: int) -> None:
    """Drop rows written after ``last_step`` (they are redone when training resumes)."""
    if not path.is_file():
        return
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
        fields = rows[0].keys() if rows else None
    kept = [r for r in rows if int(r["step"]) <= last_step]
    if fields is None:
        return
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(fields))
    writer.writeheader()
    writer.writerows(kept)
    atomic_write(path, buffer.getvalue())


def package_versions() -> dict:
    return {
        "package": "auv_envs",
        "package_version": auv_envs.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
        "gymnasium": gym.__version__,
        "python": platform.python_version(),
    }


def write_run_info(run: RunDirectory, info: dict) -> None:
    atomic_write(run.info, json.dumps(info, indent=2))


def write_final(run: RunDirectory, model, config: TrainConfig) -> Path:
    """``final/``: model, normalisation statistics and a manifest :class:`PolicyAgent` loads."""
    run.final.mkdir(parents=True, exist_ok=True)
    model.save(run.final / MODEL_FILE)
    files = [MODEL_FILE]
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        normalizer.save(run.final / NORMALIZER_FILE)
        files.append(NORMALIZER_FILE)
    manifest = {
        "name": run.path.name,
        "algo": config.algo,
        "env_id": config.env_id,
        "obs_mode": config.run["obs_mode"],
        "env_kwargs": config.run["env_kwargs"],
        "flatten_obs": config.run["flatten_obs"],
        **{name: config.run[name] for name in FRONT_ENDS},
        "steps": int(model.num_timesteps),
        "files": {name: sha256_file(run.final / name) for name in files},
    }
    (run.final / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2))
    return run.final


# ---------------------------------------------------------------- divergence
def _learned_tensors(model) -> dict[str, torch.Tensor]:
    """Every tensor the model learns: the policy's parameters (actor, critics, their
    targets) and SAC's entropy coefficient."""
    tensors = dict(model.policy.named_parameters())
    if isinstance(getattr(model, "log_ent_coef", None), torch.Tensor):
        tensors["log_ent_coef"] = model.log_ent_coef
    return tensors


def non_finite(model) -> list[str]:
    """What of ``model`` is not finite: parameter names, ``exp(log_std)`` (the action
    noise, which must stay in (0, inf)), the normalisation statistics, the losses of the
    last update; empty when all are finite.

    One sum per tensor screens them (a sum is finite when every term is, barring overflow
    of huge but finite values, which the per-tensor test that follows sorts out).
    """
    bad = []
    tensors = _learned_tensors(model)
    with torch.no_grad():
        if not torch.isfinite(torch.stack([t.sum() for t in tensors.values()]).sum()):
            bad += [name for name, t in tensors.items() if not torch.isfinite(t).all()]
        log_std = getattr(model.policy, "log_std", None)
        if isinstance(log_std, torch.Tensor) and "log_std" not in bad:
            std = log_std.exp()  # the action distribution's scale: must stay in (0, inf)
            if not torch.isfinite(std).all():
                bad.append("the action std exp(log_std) (overflowed)")
            elif not (std > 0).all():
                bad.append("the action std exp(log_std) (underflowed to 0)")
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        stats = normalizer.obs_rms if isinstance(normalizer.obs_rms, dict) \
            else {"": normalizer.obs_rms}
        stats = {f"observation {key}".rstrip(): rms for key, rms in stats.items()}
        stats["return"] = normalizer.ret_rms
        bad += [f"{name} normalisation statistics" for name, rms in stats.items()
                if not (np.isfinite(rms.mean).all() and np.isfinite(rms.var).all())]
    bad += [key for key, value in model.logger.name_to_value.items()
            if key.startswith("train/") and "loss" in key and not np.isfinite(value)]
    return bad


def non_finite_rollout(model) -> list[str]:
    """What of the on-policy rollout just collected is not finite (empty when all is, or
    for an off-policy model): checked before the update learns from it."""
    buffer = getattr(model, "rollout_buffer", None)
    if buffer is None:
        return []
    return [f"rollout {name}" for name in ("rewards", "returns", "advantages")
            if not np.isfinite(getattr(buffer, name)).all()]


# ------------------------------------------------------------------ callback
class TrainingCallback(BaseCallback):
    """Evaluation, checkpoints, episode log, divergence checks and signal-driven stops at
    safe points.

    Everything happens in ``_on_rollout_start`` (the safe point of
    :mod:`baselines.rl.checkpoint`), after :meth:`check_finite`; ``_on_rollout_end``
    checks the rollout before the update; ``_on_step`` only logs finished episodes and
    stops the run after a requested checkpoint.
    """

    def __init__(self, run: RunDirectory, config: TrainConfig, bookkeeping: dict,
                 random_state: dict | None = None, echo: bool = True):
        super().__init__()
        self.run = run
        self.config = config
        self.next_eval = bookkeeping["next_eval"]
        self.next_checkpoint = bookkeeping["next_checkpoint"]
        self.wall_time_before = bookkeeping["wall_time_s"]
        self.last_eval_step = bookkeeping.get("last_eval_step", -1)
        self.random_state = random_state
        self.echo = echo
        self.stop_signal: int | None = None
        self.stopping = False
        self.latest: Path | None = None
        self.latest_step = bookkeeping.get("step", 0)
        self.latest_wall_time = self.wall_time_before
        self._eval_env: gym.Env | None = None
        self._segment_start = time.perf_counter()

    def wall_time(self) -> float:
        return self.wall_time_before + time.perf_counter() - self._segment_start

    def _on_training_start(self) -> None:
        if self.random_state is not None:
            ckpt.restore_random_state(self.model, self.random_state)
            self.random_state = None

    def check_finite(self) -> None:
        """Raise :class:`TrainingDiverged` unless the model is finite (:func:`non_finite`)."""
        bad = non_finite(self.model)
        if bad:
            raise self.diverged(bad)

    def diverged(self, what: Sequence[str]) -> TrainingDiverged:
        return TrainingDiverged(int(self.model.num_timesteps), what, self.latest, self.run.path)

    def _on_rollout_start(self) -> None:
        self.check_finite()  # before anything evaluates or saves the model
        step = self.num_timesteps
        eval_freq = self.config.run["eval_freq"]
        if self.config.run["n_eval_episodes"] and step >= self.next_eval:
            self.evaluate()
            self.next_eval = (step // eval_freq + 1) * eval_freq
        freq = self.config.run["checkpoint_freq"]
        if step >= self.next_checkpoint or self.stop_signal is not None:
            self.next_checkpoint = max(self.next_checkpoint, (step // freq + 1) * freq)
            self.save_checkpoint()
        if self.stop_signal is not None:
            self.stopping = True

    def _on_rollout_end(self) -> None:
        bad = non_finite_rollout(self.model)
        if bad:  # before the update learns from it; say what in the model made it so
            raise self.diverged([*non_finite(self.model), *bad])

    def _on_step(self) -> bool:
        for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
            if done and "episode" in info:
                _append_row(self.run.train_episodes, EPISODE_FIELDS, {
                    "step": self.num_timesteps,
                    "return": float(info["episode"]["r"]),
                    "length": int(info["episode"]["l"]),
                    "success": int(bool(info.get("is_success", False))),
                })
        return not self.stopping

    def bookkeeping(self) -> dict:
        return {
            "next_eval": self.next_eval,
            "next_checkpoint": self.next_checkpoint,
            "wall_time_s": self.wall_time(),
            "last_eval_step": self.last_eval_step,
            "step": int(self.model.num_timesteps),
        }

    def save_checkpoint(self) -> Path:
        bookkeeping = self.bookkeeping()
        self.latest = ckpt.write_checkpoint(
            self.run.checkpoints, self.model, self.config, bookkeeping,
            self.config.run["keep_checkpoints"],
        )
        self.latest_step = int(self.model.num_timesteps)
        self.latest_wall_time = bookkeeping["wall_time_s"]
        return self.latest

    def evaluate(self) -> dict:
        """The deterministic policy on the held-out seeds; appends a row to ``eval_curve.csv``."""
        config = self.config
        if self._eval_env is None:
            self._eval_env = gym.make(config.env_id, obs_mode=config.run["obs_mode"],
                                      **config.run["env_kwargs"])
        agent = PolicyAgent(self._eval_env, self.model, self.model.get_vec_normalize_env(),
                            config.run["flatten_obs"], front_ends_of(config.run))
        rows = [run_episode(self._eval_env, agent, seed, config.env_id, "training")
                for seed in eval_seeds(config)]
        returns = np.array([r.episode_return for r in rows])
        row = {
            "step": self.num_timesteps,
            "mean_return": float(returns.mean()),
            "std_return": float(returns.std()),
            "success_rate": float(np.mean([r.success for r in rows])),
            "mean_length": float(np.mean([r.length for r in rows])),
            "episodes": len(rows),
        }
        _append_row(self.run.eval_curve, EVAL_FIELDS, row)
        self.last_eval_step = self.num_timesteps
        self.logger.record("eval/mean_return", row["mean_return"])
        self.logger.record("eval/success_rate", row["success_rate"])
        if self.echo:
            print(f"[eval] step {row['step']}: return {row['mean_return']:.2f} "
                  f"± {row['std_return']:.2f}, success {row['success_rate']:.0%} "
                  f"over {row['episodes']} held-out episodes", flush=True)
        return row

    def close(self) -> None:
        if self._eval_env is not None:
            self._eval_env.close()
            self._eval_env = None


@contextlib.contextmanager
def stop_on_signals(callback, doing: str = "checkpointing at the next safe point"):
    """SIGINT/SIGTERM set ``callback.stop_signal``: the trainer does what ``doing`` says
    and stops; a second signal aborts at once (:class:`KeyboardInterrupt`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        if callback.stop_signal is not None:
            raise KeyboardInterrupt(f"second {signal.Signals(signum).name}: aborted")
        callback.stop_signal = signum
        print(f"\n{signal.Signals(signum).name}: {doing}, then stopping (send it again "
              "to abort without saving)", flush=True)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


# ------------------------------------------------------------------ training
def _learn(model, config: TrainConfig, run: RunDirectory, callback: TrainingCallback,
           fresh: bool, command: str, progress_bar: bool, callbacks: Sequence[BaseCallback]
           ) -> TrainResult:
    torch.set_num_threads(config.run["torch_threads"])
    start_step = int(model.num_timesteps)
    model.set_logger(configure(str(run.logs / f"segment-{start_step:010d}"),
                               ["csv", "tensorboard"]))
    info = json.loads(run.info.read_text()) if run.info.is_file() else {
        **package_versions(), "algo": config.algo, "env_id": config.env_id, "seed": config.seed,
        "command": command, "segments": [],
    }
    info["n_timesteps"] = config.run["n_timesteps"]
    segment = {"command": command, "start_step": start_step, "status": "running",
               **package_versions()}
    info["segments"].append(segment)
    info["status"] = "running"
    write_run_info(run, info)
    try:
        with stop_on_signals(callback):
            model.learn(
                config.run["n_timesteps"] - start_step,
                callback=[callback, *callbacks],
                reset_num_timesteps=fresh,
                progress_bar=progress_bar,
            )
        finished = not callback.stopping
        if finished:
            callback.check_finite()  # the last update came after the last safe point
            if config.run["n_eval_episodes"] and callback.last_eval_step < model.num_timesteps:
                callback.evaluate()
            callback.save_checkpoint()
            write_final(run, model, config)
    except KeyboardInterrupt:
        segment.update(status="aborted")
        info.update(status="aborted")
        write_run_info(run, info)
        raise
    except Exception as exc:
        # A non-finite model also makes torch raise mid-update (a NaN action mean, say).
        error = exc
        if not isinstance(exc, TrainingDiverged):
            bad = non_finite(model)
            error = TrainingDiverged(int(model.num_timesteps), bad, callback.latest,
                                     run.path) if bad else None
        status = "failed" if error is None else "diverged"
        segment.update(status=status, end_step=callback.latest_step, error=str(error or exc))
        info.update(status=status, steps=callback.latest_step,
                    wall_time_s=round(callback.latest_wall_time, 3))
        write_run_info(run, info)
        if error is None or error is exc:
            raise
        raise error from exc
    finally:
        callback.close()
        model.get_env().close()
    # An interrupted run counts what its last checkpoint holds: the steps after it are redone.
    steps, wall = callback.latest_step, callback.latest_wall_time
    segment.update(end_step=steps, status="finished" if finished else "interrupted",
                   wall_time_s=round(callback.wall_time() - callback.wall_time_before, 3))
    info.update(status=segment["status"], steps=steps, wall_time_s=round(wall, 3))
    write_run_info(run, info)
    stopped_by = None if finished else signal.Signals(callback.stop_signal).name
    return TrainResult(run.path, steps, finished, stopped_by, callback.latest, wall)


def train(config: TrainConfig, run_dir: str | Path, command: str = "",
          progress_bar: bool = True, callbacks: Sequence[BaseCallback] = (),
          echo: bool = True) -> TrainResult:
    """Train from scratch into a new (or empty) run directory.

    Args:
        config: resolved config (:func:`baselines.rl.config.resolve_config`).
        run_dir: the run directory; refused if it already holds a run.
        command: the command line to record.
        progress_bar: show SB3's progress bar.
        callbacks: extra SB3 callbacks (after the training callback).
        echo: print evaluation lines.
    """
    validate(config)
    run = RunDirectory(run_dir)
    if run.config.exists():
        raise ConfigError(f"{run.path} already holds a run; resume it with --resume or pick "
                          "another --run-dir")
    torch.set_num_threads(config.run["torch_threads"])
    model = build_model(config)  # before writing anything: a bad env argument fails here
    run.path.mkdir(parents=True, exist_ok=True)
    save_config(config, run.config)
    if config.hyperparams.get("use_sde"):
        print("note: with use_sde a resumed run is not bit-identical to an uninterrupted one",
              flush=True)
    # Checkpoint 0 (the initial model): a run that diverges early still has one to resume.
    bookkeeping = {"next_eval": 0, "next_checkpoint": 0, "wall_time_s": 0.0}
    callback = TrainingCallback(run, config, bookkeeping, echo=echo)
    return _learn(model, config, run, callback, True, command, progress_bar, callbacks)


def resume(run_dir: str | Path, command: str = "", n_timesteps: int | None = None,
           expected: TrainConfig | None = None, progress_bar: bool = True,
           callbacks: Sequence[BaseCallback] = (), echo: bool = True,
           overrides: dict | None = None) -> TrainResult:
    """Continue a run from its latest checkpoint.

    Args:
        run_dir: a run directory written by :func:`train`.
        command: the command line to record.
        n_timesteps: a new total (to train longer); default: the recorded one.
        expected: a config the caller asked for; it must match the recorded
            one apart from ``n_timesteps`` and the settings in
            :data:`baselines.rl.config.RESUMABLE` (which it then sets), else
            :class:`ConfigError`.
        progress_bar, callbacks, echo: as in :func:`train`.
        overrides: new values of settings in :data:`~baselines.rl.config.RESUMABLE`
            (``{"learning_rate": 1.0e-4}`` after a divergence, say).
    """
    run = RunDirectory(run_dir)
    config = read_config(run.config)
    if config.algo == COMPILED:
        raise ConfigError(f"{run.path} is a compiled PPO (cppo) run, which cannot be resumed; "
                          "train it again (the same config and seed give the same policy)")
    if expected is not None:
        if (expected.algo, expected.env_id, expected.seed) != (
                config.algo, config.env_id, config.seed) \
                or expected.resumable_digest() != config.resumable_digest():
            raise ConfigError(
                f"the requested config does not match the one recorded in {run.config}; "
                f"resume with the same settings (only --n-timesteps and "
                f"{', '.join(RESUMABLE)} may change)"
            )
        overrides = {**{k: expected.hyperparams[k] for k in RESUMABLE
                        if k in expected.hyperparams}, **(overrides or {})}
    if overrides:
        config = resumed(config, overrides)
    if n_timesteps is not None:
        config = dataclasses.replace(config, run={**config.run, "n_timesteps": n_timesteps})
        validate(config)
    path = ckpt.latest_checkpoint(run.checkpoints)
    torch.set_num_threads(config.run["torch_threads"])
    model, random_state, bookkeeping = ckpt.load_checkpoint(path, config, custom_objects(config))
    step = int(model.num_timesteps)
    if step >= config.run["n_timesteps"]:
        model.get_env().close()
        raise ConfigError(
            f"{run.path} already reached {step} steps (n_timesteps "
            f"{config.run['n_timesteps']}); pass a larger --n-timesteps to train longer"
        )
    save_config(config, run.config)
    for path_csv in (run.eval_curve, run.train_episodes):
        _truncate_rows(path_csv, step)
    callback = TrainingCallback(run, config, bookkeeping, random_state, echo=echo)
    callback.latest = path
    return _learn(model, config, run, callback, False, command, progress_bar, callbacks)
