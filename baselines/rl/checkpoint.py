"""Checkpoints from which training resumes exactly where it stopped.

A checkpoint is taken only at a *safe point*: the start of a rollout, after the
previous update and before the next environment step (SB3 calls
``on_rollout_start`` there, for on- and off-policy algorithms alike). At that
point the whole learner state is

* the SB3 model file (parameters, optimiser states, step counters, the last
  observation and episode-start flags, the episode-statistics buffers);
* the replay buffer (off-policy algorithms);
* the environments mid-episode (pickled with their wrappers: each ``auv_envs``
  environment pickles its MuJoCo state and its generator) and the
  ``VecNormalize`` statistics, including the discounted-return accumulator
  that ``VecNormalize`` itself does not pickle;
* the global random states that SB3 draws from (Python, NumPy: minibatch
  permutations, replay sampling, action noise; PyTorch: action sampling) and
  the action space's generator (random warm-up actions).

Restoring all of it and calling ``learn`` again reproduces the uninterrupted
run bit for bit (``tests/test_train.py`` checks it), except with gSDE
(``use_sde``): SB3 resamples the exploration matrix *before* the safe point,
so a resumed gSDE run continues correctly but not bit-identically.

Each checkpoint directory holds a ``manifest.json`` with the SHA-256 of every
file and the digests of the config that produced it; a corrupt file or a
checkpoint of another configuration is refused with :class:`CheckpointError`.
A config that differs only in the settings a resume may change
(:data:`baselines.rl.config.RESUMABLE`, its ``resumable_digest``) continues it.
Directories are written under a temporary name and renamed, and the ``latest``
pointer is replaced atomically, so an interrupted write never leaves a
half-checkpoint behind as the latest one.
"""

from __future__ import annotations

import json
import os
import random
import shutil
from pathlib import Path

import cloudpickle
import numpy as np
import torch
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize

from auv_envs.core.assets import sha256_file, verify_sha256
from baselines.fileio import atomic_write
from baselines.rl.config import ALGORITHMS, OFF_POLICY, RESUMABLE, TrainConfig
from baselines.rl.envs import make_vec_env

FORMAT = 1
MODEL = "model.zip"
REPLAY_BUFFER = "replay_buffer.pkl"
STATE = "state.pkl"
MANIFEST = "manifest.json"
LATEST = "latest"


class CheckpointError(RuntimeError):
    """A checkpoint that is missing, corrupt or from another configuration."""


def _inner_dummy(vec_env: VecEnv) -> DummyVecEnv:
    env = vec_env
    while not isinstance(env, DummyVecEnv):
        if not hasattr(env, "venv"):
            raise CheckpointError(f"cannot checkpoint a {type(vec_env).__name__}")
        env = env.venv
    return env


def capture_random_state(model) -> dict:
    """Every random state the learner draws from (see the module docstring)."""
    return {
        "python": random.getstate(),
        "numpy": np.random.get_state(),  # noqa: NPY002 (SB3 draws from the legacy global)
        "torch": torch.get_rng_state(),
        "action_space": model.action_space.np_random.bit_generator.state,
        "action_noise": model.action_noise if hasattr(model, "action_noise") else None,
    }


def restore_random_state(model, state: dict) -> None:
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])  # noqa: NPY002 (the legacy global, as above)
    torch.set_rng_state(state["torch"])
    model.action_space.np_random.bit_generator.state = state["action_space"]
    if state["action_noise"] is not None:
        model.action_noise = state["action_noise"]


