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

from collections.abc import Callable

import mujoco
import numpy as np

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
