"""A recurrent core for the compiled learners: PyTorch's LSTM cell in JAX.

Policies that must integrate what they saw over time (dead reckoning on a DVL between
late USBL fixes, a track between dropped detections, a light that flickers) carry a
recurrent state that the batched rollout holds per environment and clears at each
episode start, as RSL-RL's ``ActorCriticRecurrent`` and sb3-contrib's ``RecurrentPPO``
do. The cell is ``torch.nn.LSTM``'s (Hochreiter and Schmidhuber 1997, with a forget
gate), gates in PyTorch's order (input, forget, cell, output)::

    i, f, g, o = split(x W_ih + h W_hh + b)
    c' = sigmoid(f) c + sigmoid(i) tanh(g)
    h' = sigmoid(o) tanh(c')

so a trained core is written into sb3-contrib's ``RecurrentPPO`` policy unchanged
(:func:`torch_weights`): its one bias is PyTorch's ``bias_ih`` with ``bias_hh`` zero.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class LSTMState(NamedTuple):
    """The hidden and cell states of a batch of cores, ``(batch, hidden)`` each."""

    h: jax.Array
    c: jax.Array

    @classmethod
    def zeros(cls, batch: int, hidden: int) -> LSTMState:
        return cls(jnp.zeros((batch, hidden), jnp.float32), jnp.zeros((batch, hidden),
                                                                       jnp.float32))

    def cleared(self, starts: jax.Array) -> LSTMState:
        """The state with the rows where ``starts`` (a bool per row) is set zeroed: an
        episode begins from a blank memory."""
        keep = jnp.logical_not(starts)[:, None].astype(jnp.float32)
        return LSTMState(self.h * keep, self.c * keep)


def lstm_init(key: jax.Array, input_size: int, hidden: int) -> dict:
    """A cell's weights: orthogonal input and recurrent matrices (per gate), zero bias but
    the forget gate's, 1 (Jozefowicz, Zaremba and Sutskever 2015, "An Empirical
    Exploration of Recurrent Network Architectures": a cell starts by remembering)."""
    in_key, rec_key = jax.random.split(key)
    orthogonal = jax.nn.initializers.orthogonal(1.0)
    w_ih = jnp.concatenate([orthogonal(k, (input_size, hidden), jnp.float32)
                            for k in jax.random.split(in_key, 4)], axis=1)
    w_hh = jnp.concatenate([orthogonal(k, (hidden, hidden), jnp.float32)
                            for k in jax.random.split(rec_key, 4)], axis=1)
    bias = jnp.zeros(4 * hidden, jnp.float32).at[hidden:2 * hidden].set(1.0)
    return {"w_ih": w_ih, "w_hh": w_hh, "b": bias}


def lstm_cell(params: dict, state: LSTMState, x: jax.Array) -> LSTMState:
    """One step of the cell on a batch: ``x`` ``(batch, input)``."""
    gates = x @ params["w_ih"] + state.h @ params["w_hh"] + params["b"]
    i, f, g, o = jnp.split(gates, 4, axis=-1)
    c = jax.nn.sigmoid(f) * state.c + jax.nn.sigmoid(i) * jnp.tanh(g)
    return LSTMState(jax.nn.sigmoid(o) * jnp.tanh(c), c)


def lstm_unroll(params: dict, state: LSTMState, xs: jax.Array,
                starts: jax.Array) -> tuple[LSTMState, jax.Array]:
    """The cell over a sequence: ``xs`` ``(time, batch, input)``, ``starts`` ``(time,
    batch)`` set where an episode begins at that step (its state cleared before it).
    Returns the last state and the outputs ``(time, batch, hidden)``; gradients flow
    through the whole sequence (truncated backpropagation through time at its ends)."""

    def step(state, inputs):
        x, start = inputs
        state = lstm_cell(params, state.cleared(start), x)
        return state, state.h

    return jax.lax.scan(step, state, (xs, starts))


def torch_weights(params: dict) -> dict:
    """The cell as ``torch.nn.LSTM``'s layer-0 parameters (NumPy arrays), by their names."""
    w_ih, w_hh, bias = (np.asarray(params[k], np.float32) for k in ("w_ih", "w_hh", "b"))
    return {"weight_ih_l0": w_ih.T.copy(), "weight_hh_l0": w_hh.T.copy(),
            "bias_ih_l0": bias.copy(), "bias_hh_l0": np.zeros_like(bias)}


def hidden_size(params: dict) -> int:
    """The width of a cell's state."""
    return int(params["w_hh"].shape[0])


__all__ = ["LSTMState", "hidden_size", "lstm_cell", "lstm_init", "lstm_unroll",
           "torch_weights"]

