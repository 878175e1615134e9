"""MuJoCo's integrators with a state-dependent force at every stage, and no global state.

The hull wrench of a hydrodynamic plant depends on the state, so a
higher-order integrator must evaluate it at every stage, not once per step.
MuJoCo offers that only through ``mjcb_passive``, one callback for the whole
process, which every other MuJoCo model in the process (another library's,
in another thread) would then run through. This module instead runs
MuJoCo's own pipeline stage by stage on one ``MjData``: the force is added
to ``qfrc_passive`` right after ``mj_fwdVelocity`` (which computes the
passive forces), exactly where ``mj_passive`` would call the callback, and
:func:`step` writes out MuJoCo's ``mj_step`` for the Euler and classical
RK4 integrators (MuJoCo's ``mj_RungeKutta`` with its Butcher tableau, the
final update of ``mj_advance``). Trajectories equal the callback's to the
bit, and nothing outside the ``MjModel``/``MjData`` passed in is touched, so
any number of models step in any threads beside any other MuJoCo code.

Sensors and energy are computed as ``mj_forward``/``mj_step`` compute them
(sensors at the start of a step only, energy at every stage).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import mujoco
import numpy as np

from auv_envs.core import native

#: A force: ``force(model, data)`` adds to ``data.qfrc_passive`` at the state in ``data``.
StageForce = Callable[[mujoco.MjModel, mujoco.MjData], None]

#: MuJoCo's classical RK4 (``engine_forward.c``): the stages' a_{i, i-1} and the weights b.
RK4_STAGES = (0.5, 0.5, 1.0)
RK4_WEIGHTS = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)

_ENERGY = int(mujoco.mjtEnableBit.mjENBL_ENERGY)
_STAGE_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)
_RK4 = int(mujoco.mjtIntegrator.mjINT_RK4)
_INTEGRATORS = (int(mujoco.mjtIntegrator.mjINT_EULER), _RK4)


class StagedIntegrator:
    """Steps one ``MjData`` with ``force`` added at every evaluation of the dynamics.

    Args:
        model: the model; its integrator must be ``Euler`` or ``RK4`` and it
            must have no activations (``na == 0``), as every plant of this package.
        data: the data it steps (views into it are kept: use one integrator per data).
        force: ``force(model, data)`` adds to ``data.qfrc_passive`` at the state in ``data``.

    The integrator is read from ``model.opt`` at every :meth:`step`, so a model
    whose options change between steps is followed.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, force: StageForce):
        if model.na:
            raise ValueError("StagedIntegrator does not integrate activations (model.na > 0)")
        self.model, self.data, self.force = model, data, force
        self._opt = model.opt  # a view of the model's options: changes show through
        self._qpos, self._qvel, self._qacc = data.qpos, data.qvel, data.qacc
        self._warmstart = data.qacc_warmstart
        #: Rows: the RK4 stages' (qvel, qacc); the stage weights as a column.
        self._stages = np.empty((4, 2 * model.nv))
        self._weights = np.array(RK4_WEIGHTS)[:, None]
        self._sensors = model.nsensor > 0

    def forward(self, sensors: bool = True) -> None:
        """``mj_forward`` with the force: ``data.qacc`` is then the state's full
        acceleration (``sensors=False``: as at RK4's later stages, no sensors)."""
        model, data = self.model, self.data
        energy = self._opt.enableflags & _ENERGY  # at every stage, as mj_forwardSkip
        sensors = sensors and self._sensors
        mujoco.mj_fwdPosition(model, data)
        if sensors:
            mujoco.mj_sensorPos(model, data)
        if energy:
            mujoco.mj_energyPos(model, data)
        mujoco.mj_fwdVelocity(model, data)
        if sensors:
            mujoco.mj_sensorVel(model, data)
        if energy:
            mujoco.mj_energyVel(model, data)
        self.force(model, data)
        # Actuation, acceleration, constraint (+ sensorAcc unless skipped), as mj_forward.
        mujoco.mj_forwardSkip(model, data, _STAGE_VEL, int(not sensors))

    def step(self, nstep: int = 1) -> None:
        """``mj_step`` ``nstep`` times with the force at every stage of the integrator."""
        model, data = self.model, self.data
        integrator = self._opt.integrator
        if integrator not in _INTEGRATORS:
            name = mujoco.mjtIntegrator(integrator).name
            raise ValueError(f"StagedIntegrator steps with Euler or RK4, not {name}")
        rk4 = integrator == _RK4
        for _ in range(nstep):
            mujoco.mj_checkPos(model, data)
            mujoco.mj_checkVel(model, data)
            self.forward()
            mujoco.mj_checkAcc(model, data)
            if rk4:
                self._runge_kutta()
            else:
                mujoco.mj_Euler(model, data)

    def _runge_kutta(self) -> None:
        """MuJoCo's ``mj_RungeKutta(m, d, 4)`` from the forward-computed state, with the
        force at every stage: the same floating-point operations, so the same bits.

        Each stage's ``F_i = (qvel, qacc)`` is a row of one array, so that the
        weighted sums take few NumPy calls (a stage's ``a`` is a power of two, so
        scaling by it is exact in any order).
        """
        model, data, nv = self.model, self.data, self.model.nv
        qpos, qvel, stages = self._qpos, self._qvel, self._stages
        h, time = self._opt.timestep, data.time
        qpos0 = qpos.copy()
        qvel0 = stages[0, :nv]
        stages[0, :nv] = qvel
        stages[0, nv:] = self._qacc
        for i, a in enumerate(RK4_STAGES, start=1):
            dx = stages[i - 1] * a
            qpos[:] = qpos0
            mujoco.mj_integratePos(model, qpos, dx[:nv], h)
            np.add(qvel0, dx[nv:] * h, out=qvel)
            data.time = time + a * h
            self.forward(sensors=False)
            stages[i, :nv] = qvel
            stages[i, nv:] = self._qacc
        # dX = sum_j b_j F_j, summed from zero in stage order as mj_RungeKutta does
        # (0.0 + x is x, but for -0.0, which it makes +0.0).
        weighted = stages * self._weights
        dx = (((weighted[0] + 0.0) + weighted[1]) + weighted[2]) + weighted[3]
        # mj_advance: velocities with the weighted acceleration, positions with the
        # weighted velocity, then time, then the constraint solver's warm start.
        np.add(qvel0, dx[nv:] * h, out=qvel)
        qpos[:] = qpos0
        mujoco.mj_integratePos(model, qpos, dx[:nv], h)
        data.time = time + h
        self._warmstart[:] = self._qacc


