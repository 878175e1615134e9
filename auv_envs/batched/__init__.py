"""Batched, compiled simulation on JAX and MuJoCo MJX (``pip install -e ".[jax]"``).

* :mod:`auv_envs.batched.docking`: the docking plant (the same MJCF and the
  same hydrodynamics code as ``auv_envs/DockingStation-v2``) for a batch of
  vehicles in one compiled call;
* :mod:`auv_envs.batched.docking_env`: the docking environments as pure JAX
  functions (``reset(rng)``, ``step(state, action)``, Playground's ``MjxEnv``
  interface), ``state`` and ``features`` at every level;
* :mod:`auv_envs.batched.lars_env`: the LARS capture environment likewise;
* :mod:`auv_envs.batched.acoustic_env`: the acoustic tracking environment, its rig on
  MJX (:mod:`auv_envs.batched.acoustic_plant`, with MuJoCo's ellipsoid fluid model
  in JAX: :mod:`auv_envs.tasks.acoustic.fluid`);
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
