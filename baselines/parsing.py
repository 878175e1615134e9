"""Command-line values: the text of a ``KEY=VALUE`` option as a Python value, never code.

One rule for every command line that takes such values (``evaluate.py
--env-kwargs``, :func:`baselines.evaluation.resolve_env_kwargs`; ``train.py
--set``, :func:`baselines.rl.config.parse_overrides`). It lives here, apart from
both, so that the evaluation library and the training configuration can share
it without importing each other.
"""

from __future__ import annotations

import ast

import yaml


def parse_value(text: str):
    """A command-line value: a Python literal, else a YAML scalar; never code.

    :func:`ast.literal_eval` first (``"30"`` -> 30, ``"1.5"``, ``"3e-4"`` ->
    0.0003, ``"(64, 48)"`` -> a tuple, ``"[64, 64]"``, ``"None"``, ``"True"``),
    then :func:`yaml.safe_load` for what is not a Python literal: YAML's
    scalars (``"true"`` -> True, ``"null"`` -> None) and bare words, which
    come back as the string (``"tanh"``, ``"high"``,
    ``"__import__('os').getcwd()"``).

    Raises:
        ValueError: the text is neither a Python literal nor valid YAML (e.g.
            ``"[1, 2"``).
    """
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        pass
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"cannot parse value {text!r}: {exc}") from exc
