"""What the classical front ends of the learners share. Each is pure functions of arrays with
a carry (the episode so far), served by two shells:

* :class:`FrontEnd`, the Gymnasium wrapper that runs them with NumPy on the CPU (the shipped
  agents apply it);
* :class:`BatchedFrontEnd`, a batched env whose observation they compute in JAX from the
  wrapped env's, the carry riding along in ``state.info`` (the compiled PPO trains on it).

:mod:`~baselines.rl.marker_track` (LARS), :mod:`~baselines.rl.detection_fixes` (acoustic) and
:mod:`~baselines.rl.nav_filter` (the docking mission) subclass both.
"""

from __future__ import annotations

import gymnasium as gym


class FrontEnd(gym.ObservationWrapper):
    """A front end on the CPU: the carry (``self.state``) starts afresh at :meth:`reset`
    and :meth:`clear` (which the policy agent calls at each episode's start) and advances
    with each observation, so each observation must be passed once and in order.

    Subclasses set ``observation_space``, call :meth:`clear` once built, and define
    :meth:`start` (the carry of a new episode) and :meth:`advance` (one observation: the
    next carry and the front end's observation), both on NumPy.
    """

    def start(self):
        raise NotImplementedError

    def advance(self, carry, obs) -> tuple:
        raise NotImplementedError

    def clear(self) -> None:
        """Forget the episode: the front end starts afresh at the next observation."""
        self.state = self.start()

    def reset(self, **kwargs):
        self.clear()
        return super().reset(**kwargs)

    def observation(self, observation):
        self.state, seen = self.advance(self.state, observation)
        return seen


class BatchedFrontEnd:
    """A batched env (a :class:`~auv_envs.batched.functional.FunctionalEnv`, auto-reset)
    whose observation is the front end's. The front end's carry rides in
    ``state.info[INFO_KEY]`` and starts afresh where an episode restarted. Everything
    else is the wrapped env's (its attributes are passed through).

    Subclasses set ``INFO_KEY`` and ``observation_space`` (through :meth:`around`) and
    define :meth:`start` (the carry of a new episode) and :meth:`advance` (one
    observation: the next carry and the front end's observation), both on ``jax.numpy``.
    Over an env built with ``privileged=True`` the front end reads and replaces the
    ``"state"`` entry and passes ``"privileged_state"`` on.
    """

    INFO_KEY = ""

    def __init__(self, env):
        import jax
        import jax.numpy as jnp

        self.env, self._jax, self._jnp = env, jax, jnp

    def __getattr__(self, name):
        return getattr(self.env, name)

    def around(self, space):
        """The observation space of this front end's observation ``space``: itself, or over
        a privileged env the ``Dict`` of it and the privileged state's."""
        if not getattr(self.env, "privileged", False):
            return space
        from gymnasium import spaces

        from auv_envs.batched.functional import POLICY_KEY, PRIVILEGED_KEY

        return spaces.Dict({POLICY_KEY: space, PRIVILEGED_KEY: self.env.privileged_space})

    def start(self):
        raise NotImplementedError

    def advance(self, carry, obs) -> tuple:
        raise NotImplementedError

    def _observed(self, state, restart):
        jnp = self._jnp
        carry = self._jax.tree_util.tree_map(
            lambda new, old: jnp.where(restart, new, old).astype(old.dtype),
            self.start(), state.info[self.INFO_KEY])
        if not getattr(self.env, "privileged", False):
            return self.advance(carry, state.obs)
        from auv_envs.batched.functional import POLICY_KEY

        carry, seen = self.advance(carry, state.obs[POLICY_KEY])
        return carry, {**state.obs, POLICY_KEY: seen}

    def reset(self, rng):
        state = self.env.reset(rng)
        state = state.replace(info={**state.info, self.INFO_KEY: self.start()})
        carry, obs = self._observed(state, self._jnp.bool_(True))
        return state.replace(obs=obs, info={**state.info, self.INFO_KEY: carry})

    def step_batch(self, states, actions):
        stepped = self.env.step_batch(states, actions)
        carry, obs = self._jax.vmap(self._observed)(stepped, stepped.done)
        return stepped.replace(obs=obs, info={**stepped.info, self.INFO_KEY: carry})
