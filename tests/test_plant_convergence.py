"""The docking plant against an independent reference of its own equations.

``tests/plant_reference.py`` integrates Fossen (2021) eq. 10.1 (full-matrix
C(nu) from M via ``m2c``, quaternion kinematics, RK4 at 2 ms) without any of the
package's hydrodynamics code. Each env here starts the reference from its own
reset state read through ``info`` and sends both 10 s of smooth full-range
surge/sway/heave/yaw commands. Limits (converged physics): 2 cm position,
0.5 deg attitude, 0.01 m/s (rad/s) velocity at the shipped settings, calm and in
the 0.3 m/s current; measured 1e-5 m, 0.001 deg, 1e-4 m/s (docs/physics.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the environments)
from tests.conftest import DOCKING_IDS
from tests.plant_reference import LIMITS, acoustic_truth, env_plant_error

POSITION_LIMIT = LIMITS["position_m"]
ATTITUDE_LIMIT_DEG = LIMITS["attitude_deg"]
VELOCITY_LIMIT = LIMITS["velocity"]
DURATION = 10.0
#: The comparison needs the whole 10 s: no lights-lost failure while the
#: commands turn the vehicle away from the station.
NO_LIGHTS_TIMEOUT = {"lights_lost_timeout": 1e6}


def _make(env_id: str, scenario: str, **kwargs) -> gym.Env:
    return gym.make(env_id, obs_mode="state", scenario=scenario, **NO_LIGHTS_TIMEOUT, **kwargs)


@pytest.mark.parametrize("scenario", ["mismatch", "current"])
@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_shipped_plant_stays_within_limits_of_the_converged_solution(env_id, scenario):
    env = _make(env_id, scenario)
    try:
        for seed in (91001, 91002):
            error = env_plant_error(env, seed=seed, command_seed=seed + 17, duration=DURATION)
            # The whole run is compared (no contact or failure cut it short).
            assert error.steps == round(DURATION / env.unwrapped.dt), error
            assert error.position < POSITION_LIMIT, error
            assert error.attitude_deg < ATTITUDE_LIMIT_DEG, error
            assert error.velocity < VELOCITY_LIMIT, error
            # The limits are small against the motion: the vehicle travels metres.
            assert error.travel > 1.0, error
    finally:
        env.close()


def test_plant_error_falls_at_the_order_of_its_integrator():
    """Halving the plant's step: the v0 plant (semi-implicit Euler) is first order
    (error / 2 per halving); the RK4 plant (v1, and v2 compiled) at least second order.

    MuJoCo's RK4 is fourth order for the velocities but composes the stages'
    angular velocities in the quaternion update, which is second order when the
    rotation axis turns within a step (a free body with unequal inertias); the
    quadratic damping's kink at nu_r = 0 also costs RK4 part of an order. Measured
    per halving: RK4 5.5x and 5.4x, Euler 2.0x.
    """
    errors = {}
    for integrator, substeps in (("rk4", 1), ("rk4", 2), ("rk4", 4),
                                 ("euler", 2), ("euler", 4), ("euler", 8)):
        plant = "compiled" if integrator == "rk4" else "mujoco"  # the v0 plant is MuJoCo's
        env = _make(DOCKING_IDS[0], "current", integrator=integrator, physics_substeps=substeps,
                    plant=plant)
        try:
            error = env_plant_error(env, seed=91003, command_seed=91020, duration=5.0)
        finally:
            env.close()
        assert error.steps == 50
        errors[integrator, substeps] = error.position
    for k in (1, 2):
        assert errors["rk4", k] / errors["rk4", 2 * k] > 3.5, errors
    for k in (2, 4):
        assert 1.6 < errors["euler", k] / errors["euler", 2 * k] < 2.5, errors
    # The v0 plant (euler, 2 substeps) is centimetres off; v1 a thousand times closer.
    assert errors["euler", 2] > 1e3 * errors["rk4", 1]


def test_v0_ids_keep_the_first_plant():
    """``-v0`` still integrates as the first release did (semi-implicit Euler,
    two 0.05 s steps): states recorded with that release's code (commit fd64f73)."""
    recorded = json.loads((Path(__file__).parent / "data" / "docking_v0_plant.json").read_text())
    for run in recorded["runs"]:
        env = gym.make(run["env_id"], obs_mode="state", scenario=run["scenario"])
        try:
            env.reset(seed=run["seed"])
            states = []
            for action in np.array(run["actions"], dtype=np.float32):
                _, _, _, _, info = env.step(action)
                states.append(np.concatenate(
                    [info["true_position"], info["true_euler"], info["true_velocity"]]))
        finally:
            env.close()
        # Round-off only: the wrench now enters as a generalized force, not xfrc_applied.
        np.testing.assert_allclose(np.array(states), np.array(run["states"]), rtol=0, atol=1e-11)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_seabed_contact_still_ends_the_episode(env_id):
    """Full downward thrust: the episode ends with a seabed failure when the hull
    reaches the seabed, not before and not after passing through it."""
    env = gym.make(env_id, obs_mode="state")
    try:
        _, info = env.reset(seed=91005)
        seabed = env.unwrapped.calibration.seabed_z
        radius = env.unwrapped.vehicle.diameter / 2.0
        for _ in range(600):
            _, _, terminated, truncated, info = env.step(np.array([0, 0, -1, 0], np.float32))
            if terminated or truncated:
                break
    finally:
        env.close()
    assert terminated and not truncated
    assert info["failure_reason"] == "seabed" and info["violation_seabed"]
    # Level hull (roll, pitch small): its lowest point is within a few cm of the seabed.
    lowest = info["true_position"][2] - radius
    assert seabed - 0.05 < lowest <= seabed + 1e-9, (lowest, seabed)


def test_acoustic_plant_is_close_to_a_finer_integration_of_itself():
    """The acoustic arm (MuJoCo's own fluid model, Euler in two 5 ms steps a 0.01 s sample
    period) is a hydrodynamic plant too: its end effector stays within the same 2 cm of
    a 16x finer integration (measured 1.7-11 mm over 20 s in every current level,
    ``docs/physics.md``)."""
    shipped, finer, finest = (acoustic_truth("high", 95002, 10.0, n) for n in (1, 4, 16))
    error = np.linalg.norm(shipped - finest, axis=1).max()
    assert error < POSITION_LIMIT, error
    assert np.linalg.norm(finer - finest, axis=1).max() < error / 3.0
    assert np.linalg.norm(shipped - shipped[0], axis=1).max() > 1.0  # it moved metres
