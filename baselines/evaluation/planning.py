"""What to run: check the names, resolve environment arguments, expand a request into tasks.

:func:`plan` expands environments x scenarios x agents x obs modes x seeds
into :class:`~baselines.evaluation.episodes.EpisodeTask` s and lists the
(env, agent) pairs it skips with the reason (the agent's own declaration,
:meth:`baselines.registry.AgentSpec.skip_reason`).
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym

import auv_envs
from baselines.evaluation.episodes import EpisodeTask, scenario_label, short_env_id
from baselines.parsing import parse_value
from baselines.registry import agent_names, agent_spec, unknown_agent_message


def env_parameters(env_id: str) -> tuple[str, ...]:
    """The named constructor arguments of environment ``env_id`` (``obs_mode`` excluded).

    Raises:
        KeyError: ``env_id`` is not registered with Gymnasium.
    """
    params = inspect.signature(auv_envs.task_class(env_id)).parameters.values()
    return tuple(p.name for p in params
                 if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name != "obs_mode")


def resolve_env_kwargs(env_ids: Sequence[str], assignments: Sequence[str],
                       defaults: Mapping[str, Mapping[str, Any]] | None = None,
                       ) -> dict[str, dict[str, Any]]:
    """Per-environment constructor arguments from ``[ENV:]KEY=VALUE`` strings.

    ``KEY=VALUE`` goes to every environment of ``env_ids`` whose constructor
    has ``KEY``; ``ENV:KEY=VALUE`` to one environment (full id or the part
    after ``auv_envs/``). ``defaults`` (env id -> kwargs) are applied first.
    Values are read by :func:`baselines.parsing.parse_value` (a Python
    literal, else a YAML scalar, else the bare string).

    Raises:
        ValueError: malformed text, an environment that is not selected, a
            key that no (or not that) environment accepts, or a key given twice
            for one environment.
    """
    params = {env_id: env_parameters(env_id) for env_id in env_ids}
    out = {env_id: dict((defaults or {}).get(env_id, {})) for env_id in env_ids}
    given: dict[tuple[str, str], str] = {}
    for text in assignments:
        target, sep, value = text.partition("=")
        env_part, colon, key = target.rpartition(":")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"environment arguments look like [ENV:]KEY=VALUE, got {text!r}")
        if colon:
            chosen = [e for e in env_ids if env_part in (e, short_env_id(e))]
            if not chosen:
                raise ValueError(f"{text!r}: {env_part!r} is not among the selected "
                                 f"environments ({', '.join(env_ids)})")
        else:
            chosen = [e for e in env_ids if key in params[e]]
        accepting = [e for e in chosen if key in params[e]]
        if not accepting:
            listing = "; ".join(f"{e}: {', '.join(params[e])}" for e in (chosen or env_ids))
            raise ValueError(f"{text!r}: no selected environment takes {key!r} ({listing})")
        for env_id in accepting:
            if (env_id, key) in given:
                raise ValueError(f"{text!r}: {key} is already set for {env_id} "
                                 f"({given[env_id, key]!r}); give it once")
            given[env_id, key] = text
            out[env_id][key] = parse_value(value.strip())
    return out


def check_names(env_ids: Sequence[str], agents: Sequence[str]) -> None:
    """Raise ``ValueError`` listing the valid names for unknown env ids or agent names."""
    unknown = [e for e in env_ids if e not in auv_envs.ENVIRONMENTS]
    if unknown:
        raise ValueError(f"unknown env id(s) {', '.join(unknown)}; "
                         f"registered: {', '.join(auv_envs.ENVIRONMENTS)}")
    known = agent_names()
    unknown = [a for a in agents if a not in known]
    if unknown:
        raise ValueError(unknown_agent_message(unknown))


def plan(
    env_ids: Sequence[str],
    agents: Sequence[str],
    seeds: Sequence[int],
    obs_modes: Sequence[str] | None = None,
    env_kwargs: Sequence[Mapping[str, Mapping[str, Any]]] = ({},),
) -> tuple[list[EpisodeTask], list[dict]]:
    """Tasks for every applicable (env, kwargs variant, agent, obs mode) and every seed.

    Args:
        obs_modes: modes to evaluate each agent in (those it supports); default:
            the agent's default mode for the environment.
        env_kwargs: variants (scenarios), each mapping env id -> constructor
            arguments; every variant is evaluated.

    Returns:
        ``(tasks, skipped)``; ``skipped`` holds dicts with ``env_id``,
        ``agent``, ``scenario`` and ``reason``.
    """
    check_names(env_ids, agents)
    tasks, skipped = [], []
    seen: set[tuple[str, tuple]] = set()
    for variant in env_kwargs:
        for env_id in env_ids:
            kwargs = tuple(sorted(dict(variant.get(env_id, {})).items()))
            if (env_id, kwargs) in seen:  # a variant that does not touch this env
                continue
            seen.add((env_id, kwargs))
            for name in agents:
                spec = agent_spec(name)
                reason = spec.skip_reason(env_id)
                modes = [m for m in spec.modes_for(env_id) if obs_modes is None or m in obs_modes]
                if reason is None and not modes:
                    reason = (f"acts on obs mode(s) {', '.join(spec.obs_modes)}; requested "
                              f"{', '.join(obs_modes or ())}")
                conflicts = [k for k, v in kwargs if k in spec.env_kwargs
                             and spec.env_kwargs[k] != v]
                if reason is None and conflicts:
                    reason = "needs " + ", ".join(f"{k}={spec.env_kwargs[k]}" for k in conflicts)
                if reason is not None:
                    skipped.append({"env_id": env_id, "agent": name, "scenario":
                                    scenario_label(dict(kwargs)), "reason": reason})
                    continue
                if obs_modes is None:
                    modes = modes[:1]
                tasks.extend(EpisodeTask(env_id, mode, name, int(seed), kwargs)
                             for mode in modes for seed in seeds)
    return tasks, skipped


def check_env_kwargs(tasks: Sequence[EpisodeTask]) -> None:
    """Build each distinct environment configuration once; a bad argument raises ``ValueError``."""
    for env_id, obs_mode, kwargs in dict.fromkeys((t.env_id, t.obs_mode, t.env_kwargs)
                                                  for t in tasks):
        try:
            gym.make(env_id, obs_mode=obs_mode, **dict(kwargs)).close()
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{env_id} rejects arguments {scenario_label(dict(kwargs))}: "
                             f"{exc}") from exc
