"""Resolve asset files from the installed package, never from the working directory."""

from __future__ import annotations

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
