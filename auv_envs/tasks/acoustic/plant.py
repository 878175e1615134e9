"""The acoustic tracking rig on the CPU: the tank's MuJoCo model and the transition's plant.

:func:`compose_tank_model` composes the tank and the carrier with its arm from
``assets/acoustic``; :class:`AcousticPhysics` is the transition's plant on the CPU
(:mod:`auv_envs.tasks.acoustic.transition`), its state the model's ``MjData``.

The plants on the CPU and on JAX (:class:`~auv_envs.tasks.acoustic.mjx_plant.RigPlantMJX`)
differ in three ways, each declared by the plant and read by the transition:

* ``block``: the sample periods simulated and measured at a time. The CPU plant simulates
  :data:`BLOCK` periods and the measurement model draws them together (vectorised over the
  block, many times faster than period by period); the JAX plant one period a step, so
  that the state keeps fixed shapes. The model is the same; the order of the draws is not.
* ``record``: whether the state keeps every estimate and truth (the CPU episode summary's
  record); the JAX plant's state keeps the running sum only.
* ``noise_draws``: the order of the measurement model's draws
  (:meth:`~auv_envs.core.acoustics.HydrophoneArray.measure`): on the CPU the noise of the
  kept detections only (``"kept"``, ``AcousticTracking-v1`` on) or of every path
  (``"all"``, v0); on JAX the fixed-shape order.

So a CPU episode and a batched one from the same key are the same model, not the same
draws; the equivalence tests start both from one plan and compare the source's path
step by step and the detections' statistics.
"""

from __future__ import annotations

import mujoco
import numpy as np
from dm_control import mjcf

from auv_envs.core.acoustics import NOISE_DRAWS
from auv_envs.core.assets import MJCF, asset_path
from auv_envs.core.env import check_choice

