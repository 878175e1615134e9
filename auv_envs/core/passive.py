"""MuJoCo's passive-force callback, shared safely by every model in one process.

The hull wrench of a hydrodynamic plant depends on the state, so a
higher-order integrator must evaluate it at every stage, not once per step.
MuJoCo calls ``mjcb_passive`` inside ``mj_passive`` at every evaluation of the
dynamics (four per step with ``integrator="RK4"``); the callback adds the
generalized hull force to ``qfrc_passive``.

``mjcb_passive`` is one global for the whole process. :func:`step` and
:func:`forward` therefore install a dispatcher only while one of our models
is being stepped, and the dispatcher looks the force up by the ``MjData``
being integrated: several environments in one process, vector envs and
threads each get their own force, and every other MuJoCo model in the
process (e.g. Gymnasium's own environments) never sees the callback.

One process-wide lock, :data:`MUJOCO_LOCK`, is held for each such step, for
every model ``auv_envs`` compiles (:func:`compile_model`) and around every
other MuJoCo call of ``auv_envs`` that evaluates dynamics (``mj_forward``,
``mj_step``): MuJoCo's compiler evaluates passive forces on internal data that
has no Python object, which an installed callback cannot be called with, and a
call that enters the callback while another thread uninstalls it fails. So
``auv_envs`` envs may be built and stepped from several threads. Code outside
``auv_envs`` that runs MuJoCo in another thread *while* a docking env steps is
not covered by the lock.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import mujoco

#: A force callback: ``force(model, data)`` adds to ``data.qfrc_passive``.
PassiveForce = Callable[[mujoco.MjModel, mujoco.MjData], None]

#: Held while a model steps with a passive force, while auv_envs compiles a
#: model, and around every other MuJoCo call of auv_envs that evaluates dynamics.
MUJOCO_LOCK = threading.Lock()
#: id(MjData) -> the force of the model being stepped with that data.
_FORCES: dict[int, PassiveForce] = {}


def _dispatch(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    force = _FORCES.get(id(data))
    if force is not None:
        force(model, data)


def _register(data: mujoco.MjData, force: PassiveForce) -> int:
    """Install the dispatcher for ``data``'s force; the caller holds :data:`MUJOCO_LOCK`."""
    key = id(data)
    if key in _FORCES:
        raise RuntimeError("this MjData is already being stepped with a passive force")
    if not _FORCES:
        installed = mujoco.get_mjcb_passive()
        if installed is not None and installed is not _dispatch:
            raise RuntimeError(
                "another mjcb_passive callback is installed in this process; "
                "auv_envs' hydrodynamic plants need it (auv_envs.core.passive)"
            )
        mujoco.set_mjcb_passive(_dispatch)
    _FORCES[key] = force
    return key


def _unregister(key: int) -> None:
    del _FORCES[key]
    if not _FORCES:
        mujoco.set_mjcb_passive(None)


def _call_with_force(function, model: mujoco.MjModel, data: mujoco.MjData,
                     force: PassiveForce, *args) -> None:
    with MUJOCO_LOCK:
        key = _register(data, force)
        try:
            function(model, data, *args)
        finally:
            _unregister(key)


def step(model: mujoco.MjModel, data: mujoco.MjData, force: PassiveForce, nstep: int = 1) -> None:
    """``mj_step`` ``nstep`` times with ``force`` evaluated at every stage of the integrator."""
    _call_with_force(mujoco.mj_step, model, data, force, nstep)


def forward(model: mujoco.MjModel, data: mujoco.MjData, force: PassiveForce) -> None:
    """``mj_forward`` with ``force``: ``data.qacc`` is then the state's full acceleration."""
    _call_with_force(mujoco.mj_forward, model, data, force)


def compile_model(xml: str, assets: dict | None = None) -> mujoco.MjModel:
    """``MjModel.from_xml_string``, never while one of our models steps (see the module doc)."""
    with MUJOCO_LOCK:
        return mujoco.MjModel.from_xml_string(xml, assets=assets)
