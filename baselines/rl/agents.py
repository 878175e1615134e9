"""Shipped RL policies as registered agents.

Every directory ``assets/policies/<name>/`` with a ``policy.json`` (written by
``train.py --export-policy <name>``) becomes the agent ``<name>`` for the
environment and observation mode it was trained on. Registration reads only
the manifest; the model files are checked (SHA-256) and loaded when the agent
is built, and a missing or corrupt file raises
:class:`baselines.rl.policy.PolicyFileError` naming it.
"""

from __future__ import annotations

import functools
from pathlib import Path

from baselines.registry import AgentSpec, register_agent
from baselines.rl.policy import PolicyAgent, policies_root, read_manifest


def policy_directories(root: Path | None = None) -> list[Path]:
    """Policy directories under ``root`` (default: ``assets/policies``), sorted by name."""
    root = Path(root) if root is not None else policies_root()
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))


def load_policy_agent(directory: str | Path, env) -> PolicyAgent:
    """The agent of policy ``directory`` acting in ``env``."""
    return PolicyAgent.from_directory(env, directory)


def policy_spec(directory: Path) -> AgentSpec:
    """The registry entry of one policy directory (reads its manifest only)."""
    manifest = read_manifest(directory)
    return AgentSpec(
        name=directory.name,
        factory=functools.partial(load_policy_agent, directory),
        obs_mode=manifest["obs_mode"],
        env_ids=(manifest["env_id"],),
        description=manifest.get("description")
        or f"{manifest['algo'].upper()} policy on {manifest['obs_mode']}",
    )


def register_policies(root: Path | None = None) -> list[str]:
    """Register every policy under ``root``; returns their names."""
    names = []
    for directory in policy_directories(root):
        register_agent(policy_spec(directory))
        names.append(directory.name)
    return names


SHIPPED = register_policies()
