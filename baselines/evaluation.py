"""Run agents on environments over fixed seeds and summarise their metrics.

``evaluate.py`` is a thin command line over :func:`evaluate` and
:func:`summarise`; tests import these directly.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np

import auv_envs
from baselines.registry import agent_names, agent_spec, make_agent

#: Evaluation seeds start here; training seeds (train.py) stay below it, so the
#: two sets never overlap.
EVAL_SEED_BASE = 100_000


@dataclasses.dataclass(frozen=True)
class EpisodeRow:
    """One evaluated episode (one row of the JSON output)."""

    env_id: str
    agent: str
    seed: int
    obs_mode: str
    scenario: str
    episode_return: float
    length: int
    success: bool
    failure_reason: str
    metrics: dict
    wall_time_s: float


def parse_seeds(text: str) -> list[int]:
    """``"A-B"`` (inclusive) or ``"A,B,C"`` -> list of seeds."""
    try:
        if "-" in text.strip("-"):
            first, last = (int(x) for x in text.split("-", 1))
            if last < first:
                raise ValueError
            return list(range(first, last + 1))
        return [int(x) for x in text.split(",")]
    except ValueError as exc:
        raise ValueError(f"seeds must look like 'A-B' or 'A,B,C', got {text!r}") from exc


def default_seeds(episodes: int) -> list[int]:
    if episodes <= 0:
        raise ValueError(f"episodes must be positive, got {episodes}")
    return list(range(EVAL_SEED_BASE, EVAL_SEED_BASE + episodes))


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (np.floating, float)):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, np.ndarray):
        return [_jsonable(v) for v in value.tolist()]
    return value


def run_episode(env: gym.Env, agent, seed: int, env_id: str, agent_name: str) -> EpisodeRow:
    """One seeded episode of ``agent`` in ``env``."""
    start = time.perf_counter()
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    total, length, done = 0.0, 0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(agent.act(obs, info))
        total += float(reward)
        length += 1
        done = terminated or truncated
    metrics = _jsonable(info.get("episode_metrics", {}))
    unwrapped = env.unwrapped
    return EpisodeRow(
        env_id=env_id,
        agent=agent_name,
        seed=int(seed),
        obs_mode=getattr(unwrapped, "obs_mode", ""),
        scenario=getattr(unwrapped, "scenario", ""),
        episode_return=total,
        length=length,
        success=bool(info.get("is_success", False)),
        failure_reason=str(metrics.get("failure_reason", "")),
        metrics=metrics,
        wall_time_s=time.perf_counter() - start,
    )


def evaluate(
    env_ids: Sequence[str] | None = None,
    agents: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    env_kwargs: dict | None = None,
) -> list[EpisodeRow]:
    """Every applicable (env, agent) pair on every seed.

    Args:
        env_ids: registered ids (default: all of ``auv_envs.ENVIRONMENTS``).
        agents: agent names (default: all registered).
        seeds: evaluation seeds (default: 3 from :data:`EVAL_SEED_BASE`).
        env_kwargs: extra constructor arguments for every env (e.g. scenario).
    """
    env_ids = list(env_ids or auv_envs.ENVIRONMENTS)
    agents = list(agents or agent_names())
    seeds = list(seeds if seeds is not None else default_seeds(3))
    unknown = [e for e in env_ids if e not in auv_envs.ENVIRONMENTS]
    if unknown:
        raise ValueError(
            f"unknown env id(s) {unknown}; registered: {', '.join(auv_envs.ENVIRONMENTS)}"
        )
    rows = []
    for env_id in env_ids:
        for name in agents:
            spec = agent_spec(name)
            if not spec.applies_to(env_id):
                continue
            env = gym.make(env_id, obs_mode=spec.obs_mode, **(env_kwargs or {}))
            try:
                agent = make_agent(name, env)
                rows.extend(run_episode(env, agent, s, env_id, name) for s in seeds)
            finally:
                env.close()
    return rows


#: Per-task headline metrics shown in the table (means over episodes), in order.
HEADLINE_METRICS = {
    "docking_time": ("docking time s", ".1f"),
    "final_distance": ("final distance m", ".2f"),
    "final_capture_error": ("capture error m", ".3f"),
    "rmse": ("RMSE m", ".3f"),
    "max_error": ("max error m", ".3f"),
    "tfc": ("TFC", ".1f"),
    "tcfe": ("TCFE", ".3f"),
}


def summarise(rows: Sequence[EpisodeRow]) -> list[dict]:
    """Aggregate rows per (env, agent): success rate, return, length and metric means.

    ``metrics`` maps every numeric episode metric to its mean over the
    episodes that report it (``docking_time`` only exists on success, so its
    mean is over successful episodes).
    """
    groups: dict[tuple[str, str], list[EpisodeRow]] = {}
    for row in rows:
        groups.setdefault((row.env_id, row.agent), []).append(row)
    summary = []
    for (env_id, agent), items in groups.items():
        values: dict[str, list[float]] = {}
        for r in items:
            for key, value in r.metrics.items():
                if isinstance(value, bool) or not isinstance(value, int | float):
                    continue
                if math.isfinite(value):
                    values.setdefault(key, []).append(float(value))
        summary.append(
            {
                "env_id": env_id,
                "agent": agent,
                "episodes": len(items),
                "success_rate": float(np.mean([r.success for r in items])),
                "mean_return": float(np.mean([r.episode_return for r in items])),
                "std_return": float(np.std([r.episode_return for r in items])),
                "mean_length": float(np.mean([r.length for r in items])),
                "metrics": {k: float(np.mean(v)) for k, v in values.items()},
            }
        )
    return summary


def format_table(summary: Sequence[dict]) -> str:
    """A Markdown table of :func:`summarise` output with each task's headline metrics."""
    lines = [
        "| env | agent | episodes | success | return (mean ± std) | steps | headline metrics |",
        "|" + "---|" * 7,
    ]
    for s in summary:
        shown = [
            f"{label} {format(s['metrics'][key], spec)}"
            for key, (label, spec) in HEADLINE_METRICS.items()
            if key in s["metrics"]
        ]
        lines.append(
            f"| {s['env_id']} | {s['agent']} | {s['episodes']} | {s['success_rate']:.0%} "
            f"| {s['mean_return']:.2f} ± {s['std_return']:.2f} | {s['mean_length']:.0f} "
            f"| {'; '.join(shown) or '–'} |"
        )
    return "\n".join(lines)


def write_results(rows: Sequence[EpisodeRow], out_dir: str | Path) -> Path:
    """Write ``rows.json`` and ``summary.json`` under ``out_dir``; returns the directory."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    payload = [_jsonable(dataclasses.asdict(r)) for r in rows]
    (out / "rows.json").write_text(json.dumps(payload, indent=2))
    (out / "summary.json").write_text(json.dumps(_jsonable(summarise(rows)), indent=2))
    return out
