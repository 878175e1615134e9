"""The batched JAX environments as a Gymnasium ``VectorEnv``, NumPy in and out.

::

    envs = gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs=1024, obs_mode="features")
    obs, info = envs.reset(seed=0)
    obs, reward, terminated, truncated, info = envs.step(actions)   # (1024, 4) float32

Each batched id is its CPU id with ``MJX`` after the family's name
(``auv_envs/DockingStationMJX-v2``, ...: :data:`auv_envs.families.FAMILIES`), registered
with :class:`TransitionVectorEnv` as its ``vector_entry_point`` and nothing else:
Gymnasium refuses that mode for an id registered with additional wrappers, and the CPU
ids carry one (their episode summary). Episodes reset
themselves on the step that ends them
(``AutoresetMode.SAME_STEP``): that step returns the new episode's first
observation; ``info["final_obs"]`` holds the observation that ended each
episode and ``info["episode_metrics"]`` its summary, each with a mask
(``info["_final_obs"]``, ``info["_episode_metrics"]``) of the environments
that ended.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from auv_envs.batched.compile_cache import use_compilation_cache
from auv_envs.batched.functional import FunctionalEnv
from auv_envs.core.env import action_array, clip_actions
from auv_envs.families import family


class TransitionVectorEnv(VectorEnv):
    """``num_envs`` environments of one batched family stepped in one compiled JAX call.

    Args:
        num_envs: the batch size.
        env_id: the CPU environment it twins, or the batched id (a family of
            :data:`auv_envs.families.FAMILIES`).
        obs_mode: the observation mode; None: the family's ``batched_mode``.
        max_episode_steps: episode length in steps (Gymnasium passes the
            registered one), cut to the env's ``time_limit`` where that is shorter;
            None: the env's ``time_limit``.
        randomize: domain randomisation: False (the default: every environment simulates
            the nominal world), True (the family's shipped randomiser,
            ``env.randomization``), or a randomiser ``fn(world, keys) -> (worlds,
            in_axes)`` (MuJoCo Playground's ``randomization_fn``, e.g. a
            :class:`~auv_envs.tasks.docking.randomization.DockingRandomization` with other
            ranges). Each environment of the batch simulates its own world for its
            whole life, drawn from the seed given to :meth:`reset` (:attr:`worlds`).
        **env_kwargs: the environment's arguments (the family's batched class, with
            ``auto_reset=True``; building it compiles).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, num_envs: int, env_id: str = "auv_envs/DockingStation-v2",
                 obs_mode: str | None = None, max_episode_steps: int | None = None,
                 randomize=False, **env_kwargs):
        if not (isinstance(num_envs, int) and num_envs >= 1):
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        if max_episode_steps is not None and not (isinstance(max_episode_steps, int)
                                                  and max_episode_steps >= 1):
            raise ValueError(f"max_episode_steps must be a positive int, got "
                             f"{max_episode_steps!r}")
        entry = family(env_id)
        self.env = FunctionalEnv(entry.env_id, obs_mode=obs_mode, **env_kwargs)
        if max_episode_steps is not None:
            # As gym.make's TimeLimit over a CPU env: whichever ends the episode first,
            # this or the env's own time_limit (make_vec passes the registered length).
            self.env.max_episode_steps = min(max_episode_steps, self.env.max_episode_steps)
        self.num_envs = num_envs
        self.step_metrics = self.env.STEP_METRICS
        self.failure_reason = self.env.end_reason
        self.single_observation_space = self.env.observation_space
        self.single_action_space = self.env.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        #: Where compiled programs are kept (a later process loads them instead); None on
        #: the CPU, where jaxlib's loader can crash (:mod:`auv_envs.batched.compile_cache`).
        self.compilation_cache = use_compilation_cache()
        #: The randomiser (None: no domain randomisation), the axes its worlds map over,
        #: and the worlds of the batch (drawn at :meth:`reset`).
        self.randomizer, in_axes, self.worlds = self._randomizer(randomize), None, None
        if self.randomizer is not None:
            in_axes = self.randomizer(self.env.mjx_model, self._world_keys(0))[1]
        self._reset = jax.jit(lambda keys, worlds: self.env.reset_batch(keys, worlds, in_axes))
        self._step = jax.jit(lambda states, actions, worlds: self.env.step_batch(
            states, actions, worlds, in_axes))
        self.state = None

    def _randomizer(self, randomize):
        """:meth:`__init__`'s ``randomize`` as a randomiser, or None."""
        if randomize is False or randomize is None:
            return None
        if randomize is True:
            if self.env.randomization is None:
                raise ValueError(f"{type(self.env).__name__} has no domain randomiser: "
                                 "give randomize=fn(world, keys) -> (worlds, in_axes)")
            return self.env.randomize
        if not callable(randomize):
            raise TypeError(f"randomize must be True, False or a randomiser "
                            f"fn(world, keys) -> (worlds, in_axes), got {randomize!r}")
        return randomize

    def _world_keys(self, seed: int) -> jax.Array:
        """The worlds' keys for ``seed`` (apart from the episodes' own keys)."""
        return jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), 0x5EED),
                                self.num_envs)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start every environment's episode; ``seed`` seeds JAX's generator for the batch."""
        super().reset(seed=seed)
        if options:
            raise ValueError(f"the batched environment takes no reset options, got {options}")
        if seed is None:
            seed = int(self.np_random.integers(2 ** 31))
        keys = jax.random.split(jax.random.PRNGKey(seed), self.num_envs)
        if self.randomizer is not None:
            self.worlds = self.randomizer(self.env.mjx_model, self._world_keys(seed))[0]
        self.state = self._reset(keys, self.worlds)
        return self._numpy(self.state.obs), {}

    def step(self, actions):
        if self.state is None:
            raise RuntimeError("step() called before reset()")
        # The CPU envs' rule (auv_envs.core.env): real numbers, finite, clipped to the bounds.
        actions = clip_actions(action_array(actions, self.action_space.shape),
                               self.action_space).astype(np.float32)
        self.state = self._step(self.state, jnp.asarray(actions), self.worlds)
        state = self.state
        info = state.info
        terminated = np.asarray(info["terminated"])
        truncated = np.asarray(info["truncation"])
        done = terminated | truncated
        metrics = {key: np.asarray(value) for key, value in state.metrics.items()}
        infos = {key: metrics[key] for key in self.step_metrics}
        infos.update({key: metrics[key] for key in metrics if key.startswith("reward_")})
        if done.any():
            infos["final_obs"] = self._numpy(info["final_obs"])
            infos["_final_obs"] = done
            infos["episode_metrics"] = self.episode_metrics(metrics)
            infos["_episode_metrics"] = done
        return (self._numpy(state.obs), np.asarray(state.reward), terminated, truncated, infos)

    def episode_metrics(self, metrics: dict) -> dict:
        """The episodes' summaries in the CPU env's names (arrays over the batch)."""
        out = {}
        for key, value in metrics.items():
            if not key.startswith("episode_"):
                continue
            key = key.removeprefix("episode_")
            if key == "failure":
                key, value = "failure_reason", np.array([
                    self.failure_reason(code, ok) for code, ok in
                    zip(value, metrics["episode_success"], strict=True)])
            out[key] = value
        return out

    @staticmethod
    def _numpy(tree):
        return jax.tree_util.tree_map(np.asarray, tree)
