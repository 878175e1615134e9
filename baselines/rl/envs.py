"""The environment stack between an ``auv_envs`` environment and a Stable-Baselines3 learner.

Training and the policy agent build the *same* Gymnasium wrappers through
:func:`wrap_env`, so an action the learner outputs maps back to the
environment's action exactly as it did in training:

* ``RescaleAction(-1, 1)`` when the action space is a Box with other bounds
  (``AcousticTracking-v2`` acts with a position in the tank);
* the classical front ends the config asks for (:data:`FRONT_ENDS`):
  :class:`~baselines.rl.detection_fixes.DetectionFixes` (``detection_fixes``: one
  least-squares fix per acoustic detection) and
  :class:`~baselines.rl.marker_estimate.MarkerEstimate` (``marker_estimate``:
  ``ckf-pd``'s LARS state estimate relative to the capture tip);
* :class:`FlattenObservation` when the config asks for it (a ``Dict``
  observation becomes one vector for an ``MlpPolicy``).

Training adds :class:`LearnerInfo` (drops the ground-truth info the learner
never reads), SB3's ``Monitor`` (episode returns), a ``DummyVecEnv`` and,
optionally, ``VecNormalize`` over the non-image ``Box`` observation keys.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import RescaleAction
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize

import auv_envs  # noqa: F401  (registers the ids)
from baselines.registry import LazyFactory
from baselines.rl.config import FRONT_ENDS, ConfigError, TrainConfig


def has_image(space: spaces.Space) -> bool:
    """Whether ``space`` (or one of its ``Dict`` entries) is an image."""
    if isinstance(space, spaces.Dict):
        return any(has_image(s) for s in space.spaces.values())
    return is_image_space(space, check_channels=False)


def needs_rescale(space: spaces.Space) -> bool:
    return isinstance(space, spaces.Box) and not (
        np.all(space.low == -1.0) and np.all(space.high == 1.0)
    )


class FlattenObservation(gym.wrappers.FlattenObservation):
    """Gymnasium's ``FlattenObservation``, with one ``np.concatenate`` for a plain ``Dict``.

    Gymnasium flattens a ``Dict`` key by key through ``spaces.flatten``'s
    single dispatch (a cast, a flatten and a copy per key) and then
    concatenates; on ``LARSCapture-v0`` ``features`` that cost a tenth of a
    PPO step (``benchmarks/ppo_speed.py``). When every key is a ``Box`` or
    ``MultiBinary`` its flat vector is each key's values in key order and C
    order, cast to the flat space's dtype, which one ``np.concatenate``
    builds: the same vector for every observation of the space (checked
    against ``spaces.flatten`` in ``tests/test_rl_envs.py``). Other spaces
    keep Gymnasium's path; the observation space is Gymnasium's either way.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        space = env.observation_space
        plain = isinstance(space, spaces.Dict) and all(
            isinstance(s, spaces.Box | spaces.MultiBinary) for s in space.spaces.values()
        )
        self._keys = tuple(space.spaces) if plain else None

    @property
    def concatenates(self) -> bool:
        """Whether observations flatten by one concatenation of their keys (every entry a
        ``Box`` or ``MultiBinary``), rather than through Gymnasium's ``flatten``."""
        return self._keys is not None

    def observation(self, observation):
        if self._keys is None:
            return super().observation(observation)
        return np.concatenate([observation[key] for key in self._keys], axis=None,
                              dtype=self.observation_space.dtype)


def front_ends_of(settings) -> tuple[str, ...]:
    """The front ends (:data:`FRONT_ENDS` keys) a config's run keys or a policy
    manifest switch on; a key that is absent (an older file) is off."""
    return tuple(name for name in FRONT_ENDS if settings.get(name, False))


