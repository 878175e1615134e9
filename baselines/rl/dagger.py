"""DAgger's rules, written once for every shell that distils a student from a teacher.

Dataset aggregation (Ross, Gordon and Bagnell 2011, "A Reduction of Imitation Learning
and Structured Prediction to No-Regret Online Learning", AISTATS): the rollout executes
the teacher's action with a probability (the teacher's *share*) that decays over
training and the student's otherwise; the teacher labels every state the rollout visits;
the student is fitted to the labels by regression of its deterministic action.

Two shells use these rules:

* :class:`baselines.rl.compiled.Trainer` with ``teacher:`` (every family and non-image
  observation mode, on the batched JAX envs; the teachers of :mod:`baselines.rl.teachers`
  read the privileged state): :func:`linear_share` per iteration, fitted on each
  rollout;
* :mod:`baselines.rl.distill` (the docking ``image`` mode, which only the MuJoCo renderer
  of the Gymnasium env draws): :func:`geometric_share` per round, ``beta ** round`` as
  in the paper, fitted on every frame so far.

Both execute the teacher where :func:`taught` (:func:`mix` for a batch) and minimise
:func:`imitation_loss`. The functions take the array namespace's arrays as they come
(NumPy, ``jax.numpy``; the loss also PyTorch's tensors), so the one rule runs inside a
compiled rollout and in a Python loop alike.
"""

from __future__ import annotations

import numpy as np


def linear_share(iteration, horizon: float, xp=np):
    """The teacher's share at ``iteration``: 1 decaying linearly to 0 at ``horizon``
    iterations (0 throughout when ``horizon <= 0``)."""
    if horizon <= 0:
        return xp.float32(0.0)
    return xp.clip(1.0 - iteration / horizon, 0.0, 1.0)


def geometric_share(round_: int, beta: float) -> float:
    """The teacher's share in DAgger's ``round_`` (from 0): ``beta ** round_``, the paper's
    schedule (round 0 is the teacher's alone)."""
    if not 0.0 <= beta <= 1.0:
        raise ValueError(f"beta must lie in [0, 1], not {beta}")
    return float(beta ** round_)


def taught(draw, share, xp=np):
    """Where the teacher's action is executed: ``draw`` (uniform on [0, 1), one per
    environment, or a scalar for one) below ``share``."""
    return xp.asarray(draw) < share


def mix(teacher_action, student_action, draw, share, xp=np):
    """The executed action: the teacher's where :func:`taught`, the student's elsewhere.
    Actions carry their entries on the last axis."""
    return xp.where(taught(draw, share, xp)[..., None], teacher_action, student_action)


def imitation_loss(mean, label):
    """The student's deterministic actions' squared error to the teacher's labels, summed
    over the action's entries and averaged over the steps."""
    return ((mean - label) ** 2).sum(-1).mean()


__all__ = ["geometric_share", "imitation_loss", "linear_share", "mix", "taught"]
