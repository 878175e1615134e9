"""Every family's task as Gymnasium's functional environment (``FuncEnv``).

:class:`TaskFuncEnv` speaks the interface of Gymnasium's
``gymnasium.experimental.functional.FuncEnv``: pure functions of an explicit state, random
key and parameters: ``initial(rng, params)``, ``transition(state, action, rng, params)``,
``observation``, ``reward``, ``terminal``, ``state_info`` and ``transition_info``. The
state is the batched shell's :class:`~auv_envs.batched.functional.State` (a frozen pytree:
the plant's state, the episode, the key, the observation, the reward, the flags and the
metrics); the parameters are the :class:`~auv_envs.batched.functional.World` the episode
runs in (:meth:`TaskFuncEnv.get_default_params` the nominal one; a domain randomiser's
worlds, :meth:`~auv_envs.batched.functional.FunctionalEnv.randomize`, vary it). Gymnasium's
``FunctionalJaxEnv`` runs it as a Gymnasium environment, and ``transform(jax.vmap)``
batches it.

The episode's time limit is not the task's (``terminal`` is the task's own end: docking,
failure, capture...); a wrapper or the trainer truncates, as Gymnasium's functional
environments leave it.
"""

from __future__ import annotations

from gymnasium.experimental.functional import FuncEnv

from auv_envs.batched.functional import FunctionalEnv, State, World


class TaskFuncEnv(FuncEnv):
    """A family's task as Gymnasium's ``FuncEnv`` (module docstring).

    Args:
        env_id: a family's id (``auv_envs.families.FAMILIES``).
        obs_mode: one of the family's batched modes (None: its default).
        **env_kwargs: the family's configuration (the CPU environment's arguments).

    The observation and action spaces are the CPU environment's. ``rng`` is the key of the
    call's draws: a transition draws from it, not from the state's own key.
    """

    def __init__(self, env_id: str, obs_mode: str | None = None, **env_kwargs):
        #: The batched shell whose reset and step these functions are (no auto-reset).
        self.shell = FunctionalEnv(env_id, obs_mode, auto_reset=False, **env_kwargs)
        self.observation_space = self.shell.observation_space
        self.action_space = self.shell.action_space
        super().__init__()

    def get_default_params(self, **kwargs) -> World:
        """The nominal world (no physics varied)."""
        return self.shell.mjx_model

    def initial(self, rng, params: World | None = None) -> State:
        """A new episode drawn from ``rng`` in the world ``params``."""
        return self.shell.reset(rng, params)

    def transition(self, state: State, action, rng, params: World | None = None) -> State:
        """One step under ``action`` (clipped to the action space), its draws from ``rng``,
        in the world ``params``."""
        state = state.replace(info={**state.info, "rng": rng})
        return self.shell.step(state, action, params)

    def observation(self, state: State, rng=None, params: World | None = None):
        return state.obs

    def reward(self, state: State, action, next_state: State, rng=None,
               params: World | None = None):
        return next_state.reward

    def terminal(self, state: State, rng=None, params: World | None = None):
        """Whether the episode ended by the task's own end (not its time limit)."""
        return state.info["terminated"]

    def state_info(self, state: State, params: World | None = None) -> dict:
        """The state's metrics (the step's, its reward terms and the episode's summary)."""
        return dict(state.metrics)

    def transition_info(self, state: State, action, next_state: State,
                        params: World | None = None) -> dict:
        return dict(next_state.metrics)