def write_checkpoint(root: Path, model, config: TrainConfig, extra: dict, keep: int) -> Path:
    """Save the learner at a safe point under ``root/step-<n>``; returns the directory.

    Args:
        root: the run's checkpoint directory.
        model: the SB3 model (its env is the training ``VecEnv``).
        config: the run's config (its digest goes into the manifest).
        extra: training-loop bookkeeping to restore with the learner.
        keep: how many checkpoints to keep (older ones are deleted).
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    step = int(model.num_timesteps)
    tmp = root / f".tmp-step-{step:010d}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    model.save(tmp / MODEL)
    if config.algo in OFF_POLICY:
        model.save_replay_buffer(tmp / REPLAY_BUFFER)
    vec_env = model.get_env()
    normalizer = model.get_vec_normalize_env()
    state = {
        "random": capture_random_state(model),
        "envs": _inner_dummy(vec_env).envs,
        "normalizer": normalizer,  # VecNormalize pickles its statistics without its env
        "normalizer_returns": None if normalizer is None else normalizer.returns.copy(),
        "extra": extra,
    }
    with open(tmp / STATE, "wb") as handle:
        cloudpickle.dump(state, handle)
    files = {p.name: sha256_file(p) for p in sorted(tmp.iterdir())}
    manifest = {
        "format": FORMAT,
        "step": step,
        "algo": config.algo,
        "env_id": config.env_id,
        "obs_mode": config.run["obs_mode"],
        "config_digest": config.digest(),
        "resumable_digest": config.resumable_digest(),
        "files": files,
    }
    atomic_write(tmp / MANIFEST, json.dumps(manifest, indent=2))
    final = root / f"step-{step:010d}"
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
    atomic_write(root / LATEST, json.dumps({"checkpoint": final.name}, indent=2))
    for old in sorted(root.glob("step-*"))[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def latest_checkpoint(root: Path) -> Path:
    """The directory the ``latest`` pointer names; ``CheckpointError`` when there is none."""
    pointer = Path(root) / LATEST
    if not pointer.is_file():
        raise CheckpointError(f"no checkpoint to resume from: {pointer} does not exist")
    try:
        name = json.loads(pointer.read_text())["checkpoint"]
    except (json.JSONDecodeError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"checkpoint pointer {pointer} is corrupt: {exc}") from exc
    path = Path(root) / name
    if Path(name).name != name or not path.is_dir():
        raise CheckpointError(f"checkpoint pointer {pointer} names a missing directory {name!r}")
    return path


def verify_checkpoint(path: Path, config: TrainConfig) -> dict:
    """Check a checkpoint's files and that ``config`` produced it; returns its manifest."""
    path = Path(path)
    manifest_path = path / MANIFEST
    if not manifest_path.is_file():
        raise CheckpointError(f"checkpoint {path} is incomplete: {MANIFEST} missing")
    try:
        manifest = json.loads(manifest_path.read_text())
        files = dict(manifest["files"])
    except (json.JSONDecodeError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"checkpoint manifest {manifest_path} is corrupt: {exc}") from exc
    if manifest.get("format") != FORMAT:
        raise CheckpointError(
            f"checkpoint {path} has format {manifest.get('format')!r}, this version reads {FORMAT}"
        )
    verify_sha256(path, files, CheckpointError)
    required = {MODEL, STATE} | ({REPLAY_BUFFER} if config.algo in OFF_POLICY else set())
    if not required <= set(files):
        raise CheckpointError(f"checkpoint {path} lacks {sorted(required - set(files))}")
    mine = {"algo": config.algo, "env_id": config.env_id, "obs_mode": config.run["obs_mode"]}
    theirs = {k: manifest.get(k) for k in mine}
    if mine != theirs:
        raise CheckpointError(f"checkpoint {path} is from a {theirs} run, this run is {mine}")
    # Checkpoints written before resumable_digest existed fit their exact config only.
    fits = (manifest["resumable_digest"] == config.resumable_digest()
            if "resumable_digest" in manifest else manifest.get("config_digest") == config.digest())
    if not fits:
        raise CheckpointError(
            f"checkpoint {path} was written with different hyperparameters than this run's "
            f"config (only n_timesteps, the evaluation/checkpoint frequencies and "
            f"{', '.join(RESUMABLE)} may change on resume)"
        )
    return manifest


def load_checkpoint(path: Path, config: TrainConfig, custom_objects: dict):
    """Rebuild model and vector env from a verified checkpoint.

    Returns:
        ``(model, random_state, extra)``; restore ``random_state`` with
        :func:`restore_random_state` right before training continues (building
        the model draws from the global generators).
    """
    manifest = verify_checkpoint(path, config)
    path = Path(path)
    try:
        with open(path / STATE, "rb") as handle:
            state = cloudpickle.load(handle)
        vec_env = make_vec_env(config, envs=list(state["envs"]))
        if state["normalizer"] is not None:
            normalizer: VecNormalize = state["normalizer"]
            normalizer.set_venv(_inner_dummy(vec_env))
            normalizer.returns = state["normalizer_returns"]
            vec_env = normalizer
        model = ALGORITHMS[config.algo].load(
            path / MODEL, env=vec_env, device="cpu", force_reset=False,
            custom_objects=custom_objects,
        )
        if config.algo in OFF_POLICY:
            model.load_replay_buffer(path / REPLAY_BUFFER)
    except CheckpointError:
        raise
    except Exception as exc:  # a verified file that still fails to load
        raise CheckpointError(f"cannot load checkpoint {path}: {exc}") from exc
    if model.num_timesteps != manifest["step"]:
        raise CheckpointError(
            f"checkpoint {path} holds step {model.num_timesteps}, its manifest says "
            f"{manifest['step']}"
        )
    return model, state["random"], state["extra"]
