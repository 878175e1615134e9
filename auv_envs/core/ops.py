"""Array backends for equations written once in scalar arithmetic.

The per-step rules of an environment (frames, camera projection, rewards,
termination) are written as plain arithmetic on scalars plus a few functions
taken from an ``ops`` namespace. The CPU environments pass :data:`FLOATS`
(Python floats: for a handful of numbers per step NumPy's call overhead
exceeds the arithmetic); the batched environments pass :func:`jax_ops`, and
the same code then evaluates a batch of JAX arrays elementwise, inside
``jit`` and ``vmap``. The dynamics accept ``math``, ``numpy`` or ``casadi``
modules the same way (:mod:`auv_envs.core.hydrodynamics`).

Every namespace has ``sqrt``, ``sin``, ``cos``, ``exp``, ``atan``, ``atan2``, ``asin``, ``acos``,
``hypot``, ``log10``, ``mod`` (Python's ``%``: the remainder with the divisor's sign),
``clip(x, low, high)``, ``where(condition, a, b)``, ``minimum``, ``maximum``,
``logical_not``, ``logical_and``, ``logical_or`` and ``barrier(values)`` (a
tuple of scalars materialised as one array where XLA would otherwise fuse them into
what follows, recomputing a deep expression as a tree: JAX's
``optimization_barrier``; the identity elsewhere). Comparisons combine with ``&``
and ``|``, which serve Python bools and boolean arrays alike. For a transition's state
(:mod:`auv_envs.tasks.docking.transition`) each also has ``xp`` (its array
module: NumPy, ``jax.numpy``), ``real``, ``integer`` and ``boolean`` (a scalar
of the backend's type: Python's, or float32/int32/bool arrays), ``vector`` (a
few scalars as one value: a tuple, or a float32 array), ``unpack`` (a 1-D array
as a tuple of scalars: Python floats, or array elements) and ``count`` (the
true entries of a boolean array), ``round`` (to the nearest integer, halves to even, as
a float of the backend), ``scan(body, carry, xs)``, JAX's ``lax.scan``
over a tuple of arrays ``xs`` and tuples of outputs (a Python loop on the CPU; one
traced body under JAX, however many rows), and ``either(condition, then, otherwise)``,
the result of ``then()`` where ``condition`` holds, else of ``otherwise()`` (two
functions of no arguments returning the same structure): on the CPU only the chosen
function runs, its random draws too; under JAX both run (first ``then``) and the result
is selected element by element, so a batch of episodes draws alike whatever each one
chooses. The draws of an episode on the CPU and under JAX differ there: the plants that
use it say so.

:func:`casadi_ops` evaluates the arithmetic parts (the plant, the
kinematics, a projection) on CasADi symbols, which
:class:`auv_envs.core.plant.CompiledFunction` compiles into one call; its
comparisons are CasADi expressions, which do not combine with ``&``/``|``
(use ``logical_and``, ``logical_or`` and ``where``); it also has ``round``, ``real``,
``boolean``, ``vector`` (a column of scalars), ``unpack`` and ``either`` (both branches,
selected entry by entry, as under JAX), the same numbers as
:data:`FLOATS`' to the bit but for the sign of a zero that ``where`` chooses (CasADi's
``if_else`` adds its branches, each zeroed where not chosen: -0.0 comes out 0.0; so does
a zero ``mod`` by a negative divisor, which Python gives -0.0).
"""

from __future__ import annotations

import math
import operator
import types
from typing import Any, NamedTuple

import numpy as np


class Backend(NamedTuple):
    """How a task's transition (``auv_envs/tasks/<family>/transition.py``) is evaluated.

    Attributes:
        ops: a namespace of this module (:data:`FLOATS`, :func:`jax_ops`).
        draws: the episode's random draws with NumPy ``Generator``'s interface: the
            environment's generator on the CPU, a JAX key's
            (:class:`auv_envs.batched.functional.KeyDraws`) in the batched envs.
        plant: the task's simulator (the methods each transition's module lists).
    """

    ops: Any
    draws: Any
    plant: Any


def _scan(body, carry, xs: tuple):
    """``lax.scan``'s semantics for tuples: ``body(carry, row) -> (carry, outputs)`` over
    the rows of ``xs``; returns the last carry and each output stacked over the rows."""
    outputs = []
    for row in zip(*xs, strict=True):
        carry, out = body(carry, row)
        outputs.append(out)
    return carry, tuple(np.stack(column) for column in zip(*outputs, strict=True))


def _where(condition, a, b):
    return a if condition else b


def _either(condition, then, otherwise):
    return then() if condition else otherwise()


def _round(x):
    # Python's round halves to even, as NumPy's and JAX's; copysign keeps their -0.0.
    return math.copysign(float(round(x)), x)


def _clip(x, low, high):
    # Comparisons, not min/max (which are slower and turn NaN into a bound): NaN stays NaN,
    # as NumPy's and JAX's clip leave it.
    return low if x < low else (high if x > high else x)


