"""Tests of the independent reference integrator in :mod:`tests.plant_reference` itself.

Each test checks the reference against a closed-form property of Fossen (2021) eq. 10.1
(conservation laws, terminal speed, drift with the current, small-angle roll period, frames,
RK4's convergence order), so that the reference can be trusted as an oracle for the plant.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from auv_envs.core.frames import rotation_from_euler
from auv_envs.core.vehicle import hovering_auv
from tests.plant_reference import (
    derivatives,
    rotation_from_quat,
    simulate,
    smooth_commands,
)

ZERO6 = (0.0,) * 6


def neutral(**changes):
    """``hovering_auv()`` with W = B, plus ``changes``."""
    return dataclasses.replace(hovering_auv(), net_buoyancy=0.0, **changes)


def total_inertia(params) -> np.ndarray:
    return np.diag([params.mass] * 3 + list(params.inertia)) + np.diag(params.added_mass)


def test_free_motion_conserves_energy_and_impulse():
    """No damping, no restoring, tau = 0: C is skew-symmetric (no work) and Kirchhoff's
    linear and angular impulses are constant in the world frame (this also fixes C's sign)."""
    params = neutral(cb_offset=(0.0, 0.0, 0.0), linear_damping=ZERO6, quadratic_damping=ZERO6)
    mass = total_inertia(params)
    traj = simulate(
        params, (0.3, -0.2, 0.1), (0.2, -0.1, 0.5), (0.5, -0.3, 0.2, 0.6, -0.4, 0.8),
        np.zeros((50, 6)), period=0.1, step=0.005,
    )  # fmt: skip
    energy = np.array([0.5 * nu @ mass @ nu for nu in traj.velocity])
    assert np.abs(energy / energy[0] - 1.0).max() < 1e-9
    impulse = []
    for p, q, nu in zip(traj.position, traj.quaternion, traj.velocity, strict=True):
        rot = rotation_from_quat(q)
        linear = rot @ (mass[:3, :3] @ nu[:3])
        impulse.append(
            np.concatenate((linear, rot @ (mass[3:, 3:] @ nu[3:]) + np.cross(p, linear)))
        )
    impulse = np.array(impulse)
    assert np.abs(impulse - impulse[0]).max() < 1e-9 * np.abs(impulse[0]).max()
    # The motion is not trivial: the coupling moved energy between the degrees of freedom.
    assert np.abs(traj.velocity[-1] - traj.velocity[0]).max() > 0.1


@pytest.mark.parametrize("force", [80.0, -80.0])
def test_surge_reaches_terminal_velocity(force):
    """``dl u + dq |u| u = X`` at the terminal speed (the sign checks the ``|nu_r|``)."""
    params = neutral()
    dl, dq = params.linear_damping[0], params.quadratic_damping[0]
    terminal = (-dl + math.sqrt(dl * dl + 4.0 * dq * abs(force))) / (2.0 * dq)
    commands = np.tile([force, 0, 0, 0, 0, 0], (40, 1))
    traj = simulate(params, (0, 0, 0), (0, 0, 0), ZERO6, commands, period=1.0, step=0.05)
    assert traj.velocity[-1, 0] == pytest.approx(math.copysign(terminal, force), abs=1e-4)
    assert np.abs(traj.velocity[:, 1:]).max() < 1e-12
    assert np.abs(traj.position[:, 1:]).max() < 1e-12


def test_vehicle_drifts_with_uniform_current():
    """At rest relative to the water, the vehicle moves with the current even while spinning:
    the linear part of nu_r stays zero only if the M_A nu_c_dot term is right (A is anisotropic)."""
    params = neutral()  # W = B, CB above CG, full damping
    current = np.array([0.5, -0.3, 0.1])
    euler = (0.1, -0.2, 0.7)
    rot0 = rotation_from_euler(*euler, np)
    nu0 = np.concatenate((rot0.T @ current, [0.3, -0.2, 0.6]))
    traj = simulate(
        params, (1.0, 2.0, -3.0), euler, nu0, np.zeros((50, 6)), period=0.1,
        current_world=current, step=0.005,
    )  # fmt: skip
    for q, nu in zip(traj.quaternion, traj.velocity, strict=True):  # RK4 error only
        np.testing.assert_allclose(nu[:3], rotation_from_quat(q).T @ current, atol=1e-9)
    expected = np.array([1.0, 2.0, -3.0]) + traj.times[:, None] * current
    np.testing.assert_allclose(traj.position, expected, atol=1e-9)
    assert np.abs(traj.velocity[-1, 3:] - nu0[3:]).max() > 0.1  # it did spin


def test_small_roll_period():
    params = neutral(linear_damping=ZERO6, quadratic_damping=ZERO6)
    zb = params.cb_offset[2]
    omega = math.sqrt(params.buoyancy * zb / (params.inertia[0] + params.added_mass[3]))
    traj = simulate(params, (0, 0, 0), (0.02, 0, 0), ZERO6, np.zeros((500, 6)), 0.01, step=0.005)
    roll, t = traj.euler[:, 0], traj.times
    idx = np.nonzero(np.sign(roll[:-1]) != np.sign(roll[1:]))[0]
    crossings = t[idx] - roll[idx] * (t[idx + 1] - t[idx]) / (roll[idx + 1] - roll[idx])
    assert len(crossings) >= 10
    period = 2.0 * (crossings[-1] - crossings[0]) / (len(crossings) - 1)
    assert period == pytest.approx(2.0 * math.pi / omega, rel=1e-3)
    assert np.abs(traj.euler[:, 1:]).max() < 1e-12


def test_body_surge_at_yaw_90_moves_along_world_y():
    yaw = math.pi / 2
    commands = np.tile([60.0, 0, 0, 0, 0, 0], (30, 1))
    traj = simulate(hovering_auv(), (0, 0, 0), (0, 0, yaw), ZERO6, commands, 0.1, step=0.01)
    np.testing.assert_allclose(traj.euler[0], (0.0, 0.0, yaw), atol=1e-15)
    assert traj.position[-1, 1] > 0.3
    assert abs(traj.position[-1, 0]) < 1e-9
    assert traj.position[-1, 2] > 0.0  # 10 N net buoyancy lifts it
    assert traj.euler[-1, 2] == pytest.approx(yaw, abs=1e-9)


def _convergence_errors(params, current, duration):
    commands = smooth_commands(np.random.default_rng(0), duration, 0.1, params.thrust_limits)
    runs = {
        h: simulate(params, (0, 0, 0), (0, 0, 0), ZERO6, commands, 0.1, current, step=h)
        for h in (0.001, 0.02, 0.01, 0.005)
    }

    def error(h):
        ref = runs[0.001]
        return max(
            np.abs(runs[h].position - ref.position).max(),
            np.abs(runs[h].velocity - ref.velocity).max(),
        )

    return [error(h) for h in (0.02, 0.01, 0.005)]


def test_rk4_fourth_order_convergence():
    """Quadratic damping is off here: ``d |nu_r| nu_r`` is only C^1 at nu_r = 0, which lowers
    RK4's observed order toward 3 at each zero crossing (checked in the next test)."""
    params = dataclasses.replace(hovering_auv(), quadratic_damping=ZERO6)
    errors = _convergence_errors(params, (0.3, 0.2, 0.0), duration=10.0)
    assert errors[0] > 1e-9  # above round-off, so the ratios mean something
    assert errors[0] / errors[1] > 8.0
    assert errors[1] / errors[2] > 8.0


def test_full_model_converges():
    errors = _convergence_errors(hovering_auv(), (0.5, 0.0, 0.0), duration=5.0)
    assert errors[0] / errors[1] > 6.0
    assert errors[1] / errors[2] > 6.0
    assert errors[2] < 1e-8


def test_smooth_commands_span_the_limits():
    limits = hovering_auv().thrust_limits
    commands = smooth_commands(np.random.default_rng(3), 20.0, 0.1, limits)
    again = smooth_commands(np.random.default_rng(3), 20.0, 0.1, limits)
    assert commands.shape == (200, 6)
    np.testing.assert_array_equal(commands, again)
    assert not commands[:, 3:5].any()
    peaks = np.abs(commands[:, [0, 1, 2, 5]]).max(axis=0)
    np.testing.assert_allclose(peaks, limits)
    assert np.all(np.abs(np.diff(commands, axis=0)).max(axis=0)[[0, 1, 2, 5]] < 0.3 * peaks)


def test_period_must_be_a_multiple_of_step():
    with pytest.raises(ValueError, match="multiple"):
        simulate(hovering_auv(), (0, 0, 0), (0, 0, 0), ZERO6, np.zeros((2, 6)), 0.0015)


def test_derivatives_at_rest_is_net_buoyancy():
    params = hovering_auv()
    state = np.concatenate((np.zeros(3), [1.0, 0, 0, 0], np.zeros(6)))
    rate = derivatives(params, state, ZERO6, (0.0, 0.0, 0.0))
    heave = params.net_buoyancy / (params.mass + params.added_mass[2])
    np.testing.assert_allclose(rate, np.r_[np.zeros(9), heave, np.zeros(3)], atol=1e-12)
