"""Batched, compiled simulation on JAX and MuJoCo MJX (``pip install -e ".[jax]"``).

* :class:`~auv_envs.batched.functional.FunctionalEnv`: every family's environment as pure
  JAX functions (``reset(rng)``, ``step(state, action)``, Playground's ``MjxEnv``
  interface), one shell around the family's task on JAX
  (``auv_envs/tasks/<family>/jax_task.py``: the transition with the family's plant on MJX,
  ``auv_envs/tasks/<family>/mjx_plant.py``), every batched mode at every level;
* :func:`load` (:mod:`auv_envs.batched.registry`): any family's functional env
  under MuJoCo Playground's and Brax's conventions, for ``wrap_for_brax_training``;
* :mod:`auv_envs.batched.vector`: those as a Gymnasium ``VectorEnv``,
  ``gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs=N)``, whose compiled
  programs are kept on disk on a GPU or TPU (:mod:`auv_envs.batched.compile_cache`).
"""

import contextlib
import io
import sys

from auv_envs.extras import MissingExtra

try:
    import jax  # noqa: F401

    # MJX prints "Failed to import warp: ..." when the optional MuJoCo Warp backend
    # is absent (these envs do not use it); anything else it prints is passed on.
    with contextlib.redirect_stdout(io.StringIO()) as _printed:
        from mujoco import mjx  # noqa: F401
    sys.stdout.write("".join(line for line in _printed.getvalue().splitlines(keepends=True)
                             if not line.startswith(("Failed to import warp:",
                                                     "Failed to import mujoco_warp:"))))
except ImportError:  # pragma: no cover - the message is the point
    raise MissingExtra("auv_envs.batched (the *MJX ids, --algo cppo)", "jax") from None

from auv_envs.batched.registry import load  # noqa: E402  (after the import check above)

__all__ = ["load"]
