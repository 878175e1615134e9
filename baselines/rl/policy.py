"""A trained Stable-Baselines3 policy acting through the agent protocol.

:class:`PolicyAgent` turns a raw observation of an ``auv_envs`` environment
into the learner's input exactly as in training (the wrappers of
:func:`baselines.rl.envs.wrap_env`, then ``VecNormalize.normalize_obs`` with
the frozen training statistics), takes the deterministic action and maps it
back through the same wrappers (e.g. ``RescaleAction`` onto the acoustic
tank). Files are checked against SHA-256 digests recorded when they were
written, so a truncated or edited file fails with a clear error instead of
acting wrongly (:mod:`baselines.rl.manifest`).
"""

from __future__ import annotations

import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.utils import check_for_correct_spaces
from stable_baselines3.common.vec_env import VecNormalize

from baselines.rl.config import ALGORITHMS
from baselines.rl.envs import front_ends_of, wrap_env
from baselines.rl.manifest import (
    MODEL_FILE,
    NORMALIZER_FILE,
    RECURRENT_ALGO,
    PolicyFileError,
    read_manifest,
    verify_files,
)

#: Objects an acting policy never needs; replacing them avoids unpickling the
#: training schedules (and so works across Python versions, as rl-zoo does).
_ACTING_ONLY = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}


def load_normalizer(path: Path) -> VecNormalize:
    """The ``VecNormalize`` statistics saved by ``VecNormalize.save`` (without its env)."""
    try:
        with open(path, "rb") as handle:
            normalizer = pickle.load(handle)
    except Exception as exc:  # any unpickling failure means a bad file
        raise PolicyFileError(f"cannot read normalisation statistics {path}: {exc}") from exc
    if not isinstance(normalizer, VecNormalize):
        raise PolicyFileError(f"{path} does not hold VecNormalize statistics")
    return normalizer


def _algorithm(algo: str):
    """The class of a policy's algorithm: Stable-Baselines3's, or sb3-contrib's
    ``RecurrentPPO``."""
    if algo == RECURRENT_ALGO:
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    return ALGORITHMS[algo]


def load_model(algo: str, path: Path):
    """An SB3 model for acting (CPU, no env, no training schedules)."""
    try:
        return _algorithm(algo).load(path, device="cpu", custom_objects=_ACTING_ONLY)
    except Exception as exc:  # zip/pickle/torch errors all mean a bad file
        raise PolicyFileError(f"cannot load {algo} model {path}: {exc}") from exc


def _as_learner_sees(space):
    """SB3 stores image spaces channels-first (``VecTransposeImage``); undo that for comparison."""
    if isinstance(space, spaces.Dict):
        return spaces.Dict({k: _as_learner_sees(s) for k, s in space.spaces.items()})
    if is_image_space(space, check_channels=False) and is_image_space_channels_first(space):
        channels, height, width = space.shape
        return spaces.Box(0, 255, (height, width, channels), dtype=space.dtype)
    return space


class PolicyAgent:
    """Deterministic actions of a trained SB3 model, in the environment's own units.

    A recurrent model (sb3-contrib's ``RecurrentPPO``) carries its hidden state from one
    :meth:`act` to the next and starts each episode (:meth:`reset`) from a blank one.

    Args:
        env: the environment the agent acts in (unwrapped or not; never stepped).
        model: a Stable-Baselines3 model.
        normalizer: training ``VecNormalize`` statistics, or None.
        flatten_obs: whether training flattened the observation.
        front_ends: the classical front ends training applied
            (:data:`baselines.rl.config.FRONT_ENDS` keys, e.g. ``detection_fixes``).
    """

    def __init__(self, env: gym.Env, model, normalizer: VecNormalize | None = None,
                 flatten_obs: bool = False, front_ends=()):
        self._base = env.unwrapped
        self._wrapped = wrap_env(self._base, flatten_obs, front_ends)
        self._observation_wrappers, self._action_wrappers = self._wrapper_chain()
        for wrapper in self._observation_wrappers:
            # a front end that estimates the position (the navigation filter): the agent
            # reports it, and the leaderboard scores it (``position_estimate()``)
            if callable(getattr(wrapper, "position_estimate", None)):
                self.position_estimate = wrapper.position_estimate
        try:
            check_for_correct_spaces(self._wrapped, _as_learner_sees(model.observation_space),
                                     model.action_space)
        except ValueError as exc:
            raise PolicyFileError(f"the policy does not fit this environment: {exc}") from exc
        self._model = model
        self._normalizer = normalizer
        self.recurrent = hasattr(model.policy, "lstm_actor")
        self._memory = None  # the recurrent model's (h, c); None: blank

    @classmethod
    def from_directory(cls, env: gym.Env, directory: str | Path) -> PolicyAgent:
        """Load a policy directory written by ``train.py --export-policy``."""
        directory = Path(directory)
        manifest = read_manifest(directory)
        verify_files(directory, manifest["files"])
        if MODEL_FILE not in manifest["files"]:
            raise PolicyFileError(f"policy manifest in {directory} lists no {MODEL_FILE}")
        base = env.unwrapped
        if getattr(base, "obs_mode", manifest["obs_mode"]) != manifest["obs_mode"]:
            raise PolicyFileError(
                f"policy {manifest['name']!r} needs obs_mode={manifest['obs_mode']!r}, "
                f"the environment has {base.obs_mode!r}"
            )
        model = load_model(manifest["algo"], directory / MODEL_FILE)
        normalizer = None
        if NORMALIZER_FILE in manifest["files"]:
            normalizer = load_normalizer(directory / NORMALIZER_FILE)
        return cls(env, model, normalizer, bool(manifest["flatten_obs"]),
                   front_ends_of(manifest))

    def _wrapper_chain(self):
        outer_to_inner = []
        env = self._wrapped
        while env is not self._base:
            outer_to_inner.append(env)
            env = env.env
        observation = [w for w in reversed(outer_to_inner)
                       if isinstance(w, gym.ObservationWrapper)]
        action = [w for w in outer_to_inner if isinstance(w, gym.ActionWrapper)]
        return observation, action

    def reset(self, seed: int | None = None) -> None:
        """Clears what observation wrappers hold from the last episode (``clear()``, e.g.
        :class:`~baselines.rl.detection_fixes.DetectionFixes`) and a recurrent model's
        memory; the policy acts deterministically."""
        self._memory = None
        for wrapper in self._observation_wrappers:
            if hasattr(wrapper, "clear"):
                wrapper.clear()

    def learner_observation(self, observation):
        """The observation as the learner saw it in training."""
        for wrapper in self._observation_wrappers:
            observation = wrapper.observation(observation)
        if self._normalizer is not None:
            observation = self._normalizer.normalize_obs(observation)
        return observation

    def env_action(self, action: np.ndarray) -> np.ndarray:
        """A learner action mapped back to the environment's action space."""
        for wrapper in self._action_wrappers:
            action = wrapper.action(action)
        space = self._base.action_space
        return np.clip(np.asarray(action, dtype=space.dtype), space.low, space.high)

    def act(self, observation, info: dict) -> np.ndarray:
        observation = self.learner_observation(observation)
        if not self.recurrent:
            action, _ = self._model.predict(observation, deterministic=True)
            return self.env_action(action)
        starts = np.array([self._memory is None])
        action, self._memory = self._model.predict(observation, state=self._memory,
                                                   episode_start=starts, deterministic=True)
        return self.env_action(action)
