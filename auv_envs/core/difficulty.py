"""Difficulty levels: named, documented sets of an environment's physical parameters.

Every environment takes ``difficulty`` (one of :data:`LEVELS`):

* ``"easy"``: the environment as released, bit for bit (its keyword defaults);
* ``"paper"``: the water the source paper measured in, its physical
  parameters calibrated against the paper's reported figures (each
  environment's preset says which figure each parameter was calibrated on);
* ``"hard"``: beyond the paper, with headroom left for better methods.

A preset sets only keywords whose default is ``None`` ("the level's model"),
such as the acoustic measurement model or the docking disturbances. A keyword
given explicitly overrides the preset's value for it, so
``gym.make(id, difficulty="paper", acoustic=my_config)`` keeps everything of
``paper`` except the acoustic model. ``Env.preset(level)`` returns a level's
keywords, to start a variation from.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

LEVELS = ("easy", "paper", "hard")
DEFAULT_LEVEL = "easy"


def check_presets(presets: Mapping[str, Mapping[str, Any]]) -> None:
    """An environment's presets cover exactly :data:`LEVELS`, ``easy`` sets nothing."""
    if tuple(presets) != LEVELS:
        raise ValueError(f"presets must be given for {LEVELS} in that order, got {tuple(presets)}")
    if presets["easy"]:
        raise ValueError("the easy preset is the released environment: it sets no keyword")


def resolve(presets: Mapping[str, Mapping[str, Any]], difficulty: str,
            given: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword values of ``difficulty``, overridden by those ``given`` (not None).

    Args:
        presets: level -> {keyword: value} (``check_presets``).
        difficulty: one of :data:`LEVELS`.
        given: the keywords the caller passed, None meaning "not given".

    Returns:
        ``given`` with every None the preset sets replaced by the preset's value.

    Raises:
        ValueError: an unknown level.
    """
    if difficulty not in presets:
        raise ValueError(f"difficulty must be one of {tuple(presets)}, got {difficulty!r}")
    preset = presets[difficulty]
    unknown = set(preset) - set(given)
    if unknown:
        raise ValueError(f"preset {difficulty!r} sets keywords the environment lacks: {unknown}")
    return {name: preset.get(name) if value is None else value for name, value in given.items()}