# ------------------------------------------------------------------ the compiled free body
def free_body_rk4(qpos, qvel, acceleration, h, ops) -> tuple[tuple, tuple]:
    """One step of MuJoCo's classical RK4 (its tableau, :data:`RK4_STAGES` and
    :data:`RK4_WEIGHTS`; the free joint's position update of
    :func:`auv_envs.core.frames.quat_turned`) for one free joint, in scalar arithmetic.

    Args:
        qpos: world position and unit quaternion (7 scalars).
        qvel: world linear and body angular velocity (6 scalars).
        acceleration: ``acceleration(qpos, qvel)`` -> ``qacc`` (6 scalars) at a state.
        h: the step, s.
        ops: the backend (:mod:`auv_envs.core.ops`).

    Returns:
        ``(qpos, qvel)`` after the step, as tuples of scalars.
    """
    from auv_envs.core.frames import quat_turned

    def moved(velocity, scale):  # qpos0 moved by velocity * scale for h seconds
        return (*(qpos[k] + velocity[k] * scale * h for k in range(3)),
                *quat_turned(qpos[3:], [velocity[k] * scale for k in range(3, 6)], h, ops))

    # Each stage's derivative is materialised (``ops.barrier``): a compiler that fuses the
    # stages' arithmetic into one expression per output would evaluate it as a tree.
    velocities = [tuple(qvel)]
    accelerations = [ops.barrier(acceleration(tuple(qpos), tuple(qvel)))]
    for a in RK4_STAGES:
        stage_qvel = tuple(qvel[k] + accelerations[-1][k] * a * h for k in range(6))
        velocities.append(stage_qvel)
        accelerations.append(ops.barrier(acceleration(moved(velocities[-2], a), stage_qvel)))
    velocity = [sum(b * v[k] for b, v in zip(RK4_WEIGHTS, velocities, strict=True))
                for k in range(6)]
    acc = [sum(b * a[k] for b, a in zip(RK4_WEIGHTS, accelerations, strict=True))
           for k in range(6)]
    return moved(velocity, 1.0), tuple(qvel[k] + acc[k] * h for k in range(6))