def wrap_env(env: gym.Env, flatten_obs: bool = False, front_ends=()) -> gym.Env:
    """The wrappers every learner and policy agent sees around ``env``; ``front_ends``
    names :data:`FRONT_ENDS` (applied in that table's order)."""
    unknown = set(front_ends) - set(FRONT_ENDS)
    if unknown:
        raise ConfigError(f"unknown front end(s) {sorted(unknown)}; valid: {', '.join(FRONT_ENDS)}")
    if needs_rescale(env.action_space):
        env = RescaleAction(env, np.float32(-1.0), np.float32(1.0))
    for name, target in FRONT_ENDS.items():
        if name in front_ends:  # imported here: each pipeline loads only where it is used
            env = LazyFactory(target).resolve()(env)
    if flatten_obs:
        if has_image(env.observation_space):
            raise ConfigError("flatten_obs cannot flatten image observations; use policy=auto")
        env = FlattenObservation(env)
    return env


#: The info keys a learner reads (SB3's success rate); Monitor adds ``episode``.
LEARNER_INFO_KEYS = ("is_success",)


class LearnerInfo(gym.Wrapper):
    """Passes on only :data:`LEARNER_INFO_KEYS` of ``info``.

    SB3's ``DummyVecEnv`` deep-copies every info dict on every step, and the
    ``auv_envs`` infos carry ground truth for metrics (pixels, positions,
    per-step errors) that training never reads; copying it cost about an
    eighth of PPO's time on ``DockingStation-v0`` (``benchmarks/ppo_speed.py``).
    Only the training vector env uses this wrapper; evaluation sees full infos.
    """

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return obs, _keep(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, _keep(info)


def _keep(info: dict) -> dict:
    return {key: info[key] for key in LEARNER_INFO_KEYS if key in info}


def make_env(config: TrainConfig) -> gym.Env:
    """One wrapped training environment (no seeding: the vector env seeds it)."""
    try:
        env = gym.make(config.env_id, obs_mode=config.run["obs_mode"],
                       **config.run["env_kwargs"])
    except (TypeError, ValueError) as exc:
        raise ConfigError(
            f"cannot make {config.env_id} with obs_mode={config.run['obs_mode']!r} and "
            f"env_kwargs {config.run['env_kwargs']}: {exc}"
        ) from exc
    return Monitor(LearnerInfo(wrap_env(env, config.run["flatten_obs"],
                                        front_ends_of(config.run))))


def normalize_arguments(config: TrainConfig, observation_space: spaces.Space) -> dict | None:
    """``VecNormalize`` keyword arguments, or None when the config does not normalise.

    ``normalize: true`` uses SB3's defaults; a mapping passes its keys through
    (``norm_reward``, ``clip_obs``, ``gamma`` ...). For ``Dict`` observations
    only the non-image ``Box`` keys are normalised unless ``norm_obs_keys`` is set.
    """
    setting = config.run["normalize"]
    if setting is False:
        return None
    kwargs = {} if setting is True else dict(setting)
    valid = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon",
             "norm_obs_keys"}
    unknown = set(kwargs) - valid
    if unknown:
        raise ConfigError(
            f"unknown normalize setting(s) {sorted(unknown)}; valid: {', '.join(sorted(valid))}"
        )
    if isinstance(observation_space, spaces.Dict) and "norm_obs_keys" not in kwargs:
        kwargs["norm_obs_keys"] = [
            key for key, space in observation_space.spaces.items()
            if isinstance(space, spaces.Box) and not is_image_space(space, check_channels=False)
        ]
    elif has_image(observation_space):
        kwargs.setdefault("norm_obs", False)
    return kwargs


def make_vec_env(config: TrainConfig, envs: list[gym.Env] | None = None) -> VecEnv:
    """``DummyVecEnv`` of ``n_envs`` wrapped environments (or of ``envs``), normalised if asked.

    On 2 cores ``SubprocVecEnv`` is slower than stepping in-process (measured on a
    2-core machine), and in-process envs can be checkpointed by pickling them.
    """
    if envs is None:
        envs = [make_env(config) for _ in range(config.run["n_envs"])]
    vec_env = DummyVecEnv([(lambda e=e: e) for e in envs])
    kwargs = normalize_arguments(config, vec_env.observation_space)
    if kwargs is not None:
        vec_env = VecNormalize(vec_env, **kwargs)
    return vec_env
