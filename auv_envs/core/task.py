"""The task protocol every family's transition keeps, and the end of a step both shells share.

A family's transition (``auv_envs/tasks/<family>/transition.py``) is two functions of
one shape::

    reset(params, backend, ...) -> Transition
    step(params, plant, episode, action, backend) -> Transition

``params`` the family's static task, ``backend`` a :class:`~auv_envs.core.ops.Backend`
(the arithmetic, the episode's draws, the plant), ``plant`` and ``episode`` the last
:class:`Transition`'s. The plant is a function of its state: ``place(...)`` returns the
state of an episode's start, ``advance(plant, ...)`` (docking, LARS) or ``follow(plant,
...)`` (acoustic) the state a control period later; nothing the transition holds changes.
In the batched environments the plant's state is arrays (the free joint's ``qpos`` and
``qvel``, an MJX ``Data``); on the CPU it is the environment's MuJoCo ``MjData``, which
MuJoCo integrates in place: that is the one difference between the two, and it lives in
the CPU plants.

:func:`reward` and :func:`truncated` end a step the same way in the Gymnasium shell
(:class:`auv_envs.core.env.TaskEnv`) and the batched one
(:class:`auv_envs.batched.functional.FunctionalEnv`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple


class Transition(NamedTuple):
    """What a transition's ``reset`` and ``step`` return.

    Attributes:
        plant: the plant's state after the call (module docstring).
        episode: the family's ``EpisodeState`` (immutable: a JAX pytree as is).
        truth: the ground truth the step computed once (a dict), shared by the observation,
            the reward, the metrics and ``info``.
        obs: the observation of the task's ``obs_mode``.
        judged: the step's judgement (the family's ``Assessment``: ``terms``, the reward
            terms in the family's ``REWARD_TERMS`` order, and ``terminated``, success or
            failure); None at reset.
    """

    plant: Any
    episode: Any
    truth: dict
    obs: Any
    judged: Any = None


def reward(terms: dict):
    """The reward of a step: its ``terms`` summed in their order (the first term, then each
    next one added: Python floats and JAX arrays alike)."""
    values = iter(terms.values())
    total = next(values)
    for value in values:
        total = total + value
    return total


def truncated(terminated, steps, max_episode_steps: int, ops):
    """Whether a step ends its episode at the time limit: ``steps`` reached
    ``max_episode_steps`` without terminating (``ops``: :mod:`auv_envs.core.ops`'s)."""
    return ops.logical_not(terminated) & (steps >= max_episode_steps)


class Config:
    """A family's configuration (``auv_envs/tasks/<family>/config.py``): a frozen dataclass
    of everything that fixes the task, changed by :meth:`replace` only."""

    def replace(self, **changes):
        """This configuration with ``changes``.

        Raises:
            TypeError: a name that is not one of the configuration's fields.
        """
        names = [field.name for field in dataclasses.fields(self)]
        unknown = sorted(set(changes) - set(names))
        if unknown:
            raise TypeError(f"{type(self).__name__} has no field {', '.join(unknown)}; its "
                            f"fields are {names}")
        return dataclasses.replace(self, **changes)


@dataclasses.dataclass(frozen=True)
class Setup:
    """What a family's configuration fixes (its ``params(config)``), for the Gymnasium
    environment and the task on JAX alike; each family's setup adds its own fields.

    Attributes:
        config: the configuration it was built from.
        model_source: the composed MJCF of the model the physics simulates
            (:class:`~auv_envs.core.assets.MJCF`).
        model: its compiled MuJoCo model, the integrator and timestep set: a Gymnasium
            environment built from this setup simulates (and changes) this very model.
        calibration: what an agent may know.
        params: the transition's parameters.
        observation_space, action_space: the spaces.
        dt: the step period, s.
        max_episode_steps: steps of an episode that runs to its time limit.
    """

    config: Any
    model_source: Any
    model: Any
    calibration: Any
    params: Any
    observation_space: Any
    action_space: Any
    dt: float
    max_episode_steps: int

    @property
    def obs_mode(self) -> str:
        return self.config.obs_mode
