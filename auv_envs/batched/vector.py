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
        **env_kwargs: the environment's arguments (the family's batched class, with
            ``auto_reset=True``; building it compiles).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, num_envs: int, env_id: str = "auv_envs/DockingStation-v2",
                 obs_mode: str | None = None, max_episode_steps: int | None = None,
                 **env_kwargs):
        if not (isinstance(num_envs, int) and num_envs >= 1):
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        if max_episode_steps is not None and not (isinstance(max_episode_steps, int)
                                                  and max_episode_steps >= 1):
            raise ValueError(f"max_episode_steps must be a positive int, got "
                             f"{max_episode_steps!r}")
        entry = family(env_id)
        self.env = entry.batched_class()(entry.env_id, obs_mode=obs_mode or entry.batched_mode,
                                         **env_kwargs)
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
        self._reset = jax.jit(jax.vmap(self.env.reset))
        self._step = jax.jit(self.env.step_batch)
        self.state = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start every environment's episode; ``seed`` seeds JAX's generator for the batch."""
        super().reset(seed=seed)
        if options:
            raise ValueError(f"the batched environment takes no reset options, got {options}")
        if seed is None:
            seed = int(self.np_random.integers(2 ** 31))
        keys = jax.random.split(jax.random.PRNGKey(seed), self.num_envs)
        self.state = self._reset(keys)
        return self._numpy(self.state.obs), {}

    def step(self, actions):
        if self.state is None:
            raise RuntimeError("step() called before reset()")
        # The CPU envs' rule (auv_envs.core.env): real numbers, finite, clipped to the bounds.
        actions = clip_actions(action_array(actions, self.action_space.shape),
                               self.action_space).astype(np.float32)
        self.state = self._step(self.state, jnp.asarray(actions))
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
