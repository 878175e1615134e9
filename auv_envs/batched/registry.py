"""``auv_envs.batched.load(env_id, privileged=False, **env_kwargs)``: any family's
functional environment for the JAX RL ecosystem, as MuJoCo Playground's ``registry.load``.

::

    from brax.training.agents.ppo import train as ppo
    from mujoco_playground import wrapper
    import auv_envs.batched

    env = auv_envs.batched.load("auv_envs/LARSCapture-v0", obs_mode="features")
    make_policy, params, metrics = ppo.train(
        environment=env, num_timesteps=1_000_000, episode_length=env.episode_length,
        wrap_env_fn=wrapper.wrap_for_brax_training)

The environment keeps MuJoCo Playground's and Brax's conventions
(:meth:`~auv_envs.batched.functional.FunctionalEnv.use_playground_conventions`): a flat
float32 observation, actions in [-1, 1], float32 ``done`` at termination only (the time
limit is Brax's ``EpisodeWrapper``'s, flagged as ``info["truncation"]``), no reset
inside the environment, everything an episode is in ``state.data`` (so Playground's
auto-reset to a cached first state restarts it whole), and the keys wrappers add to
``info`` and ``metrics`` kept across a step.

With ``privileged=True`` the observation is Playground's for an asymmetric critic,
``{"state": <the flat observation above>, "privileged_state": <the family's
obs_mode="state" vector>}`` (``observation_space`` a ``gymnasium.spaces.Dict`` of two
float32 ``Box`` es, ``observation_size`` their shapes by key): the policy reads what the
vehicle's sensors give, the critic the true state, which is known in simulation and
needed only in training. The episodes are the same as without it. Brax's PPO takes the
two keys::

    import functools
    from brax.training.agents.ppo import networks as ppo_networks

    env = auv_envs.batched.load("auv_envs/DockingStation-v2", obs_mode="features",
                                privileged=True)
    make_policy, params, metrics = ppo.train(
        environment=env, num_timesteps=1_000_000, episode_length=env.episode_length,
        wrap_env_fn=wrapper.wrap_for_brax_training,
        network_factory=functools.partial(ppo_networks.make_ppo_networks,
                                           policy_obs_key="state",
                                           value_obs_key="privileged_state"))
"""

from __future__ import annotations

from auv_envs.batched.functional import FunctionalEnv
from auv_envs.families import FAMILIES, family

#: Every id :func:`load` takes, a CPU id of :data:`auv_envs.families.FAMILIES` or its
#: batched twin, and the CPU id it means.
IDS = {**{entry.env_id: entry.env_id for entry in FAMILIES},
       **{entry.batched_id: entry.env_id for entry in FAMILIES}}


def load(env_id: str, privileged: bool = False, **env_kwargs) -> FunctionalEnv:
    """The functional environment of ``env_id`` under Playground's conventions.

    Args:
        env_id: a CPU id (``auv_envs/DockingStation-v2``, ``auv_envs/LampArrayDocking-v2``,
            ``auv_envs/DockingMission-v0``, ``auv_envs/LARSCapture-v0``,
            ``auv_envs/AcousticTracking-v2``) or its batched
            twin (``auv_envs/DockingStationMJX-v2``, ...).
        privileged: observations ``{"state": <the flat observation>, "privileged_state":
            <the family's obs_mode="state" vector, float32>}`` for an asymmetric critic
            (Brax's ``make_ppo_networks(..., policy_obs_key="state",
            value_obs_key="privileged_state")``; module docstring); False: the flat
            observation alone.
        **env_kwargs: the environment's arguments (``obs_mode``, ``difficulty``, ...), as
            the CPU env takes them.

    Raises:
        ValueError: an id without a batched twin (superseded versions included).
        TypeError: ``privileged`` is not a bool.
    """
    if env_id not in IDS:
        raise ValueError(f"no batched environment for {env_id!r}; load() takes "
                         f"{sorted(IDS)}")
    _register_with_playground()
    env = FunctionalEnv(family(env_id).env_id, privileged=privileged, **env_kwargs)
    return env.use_playground_conventions()


def _register_with_playground() -> None:
    """Make every batched env a (virtual) subclass of MuJoCo Playground's ``MjxEnv``,
    whose interface :class:`FunctionalEnv` implements, where Playground is installed
    (importing it only here: it takes seconds, and ``gym.make_vec`` does not need it)."""
    try:
        from mujoco_playground._src.mjx_env import MjxEnv
    except ImportError:
        return
    MjxEnv.register(FunctionalEnv)
