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

The lamps add what the navigation sensors cannot see: a heading read off the station's
frame (``hard``: 8 deg RMS) turns the filter's whole world about the transponder, and a
learner homing on it meets the entrance that far off the axis. The lights' heading filter
(:mod:`baselines.docking.estimation.light_heading`) learns the deviation from the detected
lamps; the navigation filter is turned back by each change of its estimate and reads the
heading with the estimate taken off, and so does the learner (its ``attitude``). Where
the level has no deviation (``easy``, ``paper``) the estimate stays 0 and nothing changes.

The learner's observation is the ``nav_features`` ``Dict``, its ``attitude`` corrected so,
with three entries added:

* ``nav_position`` (3): the estimate of the CG position, station frame (m);
* ``nav_entrance`` (3): the entrance centre (the station frame's origin) from the
  estimate, in body axes (m): where to go, as the vehicle sees it;
* ``nav_log_std`` (3): the natural log of the estimate's standard deviation along each
  station axis (m; about ln 1000 before the first fix).
"""

from __future__ import annotations

from typing import NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from baselines.docking.estimation import light_heading
from baselines.docking.estimation.light_heading import HeadingParams, HeadingState
from baselines.docking.estimation.navigation_filter import (  # noqa: F401 (re-exported)
    FilterParams,
    FilterState,
    NavigationFilter,
    rotation,
    step,
    turned,
)
from baselines.rl.batched_front_end import BatchedFrontEnd, FrontEnd
from baselines.rl.config import ConfigError

#: The entries the front end adds (name, length).
ADDED = (("nav_entrance", 3), ("nav_log_std", 3), ("nav_position", 3))


class Params(NamedTuple):
    """The front end's parameters: the navigation filter's and the lights' heading
    filter's."""

    nav: FilterParams
    heading: HeadingParams


class Carry(NamedTuple):
    """The front end between observations (a JAX pytree)."""

    nav: FilterState
    heading: HeadingState


def params_of(env: gym.Env) -> Params:
    """The parameters for ``env`` (a ``DockingMission-v0`` CPU env in ``nav_features``
    mode, wrapped or not, or the setup of one, :func:`auv_envs.tasks.docking.config.params`):
    those ``MissionAgent`` gives its filter, and the lights' heading
    filter's from the calibration and the navigation suite."""
    base = getattr(env, "unwrapped", env)
    nav = getattr(base, "navigation", None)
    if getattr(base, "obs_mode", None) != "nav_features" or nav is None:
        raise ConfigError("the navigation filter needs a docking env with navigation "
                          "sensors in obs_mode='nav_features' (auv_envs/DockingMission-v0)")
    return Params(NavigationFilter.for_suite(nav, base.calibration.control_period).params,
                  HeadingParams.of(base.calibration, nav))


def start(params: Params, xp=np) -> Carry:
    """The carry of a new episode."""
    return Carry(FilterState.start(params.nav, xp), HeadingState.start(params.heading, xp))


def advance(params: Params, carry: Carry, obs, xp=np) -> tuple:
    """One ``nav_features`` observation: the lights' heading filter takes it; the
    navigation filter's world is turned by the change of the heading's deviation (about
    the transponder) and takes the observation with the deviation taken off its heading.
    The next carry, and the learner's observation (:func:`observe`, whose ``attitude`` is
    the corrected one)."""
    if params.heading.deviation_var == 0.0:  # a level without a deviation: nothing to learn
        nav = step(params.nav, carry.nav, obs, xp)
        return Carry(nav, carry.heading), observe(nav, obs, xp)
    heading = light_heading.step(params.heading, carry.heading, obs, xp)
    change = heading.deviation - carry.heading.deviation
    nav = turned(carry.nav, -change, params.nav.transponder, xp)
    obs = {**obs, "attitude": light_heading.corrected_attitude(heading, obs["attitude"], xp)}
    nav = step(params.nav, nav, obs, xp)
    return Carry(nav, heading), observe(nav, obs, xp)


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

    def start(self) -> Carry:
        return start(self.params)

    def advance(self, carry: Carry, obs) -> tuple:
        return advance(self.params, carry, obs)

    def position_estimate(self) -> np.ndarray | None:
        """The filter's estimate of the CG position (station frame, m), once a USBL fix
        has placed it (None before), as ``nav-homing-ofnmpc-ekf`` reports its own."""
        nav = self.state.nav
        return nav.position.copy() if int(nav.fixes) else None


class NavFilterMJX(BatchedFrontEnd):
    """A batched ``DockingMission-v0`` (``nav_features``) whose observation is
    :class:`NavFilter`'s, computed in JAX by the same functions. The filter's state rides
    in ``state.info["nav_filter"]`` and starts afresh where an episode restarted
    (:class:`~baselines.rl.batched_front_end.BatchedFrontEnd`)."""

    INFO_KEY = "nav_filter"

    def __init__(self, env):
        super().__init__(env)
        self.params = params_of(env.task.setup)
        self.observation_space = self.around(
            observation_space(env.task.observation_space))

    def start(self) -> Carry:
        return start(self.params, self._jnp)

    def advance(self, carry: Carry, obs) -> tuple:
        return advance(self.params, carry, obs, self._jnp)
