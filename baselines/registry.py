"""Name -> agent factory.

Every agent keeps one protocol: ``reset(seed)`` then ``act(observation, info)
-> action``. A factory takes the (unwrapped) environment it will act in, so it
can read the documented calibration, never MuJoCo internals.

An :class:`AgentSpec` declares where its agent applies: the environment ids
(``env_ids``) and the observation modes it can act on (``obs_mode`` first,
then any others in ``obs_modes``). :meth:`AgentSpec.skip_reason` tells the
leaderboard why a pair is skipped; it reads the environment's declared
``obs_modes`` class attribute (the contract of every ``auv_envs`` task).

The registry declares no agent itself: :mod:`baselines.catalogue` registers
the built-in ones (through :func:`register_source`), and importing the
``baselines`` package imports the catalogue, so every lookup sees them.

Optional agent methods that the evaluation reads (see
``baselines.evaluation.run_episode``): ``position_estimate()`` -> a (3,)
world-frame estimate of the target or ``None``, and ``stats()`` -> a dict of
numbers for the episode.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

import auv_envs


class Agent(Protocol):
    def reset(self, seed: int | None = None) -> None: ...

    def act(self, observation, info: dict) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """How to build an agent and where it applies.

    Attributes:
        name: registry key.
        factory: ``factory(env) -> Agent`` with ``env`` the unwrapped env.
        obs_mode: the observation mode the agent uses by default.
        env_ids: environment ids it applies to (``None``: all).
        description: one line for tables and ``--help``.
        obs_modes: every observation mode the agent can act on; ``obs_mode``
            is put first and added when missing (default: ``obs_mode`` only).
        env_kwargs: constructor arguments the agent's environment must be
            built with (e.g. ``{"control": "position"}``); default none.
        group: the name of the agent this one is a training seed of (e.g.
            ``ppo-docking-features`` for ``ppo-docking-features-s1``): the
            leaderboard pools a group's episodes into one row and lists its
            seeds one by one; default none.
        heavy: an episode costs about a minute or more on two cores (e.g. a
            front end on every rendered camera image): the default
            leaderboard run leaves the agent out and says so
            (``--all-agents`` or ``--agents`` runs it).
    """

    name: str
    factory: Callable[[gym.Env], Agent]
    obs_mode: str
    env_ids: tuple[str, ...] | None
    description: str
    obs_modes: tuple[str, ...] = ()
    env_kwargs: Mapping[str, Any] = dataclasses.field(default_factory=dict, hash=False)
    group: str | None = None
    heavy: bool = False

    def __post_init__(self):
        modes = (self.obs_mode, *self.obs_modes)
        if not all(isinstance(m, str) and m for m in modes):
            raise ValueError(f"agent {self.name!r}: obs modes must be non-empty strings, "
                             f"got {modes!r}")
        if self.env_ids is not None:
            if isinstance(self.env_ids, str) or not all(isinstance(e, str) for e in self.env_ids):
                raise ValueError(f"agent {self.name!r}: env_ids must be a tuple of ids or None, "
                                 f"got {self.env_ids!r}")
            object.__setattr__(self, "env_ids", tuple(self.env_ids))
        # Frozen: normalise once (default mode first, no repeats; a private kwargs copy).
        object.__setattr__(self, "obs_modes", tuple(dict.fromkeys(modes)))
        object.__setattr__(self, "env_kwargs", dict(self.env_kwargs))

    def skip_reason(self, env_id: str, obs_mode: str | None = None) -> str | None:
        """Why the agent does not apply to ``env_id`` (in ``obs_mode``); ``None`` if it does.

        Args:
            env_id: a registered environment id.
            obs_mode: one mode to ask about (default: any mode the agent supports).
        """
        if self.env_ids is not None and env_id not in self.env_ids:
            return f"supports only {', '.join(self.env_ids) or 'no environment'}"
        if obs_mode is not None and obs_mode not in self.obs_modes:
            return f"acts on obs mode(s) {', '.join(self.obs_modes)}, not {obs_mode}"
        offered = env_obs_modes(env_id)
        if offered is not None and not any(m in offered for m in self.obs_modes):
            return (f"needs obs mode(s) {', '.join(self.obs_modes)}; "
                    f"{env_id} offers {', '.join(offered)}")
        if obs_mode is not None and offered is not None and obs_mode not in offered:
            return f"{env_id} does not offer obs mode {obs_mode}"
        return None

    def modes_for(self, env_id: str) -> tuple[str, ...]:
        """The agent's modes that ``env_id`` offers, default first (empty if it does not apply)."""
        if self.env_ids is not None and env_id not in self.env_ids:
            return ()
        offered = env_obs_modes(env_id)
        return tuple(m for m in self.obs_modes if offered is None or m in offered)

    def applies_to(self, env_id: str) -> bool:
        return self.skip_reason(env_id) is None


def env_obs_modes(env_id: str) -> tuple[str, ...] | None:
    """The observation modes environment ``env_id`` declares (``None``: not declared).

    Raises:
        KeyError: ``env_id`` is not registered with Gymnasium.
    """
    modes = getattr(auv_envs.task_class(env_id), "obs_modes", None)
    return tuple(modes) if modes else None


_REGISTRY: dict[str, AgentSpec] = {}
#: Sources of agents not registered yet (:func:`register_source`), oldest first.
_SOURCES: list[Callable[[], Iterable[AgentSpec]]] = []


