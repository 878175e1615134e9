"""A policy directory on disk: its file names, its ``policy.json`` manifest and their checks.

Kept apart from :mod:`baselines.rl.policy` (which loads the model through
Stable-Baselines3, and so torch): registering the shipped policies as agents
reads only their manifests (``evaluate.py --list``).
"""

from __future__ import annotations

import json
from pathlib import Path

from auv_envs.core.assets import asset_root, verify_sha256

MODEL_FILE = "model.zip"
NORMALIZER_FILE = "vecnormalize.pkl"
MANIFEST_FILE = "policy.json"

#: The Stable-Baselines3 algorithms a policy may name; :data:`baselines.rl.config.ALGORITHMS`
#: maps each to its class (here without importing Stable-Baselines3).
ALGORITHM_NAMES = ("ppo", "sac", "td3", "a2c", "ddpg")
#: sb3-contrib's ``RecurrentPPO``: a policy with a memory (the compiled PPO's
#: ``lstm_hidden_size``), which acts on its hidden state as well as the observation.
RECURRENT_ALGO = "recurrentppo"
#: Every algorithm a policy directory may name.
POLICY_ALGORITHMS = (*ALGORITHM_NAMES, RECURRENT_ALGO)


def policies_root() -> Path:
    """``assets/policies``: the shipped policies (``auv_envs/_assets/policies`` in a wheel)."""
    return asset_root() / "policies"


class PolicyFileError(RuntimeError):
    """A policy directory whose files are missing, corrupt or inconsistent."""


def read_manifest(directory: Path) -> dict:
    """``policy.json`` of a policy directory, checked for the keys an agent needs."""
    path = Path(directory) / MANIFEST_FILE
    if not path.is_file():
        raise PolicyFileError(f"policy manifest missing: {path}")
    try:
        manifest = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PolicyFileError(f"policy manifest {path} is corrupt: {exc}") from exc
    needed = {"name", "algo", "env_id", "obs_mode", "flatten_obs", "files"}
    if not isinstance(manifest, dict) or not needed <= set(manifest):
        raise PolicyFileError(f"policy manifest {path} lacks {sorted(needed)}")
    if manifest["algo"] not in POLICY_ALGORITHMS:
        raise PolicyFileError(f"policy manifest {path}: unknown algorithm {manifest['algo']!r}")
    return manifest


def verify_files(directory: Path, files: dict[str, str]) -> None:
    """Every file in ``files`` (name -> SHA-256) exists under ``directory`` with that digest."""
    verify_sha256(directory, files, PolicyFileError)
