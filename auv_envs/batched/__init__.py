"""Batched, compiled simulation on JAX and MuJoCo MJX (``pip install -e ".[jax]"``).

:mod:`auv_envs.batched.docking` steps the docking plant, the same MJCF and the
same hydrodynamics code as ``auv_envs/DockingStation-v1``, for a batch of
vehicles in one compiled call. Only the plant exists so far: the observations,
rewards and episode logic of a batched environment are not built yet.
"""

try:
    import jax  # noqa: F401
    from mujoco import mjx  # noqa: F401
except ImportError as exc:  # pragma: no cover - the message is the point
    raise ImportError(
        "auv_envs.batched needs JAX and MuJoCo MJX: pip install -e \".[jax]\""
    ) from exc
