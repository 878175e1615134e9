"""What the batched environments share: Playground's ``State`` and NumPy's draws over a key.

A batched environment is a task's transition (``auv_envs/tasks/<family>/transition.py``)
evaluated on JAX arrays: :class:`State` is what its ``reset``/``step`` return (as
MuJoCo Playground's ``mjx_env.State``), :class:`KeyDraws` the episode's random draws
with NumPy ``Generator``'s interface over a JAX key.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


@jax.tree_util.register_dataclass
@dataclasses.dataclass
class State:
    """One environment's state (a batch of them under ``vmap``), as Playground's.

    Attributes:
        data: the plant's state (docking: ``{"qpos": (7,), "qvel": (6,)}``; LARS: the
            arm's ``mjx.Data``).
        obs: the observation (an array for ``state``, a dict for ``features``).
        reward: the last step's reward.
        done: whether the last step ended the episode (terminated or truncated).
        metrics: the last step's metrics (the environment's ``STEP_METRICS``), its
            reward terms (``reward_<term>``) and the episode's summary so far
            (``episode_*``).
        info: ``rng`` (the episode's key), ``episode`` (the transition's
            ``EpisodeState``), ``terminated``, ``truncation`` and ``final_obs`` (the
            observation that ended the episode; the present one otherwise).
    """

    data: dict
    obs: object
    reward: jax.Array
    done: jax.Array
    metrics: dict
    info: dict

    def replace(self, **changes) -> State:
        return dataclasses.replace(self, **changes)


class KeyDraws:
    """NumPy ``Generator``'s draws (``uniform``, ``standard_normal``, ``normal``, ``random``,
    ``integers``, ``permutation``)
    over a JAX key: each call splits a fresh key off, so a transition draws as it does on
    the CPU."""

    def __init__(self, key: jax.Array):
        self.key = key

    def _next(self) -> jax.Array:
        self.key, key = jax.random.split(self.key)
        return key

    @staticmethod
    def _shape(size) -> tuple:
        return () if size is None else (size,) if isinstance(size, int) else tuple(size)

    def uniform(self, low=0.0, high=1.0, size=None) -> jax.Array:
        return jax.random.uniform(self._next(), self._shape(size), minval=low, maxval=high)

    def standard_normal(self, size=None) -> jax.Array:
        return jax.random.normal(self._next(), self._shape(size))

    def normal(self, loc=0.0, scale=1.0, size=None) -> jax.Array:
        return loc + scale * self.standard_normal(size)

    def random(self, size=None) -> jax.Array:
        return jax.random.uniform(self._next(), self._shape(size))

    def integers(self, low, high=None, size=None) -> jax.Array:
        """Integers in ``[low, high)`` (``[0, low)`` without ``high``), as NumPy's."""
        low, high = (0, low) if high is None else (low, high)
        return jax.random.randint(self._next(), self._shape(size), low, high)

    def permutation(self, x) -> jax.Array:
        return jax.random.permutation(self._next(), x)


class FunctionalEnv:
    """What every batched environment's shell shares: MuJoCo Playground's interface,
    read off the CPU environment (``cpu_env``: its spaces, calibration and model) and the
    plant (``plant.model``, the MJX model), and the end of a step (the time limit and the
    auto-reset).

    A subclass sets ``cpu_env``, ``plant``, ``calibration``, ``observation_space``,
    ``action_space``, ``max_episode_steps`` and ``auto_reset``, and defines ``reset``.
    """

    cpu_env = plant = calibration = observation_space = action_space = None
    max_episode_steps: int
    auto_reset: bool = True

    @property
    def dt(self) -> float:
        return self.calibration.control_period

    @property
    def action_size(self) -> int:
        return self.action_space.shape[0]

    @property
    def observation_size(self):
        space = self.observation_space
        if hasattr(space, "spaces"):
            return {key: value.shape for key, value in space.spaces.items()}
        return space.shape[0]

    @property
    def mj_model(self):
        return self.cpu_env.physics.model

    @property
    def mjx_model(self):
        return self.plant.model

    def reset(self, rng: jax.Array) -> State:
        raise NotImplementedError

    def _started(self, rng, data, episode, obs, metrics: dict) -> State:
        """The state of an episode just begun: no reward yet, not done, its first
        observation as ``final_obs``."""
        false = jnp.bool_(False)
        info = {"rng": rng, "episode": episode, "terminated": false, "truncation": false,
                "final_obs": obs}
        return State(data, obs, jnp.float32(0.0), false, metrics, info)

    def _conclude(self, rng, reset_key, data, episode, obs, terms: dict, terminated,
                  metrics: dict) -> State:
        """The state a step returns: its reward (the terms' sum), ``done`` at termination
        or the time limit (``info["truncation"]``), and, with ``auto_reset``, the episode
        that ended replaced by a fresh one from ``reset_key`` (its ``reward``, ``done``,
        ``metrics``, ``terminated``, ``truncation`` and ``final_obs`` kept)."""
        reward = sum(terms.values())
        truncated = jnp.logical_not(terminated) & (episode.steps >= self.max_episode_steps)
        done = terminated | truncated
        info = {"rng": rng, "episode": episode, "terminated": terminated,
                "truncation": truncated, "final_obs": obs}
        stepped = State(data, obs, reward, done, metrics, info)
        if not self.auto_reset:
            return stepped
        fresh = self.reset(reset_key)
        fresh = fresh.replace(
            reward=reward, done=done, metrics=stepped.metrics,
            info={**fresh.info, "terminated": terminated, "truncation": truncated,
                  "final_obs": obs})
        return jax.tree_util.tree_map(lambda new, old: jnp.where(done, new, old), fresh, stepped)
