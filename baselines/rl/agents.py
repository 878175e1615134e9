"""Shipped RL policies as registered agents.

Every directory ``assets/policies/<name>/`` with a ``policy.json`` (written by
``train.py --export-policy <name>``) becomes the agent ``<name>`` for the
environment and observation mode it was trained on. Registration reads only
the manifest (:mod:`baselines.rl.manifest`: no Stable-Baselines3, no torch);
the model files are checked (SHA-256) and loaded when the agent is built, and
a missing or corrupt file raises :class:`~baselines.rl.manifest.PolicyFileError`
naming it.

Policies outside the package (``evaluate.py --policy PATH``: an exported
policy or a ``train.py`` run directory) register under
:func:`external_policy_name` through :func:`register_external_policy`.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING

from baselines.registry import AgentSpec, agent_names, register_agent
from baselines.rl.manifest import MANIFEST_FILE, PolicyFileError, policies_root, read_manifest

if TYPE_CHECKING:
    from baselines.rl.policy import PolicyAgent


def policy_directories(root: Path | None = None) -> list[Path]:
    """Policy directories under ``root`` (default: ``assets/policies``), sorted by name."""
    root = Path(root) if root is not None else policies_root()
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))


def load_policy_agent(directory: str | Path, env) -> PolicyAgent:
    """The agent of policy ``directory`` acting in ``env``."""
    from baselines.rl.policy import PolicyAgent  # Stable-Baselines3 and torch: when built

    return PolicyAgent.from_directory(env, directory)


#: Training arguments that do not bind an evaluation: the episode length, and the
#: difficulty level it trained at (the leaderboard runs a policy at every level).
_TRAINING_ONLY_KWARGS = ("time_limit", "difficulty")


def evaluation_env_kwargs(env_kwargs) -> dict:
    """A training's environment arguments that bind its policy's evaluation (all but
    :data:`_TRAINING_ONLY_KWARGS`, e.g. LARS ``control="position"``)."""
    return {k: v for k, v in (env_kwargs or {}).items() if k not in _TRAINING_ONLY_KWARGS}


def policy_spec(directory: Path, name: str | None = None) -> AgentSpec:
    """The registry entry of one policy directory (reads its manifest only).

    The agent acts on the environment and observation mode it was trained on,
    built with the training's environment arguments (e.g. LARS
    ``control="position"``) except the episode length.
    """
    manifest = read_manifest(directory)
    env_kwargs = evaluation_env_kwargs(manifest.get("env_kwargs"))
    return AgentSpec(
        name=name or directory.name,
        factory=functools.partial(load_policy_agent, directory),
        obs_mode=manifest["obs_mode"],
        env_ids=(manifest["env_id"],),
        description=manifest.get("description")
        or f"{manifest['algo'].upper()} policy on {manifest['obs_mode']}",
        env_kwargs=env_kwargs,
        group=manifest.get("group"),
    )


def policy_directory(path: str | Path) -> Path:
    """The directory holding the policy of ``path``: an exported policy directory
    (``train.py --export-policy``) or a finished ``train.py`` run directory (its
    ``final/``).

    Raises:
        PolicyFileError: ``path`` holds neither (or its manifest is corrupt).
    """
    path = Path(path)
    for candidate in (path, path / "final"):
        if (candidate / MANIFEST_FILE).is_file():
            read_manifest(candidate)  # checked now: a bad manifest fails before any episode
            return candidate
    raise PolicyFileError(f"{path} is neither a policy directory (with {MANIFEST_FILE}) nor a "
                          f"finished train.py run directory (with final/{MANIFEST_FILE})")


def external_policy_name(path: str | Path) -> str:
    """``<directory name>@<8 hex digits of the policy files' SHA-256s>``.

    The digest makes the name (and so the leaderboard's episode cache key) change
    whenever the weights do; a run directory is named after the run, not ``final``.
    """
    directory = policy_directory(path)
    label = Path(path).name if directory.name == "final" else directory.name
    files = read_manifest(directory)["files"]
    digest = hashlib.sha256(json.dumps(files, sort_keys=True).encode()).hexdigest()[:8]
    return f"{label}@{digest}"


def register_external_policy(path: str | Path) -> str:
    """Register the policy at ``path`` (see :func:`policy_directory`) as an agent, once;
    returns its name (:func:`external_policy_name`)."""
    name = external_policy_name(path)
    if name not in agent_names():
        register_agent(policy_spec(policy_directory(path), name))
    return name


def shipped_policy_specs(root: Path | None = None) -> list[AgentSpec]:
    """The registry entries of every policy under ``root`` (default: ``assets/policies``);
    :mod:`baselines.catalogue` declares them."""
    return [policy_spec(directory) for directory in policy_directories(root)]


#: Names of the shipped policies.
SHIPPED = tuple(directory.name for directory in policy_directories())