#: Python floats (and bools): :mod:`math`, with ``where`` a conditional expression.
FLOATS = types.SimpleNamespace(
    name="floats",
    sqrt=math.sqrt, sin=math.sin, cos=math.cos, exp=math.exp, atan=math.atan, atan2=math.atan2,
    asin=math.asin, acos=math.acos, hypot=math.hypot, log10=math.log10, mod=operator.mod,
    clip=_clip, where=_where, minimum=min, maximum=max,
    logical_not=lambda x: not x, logical_and=operator.and_, logical_or=operator.or_,
    barrier=lambda values: values,
    xp=np, real=float, integer=int, boolean=bool, vector=tuple,
    unpack=lambda array: tuple(array.tolist()),
    count=lambda array: int(np.count_nonzero(array)),
    round=_round,
    scan=_scan,
    either=_either,
)


def jax_ops() -> types.SimpleNamespace:
    """``jax.numpy`` under the names of :data:`FLOATS` (imports JAX on first use)."""
    import jax
    import jax.numpy as jnp

    return types.SimpleNamespace(
        name="jax",
        sqrt=jnp.sqrt, sin=jnp.sin, cos=jnp.cos, exp=jnp.exp, atan=jnp.arctan, atan2=jnp.arctan2,
        asin=jnp.arcsin, acos=jnp.arccos, hypot=jnp.hypot, log10=jnp.log10, mod=jnp.mod,
        clip=jnp.clip, where=jnp.where, minimum=jnp.minimum, maximum=jnp.maximum,
        logical_not=jnp.logical_not, logical_and=jnp.logical_and, logical_or=jnp.logical_or,
        barrier=lambda values: tuple(jax.lax.optimization_barrier(jnp.stack(values))),
        xp=jnp, real=lambda value: jnp.asarray(value, jnp.float32),
        integer=lambda value: jnp.asarray(value, jnp.int32),
        boolean=lambda value: jnp.asarray(value, jnp.bool_),
        vector=lambda values: jnp.asarray(values, jnp.float32),
        unpack=lambda array: tuple(array[k] for k in range(array.shape[0])),
        count=lambda array: jnp.sum(array.astype(jnp.int32)),
        round=jnp.round,
        scan=jax.lax.scan,
        either=lambda condition, then, otherwise: jax.tree.map(
            lambda a, b: jnp.where(condition, a, b), then(), otherwise()),
    )


def casadi_ops() -> types.SimpleNamespace:
    """CasADi's scalar functions under the names of :data:`FLOATS` (no array module:
    expressions on ``SX`` symbols, compiled by :class:`auv_envs.core.plant.CompiledFunction`)."""
    import casadi

    def clip(x, low, high):  # comparisons, as FLOATS: NaN stays NaN
        return casadi.if_else(x < low, low, casadi.if_else(x > high, high, x))

    # Comparisons, as Python's min and max choose (the second only where it is strictly
    # smaller or larger): C's fmin and fmax, which CasADi emits for its own, are calls
    # into the maths library in compiled code, where these are one instruction.
    def minimum(a, b):
        return casadi.if_else(b < a, b, a)

    def maximum(a, b):
        return casadi.if_else(b > a, b, a)

    def mod(x, y):  # Python's %: C's fmod moved to the divisor's side
        remainder = casadi.fmod(x, y)
        wrong_side = casadi.logic_and(remainder != 0, (remainder < 0) != (y < 0))
        return casadi.if_else(wrong_side, remainder + y, remainder)

    def round_half_even(x):  # Python's round (halves to even) and FLOATS' sign of zero
        low = casadi.floor(x)
        above = x - low
        odd = casadi.fmod(low, 2.0) != 0
        up = casadi.logic_or(above > 0.5, casadi.logic_and(above == 0.5, odd))
        return casadi.copysign(casadi.if_else(up, low + 1.0, low), x)

    def either(condition, then, otherwise):  # both, selected entry by entry (as JAX's)
        def select(a, b):
            if isinstance(a, tuple | list):
                return type(a)(select(x, y) for x, y in zip(a, b, strict=True))
            return casadi.if_else(condition, a, b)
        return select(then(), otherwise())

    return types.SimpleNamespace(
        name="casadi",
        sqrt=casadi.sqrt, sin=casadi.sin, cos=casadi.cos, exp=casadi.exp,
        atan=casadi.atan, atan2=casadi.atan2, asin=casadi.asin, acos=casadi.acos,
        hypot=lambda x, y: casadi.sqrt(x * x + y * y), log10=casadi.log10, mod=mod,
        clip=clip, where=casadi.if_else, minimum=minimum, maximum=maximum,
        logical_not=casadi.logic_not, logical_and=casadi.logic_and,
        logical_or=casadi.logic_or, barrier=lambda values: values,
        round=round_half_even, real=lambda value: value, boolean=lambda value: value,
        either=either,
        vector=lambda values: casadi.vertcat(*values),
        unpack=lambda column: tuple(column[k] for k in range(column.numel())),
    )
