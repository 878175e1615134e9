"""JAX pytrees declared where their classes are defined.

JAX is an optional extra (``pip install -e ".[jax]"``), and the CPU environments never
import it. A class of an episode's draws that the batched tasks carry in their ``State``
is declared a pytree by a decorator beside its definition: :func:`dataclass_pytree` (a
frozen dataclass: its fields the leaves, ``meta`` fields static) or
:func:`attribute_pytree` (a plain class: named attributes the leaves, others static,
rebuilt without running its constructor). The declaration registers the class with
:mod:`jax.tree_util` at once where JAX is already imported; otherwise
:func:`register_declared`, which every module of the package that imports JAX calls when
it loads, registers it.
"""

from __future__ import annotations

import dataclasses
import sys

#: The declared classes not yet registered with JAX, with how each flattens; emptied by
#: :func:`register_declared`.
_WAITING: list = []


def dataclass_pytree(meta: tuple[str, ...] = ()):
    """Declare a frozen dataclass a JAX pytree: its fields are the leaves, but those named
    in ``meta`` (static: hashed, not traced)."""

    def declare(cls):
        fields = [field.name for field in dataclasses.fields(cls)]
        unknown = set(meta) - set(fields)
        if unknown:
            raise TypeError(f"{cls.__name__} has no fields {sorted(unknown)}")
        _declare(cls, ("dataclass", [f for f in fields if f not in meta], list(meta)))
        return cls

    return declare


def attribute_pytree(children: tuple[str, ...], aux: tuple[str, ...] = ()):
    """Declare a class a JAX pytree of its attributes ``children`` (``aux``: static); it is
    rebuilt by setting them on a new instance, without running its constructor."""

    def declare(cls):
        _declare(cls, ("attributes", tuple(children), tuple(aux)))
        return cls

    return declare


def register_declared() -> None:
    """Register every declared class with :mod:`jax.tree_util` (each once)."""
    while _WAITING:
        _register(*_WAITING.pop(0))


def _declare(cls, how: tuple) -> None:
    if "jax" in sys.modules:
        _register(cls, how)
    else:
        _WAITING.append((cls, how))


def _register(cls, how: tuple) -> None:
    import jax

    if how[0] == "dataclass":
        jax.tree_util.register_dataclass(cls, data_fields=how[1], meta_fields=how[2])
        return
    _, children, aux = how

    def flatten(obj):
        return (tuple(getattr(obj, name) for name in children),
                tuple(getattr(obj, name) for name in aux))

    def unflatten(static, leaves):
        obj = object.__new__(cls)
        for name, value in (*zip(children, leaves, strict=True),
                            *zip(aux, static, strict=True)):
            object.__setattr__(obj, name, value)
        return obj

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)