def hull_advance(hull, qpos, qvel, tau, current, timestep: float, substeps: int,
                 ops) -> tuple[tuple, tuple]:
    """``substeps`` steps of :func:`free_body_rk4` of the free joint ``(qpos, qvel)`` (7 and 6
    scalars) under :func:`~auv_envs.core.hydrodynamics.free_body_acceleration` of ``hull``
    (a :class:`~auv_envs.core.hydrodynamics.HullForceModel`), with the body-frame force
    ``tau`` (6) and the world current (3) held: the docking plant, compiled on the CPU
    (:class:`FreeBodyPlant`) and evaluated on JAX in the batched environment."""
    from auv_envs.core.frames import rotation_rows_from_quat
    from auv_envs.core.hydrodynamics import free_body_acceleration

    def acceleration(q, v):
        return free_body_acceleration(hull, rotation_rows_from_quat(*q[3:]), v, tau, current)

    for _ in range(substeps):
        qpos, qvel = free_body_rk4(qpos, qvel, acceleration, timestep, ops)
    return qpos, qvel


class CompiledFunction:
    """A CasADi ``Function`` of a few float64 vectors, evaluated in place.

    CasADi's ``Function.__call__`` converts its arguments and results through
    SWIG; its ``buffer()`` evaluates on memory bound once, which costs little
    besides the arithmetic (on its virtual machine; as machine code, where a C
    compiler is present, less: :mod:`auv_envs.core.native`, the same numbers to the
    bit; ``docs/speed.md`` has the timings). :attr:`inputs` and
    :attr:`outputs` are those memories as NumPy arrays: write the inputs, call,
    read the outputs.

    Args:
        function: a ``casadi.Function`` of dense column-vector inputs and outputs.
        inputs: arrays to read the inputs from, bound once (e.g. views into a
            ``MjData``: then nothing is copied per call); None: new arrays. Each must
            be a contiguous float64 array of its input's size.
    """

    def __init__(self, function, inputs=None):
        self.function = function
        if inputs is None:
            inputs = tuple(np.zeros(function.nnz_in(i)) for i in range(function.n_in()))
        for i, array in enumerate(inputs):
            if (array.dtype != np.float64 or not array.flags.c_contiguous
                    or array.size != function.nnz_in(i)):
                raise ValueError(f"input {i} must be a contiguous float64 array of "
                                 f"{function.nnz_in(i)} entries, got {array.dtype} "
                                 f"{array.shape}")
        self.inputs = tuple(inputs)
        self.outputs = tuple(np.zeros(function.nnz_out(i)) for i in range(function.n_out()))
        code = native.machine_code(function)
        #: Whether it runs as machine code (:mod:`auv_envs.core.native`), not on CasADi's
        #: virtual machine.
        self.native = code is not function
        buffer, self._evaluate = code.buffer()
        for i, array in enumerate(self.inputs):
            buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(self.outputs):
            buffer.set_res(i, memoryview(array))
        self._buffer = buffer  # bound to the arrays: kept with them

    def __call__(self) -> tuple[np.ndarray, ...]:
        """Evaluate at :attr:`inputs`; returns :attr:`outputs` (the same arrays every call)."""
        self._evaluate()
        return self.outputs

    def __getstate__(self):
        return {"function": self.function, "inputs": self.inputs}

    def __setstate__(self, state):
        self.__init__(state["function"])
        for mine, theirs in zip(self.inputs, state["inputs"], strict=True):
            mine[:] = theirs


class SymbolicDraws:
    """A NumPy ``Generator``'s draws (``standard_normal``, ``random``) as CasADi symbols, in
    the order a model written for the generator asks for them, so that the model compiles
    with its draws as an input (:meth:`column`); :meth:`draw` then makes the same calls on
    a generator, each into its slice of that input (the same numbers as the model's own
    calls would get).

    Args:
        name: the symbols' prefix.
    """

    def __init__(self, name: str):
        self.name, self.calls, self._symbols, self._size = name, [], [], 0
        #: The number of calls made before each :meth:`mark`.
        self.marks = []

    def mark(self) -> None:
        """Mark the calls so far: a model's draws that are made only sometimes (a USBL
        ping's) begin here; :meth:`views` of a slice of calls serves each group."""
        self.marks.append(len(self.calls))

    def _take(self, kind: str, size):
        import casadi

        count = 1 if size is None else int(size)
        symbol = casadi.SX.sym(f"{self.name}_{len(self.calls)}", count)
        self.calls.append((kind, slice(self._size, self._size + count)))
        self._symbols.append(symbol)
        self._size += count
        return symbol[0] if size is None else symbol

    def random(self, size=None):
        return self._take("random", size)

    def standard_normal(self, size=None):
        return self._take("standard_normal", size)

    def column(self):
        """All the draws as one symbolic column (the function's input)."""
        import casadi

        return casadi.vertcat(*self._symbols)

    def views(self, array: np.ndarray, calls: slice = slice(None)) -> tuple:
        """The ``calls`` (all: every one) as ``Generator`` methods, each with its slice of
        ``array`` (the bound input); consecutive calls of one method merged into one (a
        generator's ``random`` and ``standard_normal`` keep nothing between calls: the same
        numbers)."""
        merged = []
        for kind, part in self.calls[calls]:
            if merged and merged[-1][0] == kind:
                merged[-1] = (kind, slice(merged[-1][1].start, part.stop))
            else:
                merged.append((kind, part))
        return tuple((getattr(np.random.Generator, kind), array[part])
                     for kind, part in merged)

    @staticmethod
    def draw(views: tuple, generator) -> None:
        """Make the recorded calls on ``generator`` (a NumPy ``Generator``) into ``views``."""
        for method, out in views:
            method(generator, out=out)


