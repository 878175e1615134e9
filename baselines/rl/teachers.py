"""Privileged teachers for distillation on the batched environments.

A teacher reads the privileged state (the family's ``state`` observation, which the
batched env gives as ``obs["privileged_state"]`` when built with ``privileged=True``)
and answers the action a student should have taken, in the unit action box [-1, 1] the
compiled trainer acts in. The compiled PPO's distillation (``teacher:`` in ``cppo.yml``,
:class:`baselines.rl.compiled.Trainer`) asks it at every step the student visits
(DAgger) and fits the student, which reads only the non-privileged observation.

A teacher is an object with two pure functions over a batch, so that it runs inside the
compiled rollout:

* ``init(n)``: its memory for ``n`` environments (a pytree; None when it has none);
* ``act(memory, privileged, starts) -> (actions (n, A), memory)``: ``privileged`` the
  batch's privileged states ``(n, P)``, ``starts`` where an episode begins at this step
  (a teacher with a memory clears it there).

:data:`TEACHERS` names them; each refuses an environment it cannot teach.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from baselines.docking.control.homing import (
    CORRIDOR_WIDTH,
    HomingGains,
    corridor_action,
    homing_action,
)
from baselines.docking.control.pd import PDGains, pd_action
from baselines.rl.config import ConfigError


class MemorylessTeacher:
    """A teacher whose answer depends on the present privileged state alone: no memory,
    ``act`` is :meth:`answer` on the batch."""

    @staticmethod
    def init(n: int):
        del n
        return None

    def act(self, memory, privileged, starts):
        del starts
        return self.answer(privileged), memory

    def answer(self, privileged):
        raise NotImplementedError


class TruthTeacher(MemorylessTeacher):
    """Acoustic tracking's oracle: the estimate is the end effector's true position,
    the first three entries of the ``state`` observation (the tank frame, the action's),
    mapped into the unit box as the batched env maps unit actions onto the tank."""

    def __init__(self, env):
        from auv_envs.tasks.acoustic.jax_task import AcousticJax

        base = getattr(env, "env", env)  # a front end's or itself
        if not isinstance(getattr(base, "task", None), AcousticJax):
            raise ConfigError(f"the truth teacher teaches acoustic tracking, not "
                              f"{type(env).__name__}")
        box = env._action_box
        if box is None:
            raise ConfigError("the truth teacher answers unit actions: the env must take "
                              "actions in [-1, 1] (use_unit_actions)")
        self._low = jnp.asarray(box.low, jnp.float32)
        self._span = jnp.asarray(np.asarray(box.high) - np.asarray(box.low), jnp.float32)

    def answer(self, privileged):
        position = privileged[:, :3]
        return jnp.clip(2.0 * (position - self._low) / self._span - 1.0, -1.0, 1.0)


def _thrust_gains(env, name: str, env_ids: tuple[str, ...], gains_type):
    """The float32 gains (``gains_type.from_calibration``) of a docking teacher ``name``
    on ``env``, which must be one of ``env_ids`` and take the normalised thrust in
    [-1, 1]."""
    env_id = getattr(env, "env_id", None)
    if env_id not in env_ids:
        raise ConfigError(f"the {name} teacher teaches {' and '.join(env_ids)}, not "
                          f"{env_id or type(env).__name__}")
    if env._action_box is None or not np.allclose(env._action_box.low, -1.0) \
            or not np.allclose(env._action_box.high, 1.0):
        raise ConfigError(f"the {name} teacher answers the normalised thrust in [-1, 1]")
    return jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float32),
                                  gains_type.from_calibration(env.calibration))


class PDTeacher(MemorylessTeacher):
    """``pd-state`` (:func:`baselines.docking.control.pd.pd_action`) on the docking
    stations: the PD law towards the docking point from the true state."""

    ENV_IDS = ("auv_envs/DockingStation-v2", "auv_envs/LampArrayDocking-v2")

    def __init__(self, env):
        gains = _thrust_gains(env, "pd", self.ENV_IDS, PDGains)
        self.answer = jax.vmap(functools.partial(pd_action, gains, xp=jnp))


class HomingTeacher:
    """``homing-pd-state`` (:mod:`baselines.docking.control.homing`) on the whole approach:
    line-of-sight homing to the staging point, then the PD terminal controller, from the
    true state; its memory is the hand-over latch of each environment, cleared where an
    episode begins."""

    def __init__(self, env):
        gains = _thrust_gains(env, "homing-pd", ("auv_envs/DockingMission-v0",), HomingGains)
        self._gains = gains
        self._act = jax.vmap(functools.partial(homing_action, gains, xp=jnp))

    @staticmethod
    def init(n: int) -> jax.Array:
        return jnp.zeros(n, bool)

    def act(self, memory, privileged, starts):
        return self._act(privileged, memory & jnp.logical_not(starts))


class CorridorHomingTeacher(MemorylessTeacher, HomingTeacher):
    """``homing-pd``'s laws with a hand-over the state decides
    (:func:`~baselines.docking.control.homing.in_corridor`): the terminal law within
    :data:`CORRIDOR_WIDTH` m of the docking axis from the staging point into the funnel,
    homing elsewhere. It has no memory, so its student need not infer a latch
    that the teacher set long before."""

    #: The corridor's half-width (m): twice the staging point's capture distance.
    CORRIDOR_WIDTH = CORRIDOR_WIDTH

    def __init__(self, env):
        HomingTeacher.__init__(self, env)
        self.answer = jax.vmap(functools.partial(corridor_action, self._gains, xp=jnp,
                                                 width=self.CORRIDOR_WIDTH))


#: Teacher name -> its class (built on the batched env; it refuses an env it cannot teach).
TEACHERS = {
    "homing-pd": HomingTeacher,
    "homing-pd-corridor": CorridorHomingTeacher,
    "pd": PDTeacher,
    "truth": TruthTeacher,
}


def make_teacher(name: str, env):
    """The teacher ``name`` of :data:`TEACHERS` for the batched ``env``.

    Raises:
        ConfigError: an unknown name, or an env the teacher cannot teach.
    """
    if name not in TEACHERS:
        raise ConfigError(f"unknown teacher {name!r}; teachers: {', '.join(sorted(TEACHERS))}")
    return TEACHERS[name](env)


__all__ = ["TEACHERS", "CorridorHomingTeacher", "HomingTeacher", "PDTeacher", "TruthTeacher",
           "make_teacher"]