def register_agent(spec: AgentSpec) -> None:
    """Add an agent (a catalogue entry, a policy file, a test's agent); names are unique."""
    _register_sources()
    _add(spec)


def register_source(source: Callable[[], Iterable[AgentSpec]]) -> None:
    """Register the agents ``source()`` returns before the registry is next read or added to.

    For declarations that cost something to make (:mod:`baselines.catalogue`
    reads the shipped policies' manifests): they are paid for only by a process
    that asks for an agent, and still come before any agent added later.
    """
    _SOURCES.append(source)


def _add(spec: AgentSpec) -> None:
    if spec.name in _REGISTRY:
        raise ValueError(f"agent {spec.name!r} is already registered")
    _REGISTRY[spec.name] = spec


def _register_sources() -> None:
    while _SOURCES:
        # Taken off first: a source that fails is not retried on every lookup.
        source = _SOURCES.pop(0)
        for spec in source():
            _add(spec)


def agent_spec(name: str) -> AgentSpec:
    """The spec of agent ``name``; a group's name (training seeds pooled) gives its first
    member's, the one a single episode (a clip, a dataset) is played by.

    Raises:
        KeyError: no agent or group is called ``name`` (the closest names suggested).
    """
    _register_sources()
    if name in _REGISTRY:
        return _REGISTRY[name]
    members = group_members(name)
    if members:
        return _REGISTRY[members[0]]
    raise KeyError(unknown_agent_message([name]))


def group_members(name: str) -> list[str]:
    """The agents pooled under group ``name`` (its training seeds), sorted; [] if none."""
    return sorted(agent for agent, group in agent_groups().items() if group == name)


def unknown_agent_message(unknown: Sequence[str]) -> str:
    """``unknown agent(s) ...`` with the closest registered agent or group names to each."""
    names = sorted({*agent_names(), *agent_groups().values()})
    hints = []
    for name in unknown:
        close = difflib.get_close_matches(name, names, n=3, cutoff=0.6)
        hints.append(f"{name!r}" + (f" (did you mean {', '.join(close)}?)" if close else ""))
    return (f"unknown agent(s) {', '.join(hints)}; `python evaluate.py --list` lists every "
            f"agent and group")


def resolve_agent_names(names: Sequence[str]) -> list[str]:
    """Agent names with each group's name replaced by its members (in order, once each).

    Raises:
        ValueError: a name that is neither an agent nor a group (closest matches named).
    """
    known = set(agent_names())
    out, unknown = [], []
    for name in names:
        members = [name] if name in known else group_members(name)
        if not members:
            unknown.append(name)
        out.extend(members)
    if unknown:
        raise ValueError(unknown_agent_message(unknown))
    return list(dict.fromkeys(out))


def agent_groups() -> dict[str, str]:
    """Agent name -> its group, for the agents that belong to one (``AgentSpec.group``)."""
    _register_sources()
    return {name: spec.group for name, spec in _REGISTRY.items() if spec.group}


def agent_names() -> list[str]:
    _register_sources()
    return sorted(_REGISTRY)


def make_agent(name: str, env: gym.Env) -> Agent:
    """Build agent ``name`` for ``env`` (wrapped or not).

    Raises:
        KeyError: no agent is called ``name``.
        ValueError: the agent does not apply to the environment (its id, when
            it was made with ``gym.make``) or to its ``obs_mode``
            (:meth:`AgentSpec.skip_reason`).
    """
    spec = agent_spec(name)
    unwrapped = env.unwrapped
    obs_mode = getattr(unwrapped, "obs_mode", None)
    env_id = unwrapped.spec.id if unwrapped.spec is not None else None
    where = env_id or type(unwrapped).__name__
    reason = spec.skip_reason(env_id) if env_id is not None else None
    if reason is None and obs_mode is not None and obs_mode not in spec.obs_modes:
        needed = " or ".join(f"obs_mode={mode!r}" for mode in spec.obs_modes)
        reason = f"it needs {needed}, got obs_mode={obs_mode!r}"
    if reason is not None:
        raise ValueError(f"agent {name!r} does not apply to {where}: {reason}")
    return spec.factory(unwrapped)


@dataclasses.dataclass(frozen=True)
class LazyFactory:
    """``factory(env)``: import ``target`` (``"module:attribute[.attribute]"``) when first
    called, then ``target(env, **kwargs)``. Picklable (strings only), so a spec travels
    to worker processes; the import happens where the agent is built."""

    target: str
    kwargs: Mapping[str, Any] = dataclasses.field(default_factory=dict, hash=False)

    def resolve(self) -> Callable:
        module_name, _, attributes = self.target.partition(":")
        if not attributes:
            raise ValueError(f"factory {self.target!r} must be 'module:attribute'")
        value = importlib.import_module(module_name)
        for attribute in attributes.split("."):
            value = getattr(value, attribute)
        return value

    def __call__(self, env: gym.Env) -> Agent:
        return self.resolve()(env, **self.kwargs)


def lazy(target: str, **kwargs) -> LazyFactory:
    """A factory that imports ``target`` (``"module:attribute"``) only when an agent is built."""
    return LazyFactory(target, dict(kwargs))


def env_ids_of(module: str) -> tuple[str, ...]:
    """Every registered environment id whose entry point is a class of ``module``."""
    ids = tuple(env_id for env_id, entry_point in auv_envs.ENVIRONMENTS.items()
                if entry_point.partition(":")[0] == module)
    if not ids:
        raise ValueError(f"no environment is registered from module {module!r}")
    return ids
