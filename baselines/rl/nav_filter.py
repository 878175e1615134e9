"""The docking mission on ``nav_features`` for a learner: the navigation filter as a front end.

A position exists in the ``nav`` sensors only by integrating them: the DVL's velocity
over time, corrected by the depth and by USBL fixes that arrive late and are sometimes
wrong (``docs/navigation.md``). ``nav-homing-ofnmpc-ekf`` does it with an error-state
Kalman filter written as pure functions of arrays
(:mod:`baselines.docking.estimation.navigation_filter`: the equations, their sources, and
the forms that hold in float32). This module makes that filter a learner's front end:
evaluated with NumPy on the CPU (:class:`NavFilter`, the Gymnasium wrapper a shipped agent
applies) and with ``jax.numpy`` under ``jit`` and ``vmap`` (:class:`NavFilterMJX`, around
the batched env the compiled PPO trains on): one definition for the pipeline, the learner
in training and the shipped learner.

The learner's observation is the ``nav_features`` ``Dict`` with three entries added:

* ``nav_position`` (3): the estimate of the CG position, station frame (m);
* ``nav_entrance`` (3): the entrance centre (the station frame's origin) from the
  estimate, in body axes (m): where to go, as the vehicle sees it;
* ``nav_log_std`` (3): the natural log of the estimate's standard deviation along each
  station axis (m; about ln 1000 before the first fix).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from baselines.docking.estimation.navigation_filter import (  # noqa: F401 (re-exported)
    FilterParams,
    FilterState,
    NavigationFilter,
    rotation,
    step,
)
from baselines.rl.batched_front_end import BatchedFrontEnd, FrontEnd
from baselines.rl.config import ConfigError

#: The entries the front end adds (name, length).
ADDED = (("nav_entrance", 3), ("nav_log_std", 3), ("nav_position", 3))


def params_of(env: gym.Env) -> FilterParams:
    """The parameters ``MissionAgent`` gives its filter, for ``env`` (a
    ``DockingMission-v0`` CPU env in ``nav_features`` mode, wrapped or not)."""
    base = env.unwrapped
    nav = getattr(base, "navigation", None)
    if getattr(base, "obs_mode", None) != "nav_features" or nav is None:
        raise ConfigError("the navigation filter needs a docking env with navigation "
                          "sensors in obs_mode='nav_features' (auv_envs/DockingMission-v0)")
    return NavigationFilter.for_suite(nav, base.calibration.control_period).params


def observation_space(space: spaces.Dict) -> spaces.Dict:
    """``space`` (the env's ``nav_features`` space) with the added entries."""
    added = {name: spaces.Box(-np.inf, np.inf, (n,), np.float32) for name, n in ADDED}
    return spaces.Dict({**space.spaces, **added})


def observe(state: FilterState, obs, xp=np) -> dict:
    """``obs`` with the entries of :data:`ADDED` from the filter ``state`` that took it (its
    latest entry holds the attitude's rotation)."""
    R = state.past_rotation[(state.head - 1) % state.past_rotation.shape[0]]
    std = xp.sqrt(xp.maximum(xp.diagonal(state.covariance), 1e-12))
    added = {"nav_entrance": R.T @ -state.position, "nav_log_std": xp.log(std),
             "nav_position": state.position}
    return {**obs, **{k: v.astype(xp.float32) for k, v in added.items()}}


class NavFilter(FrontEnd):
    """The ``nav_features`` observation with the navigation filter's estimate added (the
    module docstring), on the CPU with NumPy.

    ``nav_filter: true`` in a training config or a policy manifest applies it
    (:data:`baselines.rl.config.FRONT_ENDS`); the filter keeps the episode's state
    (:class:`~baselines.rl.batched_front_end.FrontEnd`).

    Raises:
        ConfigError: the environment is not ``DockingMission-v0`` in ``nav_features`` mode.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.params = params_of(env)
        self.observation_space = observation_space(env.observation_space)
        self.clear()

    def start(self) -> FilterState:
        return FilterState.start(self.params)

    def advance(self, carry: FilterState, obs) -> tuple:
        carry = step(self.params, carry, obs)
        return carry, observe(carry, obs)

    def position_estimate(self) -> np.ndarray | None:
        """The filter's estimate of the CG position (station frame, m), once a USBL fix
        has placed it (None before), as ``nav-homing-ofnmpc-ekf`` reports its own."""
        return self.state.position.copy() if int(self.state.fixes) else None


class NavFilterMJX(BatchedFrontEnd):
    """A batched ``DockingMission-v0`` (``nav_features``) whose observation is
    :class:`NavFilter`'s, computed in JAX by the same functions. The filter's state rides
    in ``state.info["nav_filter"]`` and starts afresh where an episode restarted
    (:class:`~baselines.rl.batched_front_end.BatchedFrontEnd`)."""

    INFO_KEY = "nav_filter"

    def __init__(self, env):
        super().__init__(env)
        self.params = params_of(env.cpu_env)
        self.observation_space = self.around(
            observation_space(env.cpu_env.observation_space))

    def start(self) -> FilterState:
        return FilterState.start(self.params, self._jnp)

    def advance(self, carry: FilterState, obs) -> tuple:
        carry = step(self.params, carry, obs, self._jnp)
        return carry, observe(carry, obs, self._jnp)
