"""Resolve asset files from the installed package, never from the working directory."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import tempfile
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


@dataclasses.dataclass(frozen=True, eq=False)
class MJCF:
    """A composed MuJoCo model as text: its MJCF ``xml`` and the ``assets`` it names
    (file name -> bytes: meshes, textures), as dm_control's ``mjcf`` writes them.

    The environments compose their models from ``assets/`` in memory; this keeps what
    was compiled, so the model can be written out whole (MuJoCo Playground's
    ``xml_path`` and ``model_assets``)."""

    xml: str
    assets: dict

    @classmethod
    def of(cls, root) -> MJCF:
        """The text of a dm_control ``mjcf`` root element as it is now."""
        return cls(root.to_xml_string(), dict(root.get_assets()))

    def compile(self):
        """The ``mujoco.MjModel``."""
        import mujoco

        return mujoco.MjModel.from_xml_string(self.xml, assets=self.assets)

    @property
    def digest(self) -> str:
        """SHA-256 of the XML and the assets (by name)."""
        digest = hashlib.sha256(self.xml.encode())
        for name in sorted(self.assets):
            digest.update(name.encode() + b"\0" + self.assets[name])
        return digest.hexdigest()

    def with_option(self, **values) -> MJCF:
        """The model with ``<option>``'s attributes set (MJCF's names and spellings:
        ``timestep=0.05``, ``integrator="RK4"``); the rest of the text as it was."""
        import xml.etree.ElementTree as ElementTree

        root = ElementTree.fromstring(self.xml)
        option = root.find("option")
        if option is None:
            option = ElementTree.Element("option")
            root.insert(0, option)
        for name, value in values.items():
            option.set(name, repr(value) if isinstance(value, float) else str(value))
        return MJCF(ElementTree.tostring(root, encoding="unicode"), self.assets)

    def write(self, directory: str | Path) -> Path:
        """The model's XML under ``directory/<digest>/model.xml``, its assets beside it
        (written once, each file under a temporary name and renamed: another process
        writing the same model leaves whole files); returns the XML's path."""
        folder = Path(directory) / self.digest[:32]
        path = folder / "model.xml"
        if path.is_file():
            return path
        folder.mkdir(parents=True, exist_ok=True)
        for name, content in [*self.assets.items(), ("model.xml", self.xml.encode())]:
            with tempfile.NamedTemporaryFile(dir=folder, delete=False) as handle:
                handle.write(content)
            os.replace(handle.name, folder / name)
        return path