#: The rig's integrators (``integrator=``): from v1 on Euler in two 5 ms steps a period,
#: in v0 implicitfast in one 10 ms step; each close to finer integrations of itself
#: (``tests/test_plant_convergence.py``; ``docs/physics.md`` has the figures).
INTEGRATORS = {"euler": mujoco.mjtIntegrator.mjINT_EULER,
               "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}
ARM_JOINTS = ("shoulder_yaw", "shoulder_pitch", "elbow", "wrist_roll", "wrist_pitch",
              "tool_roll")
CARRIER_JOINTS = ("carrier_x", "carrier_y", "carrier_z", "carrier_yaw")
#: Sample periods the CPU plant simulates and measures at a time (0.5 s at 100 Hz).
BLOCK = 50


def build_tank_model() -> mujoco.MjModel:
    """:func:`compose_tank_model`, compiled."""
    return compose_tank_model().compile()


def compose_tank_model() -> MJCF:
    """Compose the tank and the carrier + arm from ``assets/acoustic`` with mjcf."""
    tank = mjcf.from_path(str(asset_path("acoustic/tank.xml")))
    rig = mjcf.from_path(str(asset_path("acoustic/carrier_arm.xml")))
    rig.model = "rig"
    tank.worldbody.attach(rig)
    return MJCF.of(tank)


class AcousticPhysics:
    """The MuJoCo model/data pair with the ids this task needs, resolved once: the
    transition's plant on the CPU.

    Args:
        model: the tank's model (:func:`build_tank_model`).
        noise_draws: the measurement model's draw order (module docstring).
    """

    #: Sample periods simulated and measured at a time (module docstring).
    block = BLOCK
    #: The state keeps every estimate and truth (module docstring).
    record = True

    def __init__(self, model: mujoco.MjModel, noise_draws: str = "kept"):
        check_choice("noise_draws", noise_draws, NOISE_DRAWS)
        #: The measurement model's draw order (module docstring).
        self.noise_draws = noise_draws
        self.model = model
        self.data = mujoco.MjData(model)
        self.source_site = model.site("rig/source").id
        self.hydrophones = np.array(
            [model.site_pos[model.site(f"hydrophone_{i}").id] for i in range(1, 9)]
        )
        self.carrier_qpos = np.array([model.joint(f"rig/{j}").qposadr[0] for j in CARRIER_JOINTS])
        self.arm_qpos = np.array([model.joint(f"rig/{j}").qposadr[0] for j in ARM_JOINTS])
        self.carrier_pos_act = np.array(
            [model.actuator(f"rig/{j}_pos").id for j in CARRIER_JOINTS]
        )
        self.carrier_vel_act = np.array(
            [model.actuator(f"rig/{j}_vel").id for j in CARRIER_JOINTS]
        )
        self.arm_act = np.array([model.actuator(f"rig/{j}").id for j in ARM_JOINTS])
        # The tank as assets/acoustic/tank.xml draws it: the bottom plane spans it.
        bottom = model.geom("bottom")
        self.tank_depth = -float(bottom.pos[2])
        self.tank_size = (2.0 * float(bottom.size[0]), 2.0 * float(bottom.size[1]))
        self._jac = np.zeros((3, model.nv))
        #: Physics steps per sample period.
        self.substeps = 1

    def place(self, carrier, arm):
        """The rig at rest with the carrier's and the arm's joints at ``carrier`` (4) and
        ``arm`` (6) (the transition's plant, :mod:`auv_envs.tasks.acoustic.transition`,
        whose state is this ``MjData``, integrated in place: :mod:`auv_envs.core.task`)."""
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        data.qpos[self.carrier_qpos] = carrier
        data.qpos[self.arm_qpos] = arm
        mujoco.mj_forward(model, data)
        return data

    def follow(self, rig, carrier_ref, carrier_vel, arm_ref, current, start: int):
        """``(rig, positions, velocities)``: the source's positions and velocities (count,
        3) at sample periods ``start``,
        ``start + 1``, ...: the rig moved on one period (``substeps`` physics steps)
        towards each row of the servos' references ((count, 4), (count, 4) and (count,
        6)) in the current of the period before it (MuJoCo's ``wind``, (count, 3) rows:
        row ``j`` is the current from period ``start + j - 1`` to ``start + j``).
        Period 0 is the rig as :meth:`place` left it (that row's references and current
        are unused); later calls continue from the integration state.

        Each physics step is MuJoCo's ``mj_step1`` (positions, velocities and the fluid
        forces in the current) then ``mj_step2`` (the servos' forces, the integration):
        ``mj_step``'s arithmetic, with the source read from the next step's first half
        instead of a further pass over the kinematics.
        """
        model, data = self.model, self.data
        count = len(current)
        ctrl = np.empty((count, model.nu))
        ctrl[:, self.carrier_pos_act] = carrier_ref
        ctrl[:, self.carrier_vel_act] = carrier_vel
        ctrl[:, self.arm_act] = arm_ref
        positions = np.empty((count, 3))
        velocities = np.empty((count, 3))
        # Views into this model and data, taken per call (a copied env has its own).
        wind, data_ctrl, qvel, jac, site = model.opt.wind, data.ctrl, data.qvel, self._jac, \
            self.source_site
        xpos = data.site_xpos[site]
        step1, step2, jac_site = mujoco.mj_step1, mujoco.mj_step2, mujoco.mj_jacSite
        more = range(self.substeps - 1)
        for j in range(count):
            if start + j == 0:
                continue  # period 0: the rig as placed
            wind[:] = current[j]
            step1(model, data)
            if j:  # the state of period start + j - 1, its kinematics current
                positions[j - 1] = xpos
                jac_site(model, data, jac, None, site)
                np.dot(jac, qvel, out=velocities[j - 1])
            data_ctrl[:] = ctrl[j]
            step2(model, data)
            for _ in more:
                step1(model, data)
                step2(model, data)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        positions[-1] = xpos
        jac_site(model, data, jac, None, site)
        np.dot(jac, qvel, out=velocities[-1])
        return rig, positions, velocities

    def source_offset(self, posture) -> np.ndarray:
        """Source position relative to the carrier at yaw 0 in a given arm posture."""
        data = mujoco.MjData(self.model)
        data.qpos[self.arm_qpos] = posture
        mujoco.mj_kinematics(self.model, data)
        return data.site_xpos[self.source_site].copy()
