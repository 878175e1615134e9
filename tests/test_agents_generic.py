"""Registry-driven agent tests: every agent, on every env id and obs mode it declares.

Each case is a short seeded episode (a few steps) that checks the agent
protocol shared by all baselines: actions inside the action space and finite,
the same seed giving the same actions, ``stats()`` a dict of numbers (or labels) and
``position_estimate()`` ``None`` or a finite (3,) array. Agents and
environments are found only through ``baselines.registry`` and ``auv_envs``.
"""

from __future__ import annotations

import inspect
import math
from numbers import Real

import gymnasium as gym
import numpy as np
import pytest

from baselines.catalogue import builtin_specs
from baselines.registry import agent_names, agent_spec, make_agent
from tests.conftest import ENV_IDS, IMAGE_MODES, make_env, obs_modes, task_class

#: Seconds of simulated time per test episode: a guard, so that an episode
#: ends early even if an agent never terminates it (the tests take fewer steps).
SHORT_TIME_LIMIT = 1.0
SEED = 3

CASES = [
    (name, env_id, mode)
    for name in agent_names()
    for env_id in ENV_IDS
    for mode in agent_spec(name).modes_for(env_id)
]
CASE_IDS = [f"{name}-{env_id.split('/')[1]}-{mode}" for name, env_id, mode in CASES]


def _n_steps(name: str, mode: str) -> int:
    """Few steps: fewer for agents that cost a lot per step or render images."""
    return 2 if agent_spec(name).heavy or mode in IMAGE_MODES else 4


def _make_env(name: str, env_id: str, mode: str) -> gym.Env:
    kwargs = dict(agent_spec(name).env_kwargs)
    if "time_limit" in inspect.signature(task_class(env_id)).parameters:
        kwargs.setdefault("time_limit", SHORT_TIME_LIMIT)
    return make_env(env_id, mode, **kwargs)


def _assert_stats(stats) -> None:
    """A dict of real numbers, none infinite, besides labels (strings, e.g. a phase name).

    NaN is allowed: it is how an agent says a statistic has no sample yet (a mean
    solve time before the first solve, a period before the first fit); the evaluation
    writes it as ``None`` and leaves labels out.
    """
    assert isinstance(stats, dict), f"stats() returned {type(stats).__name__}, not a dict"
    for key, value in stats.items():
        assert isinstance(key, str)
        if isinstance(value, str):
            continue
        assert isinstance(value, Real | np.number) and not isinstance(value, bool | np.bool_), (
            f"stats()[{key!r}] = {value!r} is neither a number nor a label"
        )
        assert not math.isinf(float(value)), f"stats()[{key!r}] = {value!r} is infinite"


def _assert_in_box(space: gym.Space, action, name: str) -> None:
    """``action`` has the space's shape, finite values inside its bounds (any float dtype:
    the environments take float64 actions as well as float32)."""
    arr = np.asarray(action, dtype=np.float64)
    assert np.all(np.isfinite(arr)), f"{name}: non-finite action {arr}"
    if isinstance(space, gym.spaces.Box):
        assert arr.shape == space.shape, f"{name}: action shape {arr.shape} != {space.shape}"
        assert np.all(arr >= space.low) and np.all(arr <= space.high), (
            f"{name}: action {arr} outside [{space.low}, {space.high}]"
        )
    else:
        assert space.contains(action), f"{name}: action {action!r} outside {space}"


def _assert_estimate(estimate) -> None:
    if estimate is None:
        return
    arr = np.asarray(estimate, dtype=np.float64)
    assert arr.shape == (3,), f"position_estimate() has shape {arr.shape}, not (3,)"
    assert np.all(np.isfinite(arr)), f"position_estimate() = {arr} is not finite"


def _episode(name: str, env_id: str, mode: str, seed: int) -> list[np.ndarray]:
    """The actions of a short seeded episode, checking the protocol on every step."""
    env = _make_env(name, env_id, mode)
    try:
        agent = make_agent(name, env)
        obs, info = env.reset(seed=seed)
        agent.reset(seed)
        estimate = getattr(agent, "position_estimate", None)
        actions = []
        for _ in range(_n_steps(name, mode)):
            action = agent.act(obs, info)
            _assert_in_box(env.action_space, action, name)
            actions.append(np.array(action, copy=True))
            if callable(estimate):
                _assert_estimate(estimate())
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        if callable(getattr(agent, "stats", None)):
            _assert_stats(agent.stats())
        return actions
    finally:
        env.close()


@pytest.mark.parametrize(("name", "env_id", "mode"), CASES, ids=CASE_IDS)
def test_agent_short_episode_is_valid_and_seeded(name, env_id, mode):
    first = _episode(name, env_id, mode, SEED)
    assert first, f"{name} took no step"
    second = _episode(name, env_id, mode, SEED)
    assert len(first) == len(second)
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)


def test_every_builtin_agent_applies_somewhere():
    # The catalogue's agents, not agent_names(): other tests register agents of their own.
    assert {spec.name for spec in builtin_specs()} <= {name for name, _, _ in CASES}


def _misuses(name: str) -> list[tuple[str, str]]:
    """(env id, obs mode) pairs the agent does not apply to: one env id outside its
    ``env_ids`` (in a mode that env offers) and one mode it does not declare on an env
    it does apply to, where such pairs exist."""
    spec = agent_spec(name)
    out = []
    outside = [e for e in ENV_IDS if not spec.modes_for(e)]
    if outside:
        out.append((outside[0], obs_modes(outside[0])[0]))
    for env_id in ENV_IDS:
        other = [m for m in obs_modes(env_id) if spec.modes_for(env_id)
                 and m not in spec.obs_modes and m not in IMAGE_MODES]
        if other:
            out.append((env_id, other[0]))
            break
    return out


MISUSES = [(name, env_id, mode) for name in agent_names() for env_id, mode in _misuses(name)]


@pytest.mark.parametrize(("name", "env_id", "mode"), MISUSES,
                         ids=[f"{n}-{e.split('/')[1]}-{m}" for n, e, m in MISUSES])
def test_make_agent_rejects_an_env_or_mode_it_does_not_apply_to(name, env_id, mode):
    # The registry refuses before the factory runs, naming the agent and the environment
    # (a factory alone may build silently or fail with an AttributeError).
    spec = agent_spec(name)
    # The spec's env kwargs are arguments of the envs it applies to, not of the others.
    env = make_env(env_id, mode, **(spec.env_kwargs if spec.modes_for(env_id) else {}))
    try:
        with pytest.raises(ValueError) as raised:
            make_agent(name, env)
        assert name in str(raised.value) and env_id in str(raised.value)
    finally:
        env.close()