class FreeBodyPlant:
    """The hull of a :class:`~auv_envs.core.hydrodynamics.HullForceModel` as one compiled
    call: ``substeps`` steps of :func:`free_body_rk4` under
    :func:`~auv_envs.core.hydrodynamics.free_body_acceleration`, without contacts.

    The same equations as MuJoCo's free body stepped by :class:`StagedIntegrator`
    with the hull wrench at every stage (equal to round-off where no contact
    acts, ``tests/test_compiled_plant.py``), compiled by CasADi from the scalar code that
    the batched plant evaluates on JAX: one call where the staged integrator makes
    many Python calls into MuJoCo (``python benchmarks/plant_cost.py`` times both).

    Args:
        params: the nominal vehicle (:class:`~auv_envs.core.vehicle.VehicleParams`).
        timestep: one RK4 step, s.
        substeps: steps per :meth:`advance`.

    The episode's vehicle is an input (:meth:`~auv_envs.core.vehicle.PlantPerturbation.apply`'s
    draws: mass factor, 12 damping factors, net-buoyancy offset), so a perturbed
    episode steps the same compiled function.
    """

    #: The perturbation draws of the nominal vehicle (factors 1, offset 0).
    NOMINAL = (1.0, (1.0,) * 12, 0.0)

    def __init__(self, params, timestep: float, substeps: int = 1):
        self.timestep, self.substeps = timestep, substeps
        function = _free_body_function(params, float(timestep), int(substeps))
        self._call = CompiledFunction(function)
        self.vehicle(None)

    def vehicle(self, draws) -> None:
        """Simulate the vehicle of these perturbation draws ``(mass factor, 12 damping
        factors, buoyancy offset)``; None: the nominal one."""
        mass, damping, buoyancy = self.NOMINAL if draws is None else draws
        self._call.inputs[4][:] = (mass, *damping, buoyancy)

    def advance(self, qpos: np.ndarray, qvel: np.ndarray, tau, current) -> None:
        """Step ``qpos`` (7) and ``qvel`` (6) in place by ``substeps`` RK4 steps under the
        body-frame generalized force ``tau`` (6) and the world current (3), held."""
        qpos_in, qvel_in, tau_in, current_in, _ = self._call.inputs
        qpos_in[:] = qpos
        qvel_in[:] = qvel
        tau_in[:] = tau
        current_in[:] = current
        qpos_out, qvel_out = self._call()
        qpos[:] = qpos_out
        qvel[:] = qvel_out


@functools.lru_cache(maxsize=32)
def _free_body_function(params, timestep: float, substeps: int):
    """:class:`FreeBodyPlant`'s CasADi function of ``(qpos, qvel, tau, current, vehicle
    draws)``; built once per vehicle and step (a CasADi function is immutable, and each
    plant evaluates it on its own memory)."""
    import casadi

    from auv_envs.core.hydrodynamics import HullForceModel
    from auv_envs.core.ops import casadi_ops
    from auv_envs.core.vehicle import PlantPerturbation

    sym = casadi.SX.sym
    qpos, qvel, tau, current, draws = (sym("qpos", 7), sym("qvel", 6), sym("tau", 6),
                                       sym("current", 3), sym("vehicle", 14))
    vehicle = PlantPerturbation.apply(params, draws[0], [draws[1 + k] for k in range(12)],
                                      draws[13])
    q, v = hull_advance(HullForceModel(vehicle, 0, 0), [qpos[k] for k in range(7)],
                        [qvel[k] for k in range(6)], [tau[k] for k in range(6)],
                        [current[k] for k in range(3)], timestep, substeps, casadi_ops())
    return casadi.Function("free_body", [qpos, qvel, tau, current, draws],
                           [casadi.vertcat(*q), casadi.vertcat(*v)], {"cse": True})
