"""The LARS truth compiled for the CPU arm: :func:`~auv_envs.tasks.lars.transition.geometry`
of an episode without a sea model as one CasADi call.

Built from the same code on CasADi symbols, evaluated on CasADi's ``FunctionBuffer``
(:class:`auv_envs.core.plant.CompiledFunction`): the same operations in the same order
as Python's floats, so the same numbers to the bit (``tests/test_lars_compiled.py``),
for a few Python calls where the floats take a few hundred bytecodes a step.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from auv_envs.core.camera import inside_image_flat
from auv_envs.core.ops import FLOATS, casadi_ops
from auv_envs.core.plant import CompiledFunction
from auv_envs.tasks.lars import transition
from auv_envs.tasks.lars.scene import AUVMotion

#: The scene's numbers the compiled geometry reads: its motion (:class:`AUVMotion`'s
#: fields in order), then the marker's corners, the capture point and the hull's axis in
#: world axes about the CG.
_MOTION = tuple(field.name for field in dataclasses.fields(AUVMotion))
_SCENE_SIZE = len(_MOTION) + 9 + 3 + 3
#: Entries of the truth the compiled call does not give: the joints (read from MjData),
#: the sea's sample (none) and the corners' visibility (from the pixels).
_NOT_COMPILED = ("q", "qd", "sea", "visible")


def scene_numbers(scene: transition.Scene) -> list[float]:
    """The :data:`_SCENE_SIZE` numbers of ``scene`` the compiled geometry reads."""
    motion = scene.motion
    return ([getattr(motion, name) for name in _MOTION]
            + [c for corner in scene.corners for c in corner]
            + list(scene.capture) + list(scene.axis))


class CompiledTruth:
    """:func:`~auv_envs.tasks.lars.transition.truth` of an episode without a sea model
    (``scene.sea`` None: [LTAT]'s sinusoidal heave), its arithmetic compiled.

    Args:
        params: the task's :class:`~auv_envs.tasks.lars.transition.LARSParams`.
        qpos, qvel: the arm's joint angles and rates, read at every call (MjData's own
            arrays: nothing is copied in).
    """

    def __init__(self, params: transition.LARSParams, qpos: np.ndarray, qvel: np.ndarray):
        function, self._layout = _geometry_function(params)
        self._call = CompiledFunction(function, (qpos, qvel, np.zeros(1),
                                                 np.zeros(_SCENE_SIZE)))
        self.params = params
        self._qpos, self._qvel = qpos, qvel
        self._scene = None

    def __call__(self, scene: transition.Scene, steps: int) -> dict:
        """The truth at step ``steps`` of the episode in ``scene`` (``scene.sea`` None)."""
        _, _, t_in, scene_in = self._call.inputs
        if scene is not self._scene:
            scene_in[:] = scene_numbers(scene)
            self._scene = scene
        t = steps * self.params.dt
        t_in[0] = t
        (out,) = self._call()
        values = out.tolist()
        now = {"q": self._qpos.tolist(), "qd": self._qvel.tolist(), "sea": None}
        for key, part, kind in self._layout:
            now[key] = kind(values[part]) if kind is not float else values[part.start]
        seen = inside_image_flat(self.params.intrinsics, now["pixels"])
        now["visible"] = [seen[:3], seen[3:]]
        return transition.sighting(self.params, scene, t, None, now, FLOATS)


def _geometry_function(params: transition.LARSParams):
    """:class:`CompiledTruth`'s CasADi function of ``(q, qd, t, scene numbers)`` and its
    layout: each truth key with its slice of the output and what rebuilds it from that
    slice's values (``float``: a scalar, the slice's one value)."""
    import casadi

    q, qd = casadi.SX.sym("q", 3), casadi.SX.sym("qd", 3)
    t, numbers = casadi.SX.sym("t"), casadi.SX.sym("scene", _SCENE_SIZE)
    values = [numbers[k] for k in range(_SCENE_SIZE)]
    n = len(_MOTION)
    motion = AUVMotion(*values[:n])
    scene = transition.Scene(motion=motion, wash=None, analogs=(), waves=None, glint=None,
                             sea=None, corners=[tuple(values[n + 3 * k:n + 3 * k + 3])
                                                for k in range(3)],
                             capture=tuple(values[n + 9:n + 12]),
                             axis=tuple(values[n + 12:n + 15]))
    now = transition.geometry(params, scene, t, None, [q[k] for k in range(3)],
                              [qd[k] for k in range(3)], casadi_ops(), inside=False)
    layout, flat = [], []
    for key, value in now.items():
        if key in _NOT_COMPILED:
            continue
        kind = float
        if key == "cameras":  # two points
            value, kind = [*value[0], *value[1]], _camera_pair
        elif isinstance(value, tuple | list):
            kind = type(value)
        entries = list(value) if kind is not float else [value]
        layout.append((key, slice(len(flat), len(flat) + len(entries)), kind))
        flat.extend(entries)
    function = casadi.Function("lars_geometry", [q, qd, t, numbers],
                               [casadi.vertcat(*flat)])
    return function, tuple(layout)


def _camera_pair(values: list) -> tuple:
    """The truth's ``cameras`` from their six numbers: two ``(x, y, z)`` tuples."""
    return tuple(values[:3]), tuple(values[3:])
