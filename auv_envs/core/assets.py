"""Resolve asset files from the installed package, never from the working directory."""

from __future__ import annotations

import hashlib
from pathlib import Path

#: Root of the asset tree. In a source checkout (editable install) this is the
#: top-level ``assets/``; a wheel ships the same tree as ``auv_envs/_assets``.
_CANDIDATES = (
    Path(__file__).resolve().parents[2] / "assets",
    Path(__file__).resolve().parents[1] / "_assets",
)


def asset_root() -> Path:
    """The directory holding the MJCF models and other assets."""
    for root in _CANDIDATES:
        if root.is_dir():
            return root
    raise FileNotFoundError(
        "auv_envs assets not found; looked in: " + ", ".join(str(c) for c in _CANDIDATES)
    )


def asset_path(relative: str) -> Path:
    """Absolute path of an asset, with an error that names the missing file."""
    path = asset_root() / relative
    if not path.is_file():
        raise FileNotFoundError(f"auv_envs asset missing: {path}")
    return path


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file, read in 1 MiB blocks (shipped weights and checkpoints)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def verify_sha256(
    directory: str | Path, files: dict[str, str], error: type[Exception] = ValueError
) -> None:
    """Every file in ``files`` (name -> hex SHA-256) exists under ``directory`` with that digest.

    Raises ``error`` naming the first file that is missing or whose digest differs.
    """
    directory = Path(directory)
    for name, expected in files.items():
        path = directory / name
        if not path.is_file():
            raise error(f"file missing: {path}")
        if sha256_file(path) != expected:
            raise error(
                f"file {path} is corrupt or was changed (SHA-256 differs from the one recorded)"
            )
