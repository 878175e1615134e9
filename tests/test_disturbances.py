"""Docking disturbance models: Gauss–Markov current, plant perturbation, thruster lag."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest

from auv_envs.core.ops import FLOATS
from auv_envs.core.sea import GaussMarkovCurrent, current_vector
from auv_envs.core.vehicle import PlantPerturbation, hovering_auv, thruster_lag_gain
from auv_envs.tasks.docking.env import DockingDisturbances
from tests.conftest import DOCKING_IDS
from tests.plant_reference import LIMITS, env_plant_error

DOCK = DOCKING_IDS[0]


# ------------------------------------------------------------------ current process
def _simulate(process: GaussMarkovCurrent, mean: tuple[float, float], dt: float, n: int,
              seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    state = process.start(*mean, rng, FLOATS)
    out = np.empty((n, 2))
    for k in range(n):
        state = process.advance(*state, *mean, dt, rng, FLOATS)
        out[k] = state
    return out


def _autocorrelation(x: np.ndarray, lag: int) -> float:
    x = x - x.mean()
    return float(np.dot(x[:-lag], x[lag:]) / np.dot(x, x))


def test_current_statistics_match_the_gauss_markov_parameters():
    process = GaussMarkovCurrent(speed_std=0.04, direction_std_deg=15.0, time_constant=5.0)
    dt = 0.1
    series = _simulate(process, (0.3, 1.0), dt, 200_000)  # 20,000 s, 4,000 time constants
    speed, direction = series[:, 0], series[:, 1]
    assert speed.mean() == pytest.approx(0.3, abs=0.003)
    assert speed.std() == pytest.approx(0.04, rel=0.03)
    assert direction.mean() == pytest.approx(1.0, abs=0.02)
    assert np.degrees(direction.std()) == pytest.approx(15.0, rel=0.03)
    # First-order Gauss–Markov: autocorrelation exp(-lag dt / T).
    for lag in (1, 10, 50):
        expected = math.exp(-lag * dt / process.time_constant)
        assert _autocorrelation(speed, lag) == pytest.approx(expected, abs=0.02)
        assert _autocorrelation(direction, lag) == pytest.approx(expected, abs=0.02)


def test_current_discretisation_is_exact_whatever_the_period():
    # The same process sampled every 0.1 s or every 1 s: the same stationary spread
    # and the same correlation per second.
    process = GaussMarkovCurrent(speed_std=0.05, direction_std_deg=0.0, time_constant=4.0)
    fine = _simulate(process, (0.5, 0.0), 0.1, 100_000, seed=1)[:, 0]
    coarse = _simulate(process, (0.5, 0.0), 1.0, 100_000, seed=2)[:, 0]
    assert fine.std() == pytest.approx(coarse.std(), rel=0.03)
    assert _autocorrelation(fine, 10) == pytest.approx(_autocorrelation(coarse, 1), abs=0.02)
    assert np.isfinite(fine).all()
    assert _simulate(process, (0.5, 0.0), 0.1, 10, seed=3)[:, 1].tolist() == [0.0] * 10


def test_current_speed_is_saturated():
    process = GaussMarkovCurrent(speed_std=0.5, time_constant=1.0, max_speed=0.6)
    speed = _simulate(process, (0.2, 0.0), 0.1, 20_000)[:, 0]
    assert speed.min() == 0.0 and speed.max() == 0.6


def test_inactive_current_draws_nothing():
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    process = GaussMarkovCurrent()
    assert not process.active
    assert process.start(0.3, 1.0, rng, FLOATS) == (0.3, 1.0)
    assert rng.bit_generator.state == state
    np.testing.assert_allclose(current_vector(0.3, math.pi / 2), [0.0, 0.3, 0.0], atol=1e-15)


@pytest.mark.parametrize("kwargs", [{"speed_std": -0.1}, {"time_constant": 0.0},
                                    {"direction_std_deg": math.nan}, {"max_speed": math.inf}])
def test_current_rejects_bad_parameters(kwargs):
    with pytest.raises(ValueError):
        GaussMarkovCurrent(**kwargs)


# ------------------------------------------------------------------ plant and thrusters
def test_plant_perturbation_draws_within_its_ranges():
    nominal = hovering_auv()
    spec = PlantPerturbation(mass=0.1, damping=0.3, net_buoyancy=5.0)
    rng = np.random.default_rng(4)
    for _ in range(50):
        vehicle, draws = spec.draw(nominal, rng)
        assert 0.9 <= draws["mass_scale"] <= 1.1
        assert vehicle.mass == pytest.approx(nominal.mass * draws["mass_scale"])
        assert vehicle.inertia == pytest.approx(
            tuple(i * draws["mass_scale"] for i in nominal.inertia))
        assert vehicle.added_mass == nominal.added_mass  # the hull's shape is unchanged
        for key, nominal_values, values in (
                ("linear_damping_scale", nominal.linear_damping, vehicle.linear_damping),
                ("quadratic_damping_scale", nominal.quadratic_damping,
                 vehicle.quadratic_damping)):
            assert all(0.7 <= f <= 1.3 for f in draws[key])
            assert values == pytest.approx(
                tuple(v * f for v, f in zip(nominal_values, draws[key], strict=True)))
        assert abs(draws["net_buoyancy_offset"]) <= 5.0
        assert vehicle.net_buoyancy == pytest.approx(10.0 + draws["net_buoyancy_offset"])
    assert PlantPerturbation().draw(nominal, rng) == (nominal, {})


@pytest.mark.parametrize("kwargs", [{"mass": -0.1}, {"mass": 0.6}, {"damping": 1.0},
                                    {"net_buoyancy": math.nan}])
def test_plant_perturbation_rejects_bad_ranges(kwargs):
    with pytest.raises(ValueError):
        PlantPerturbation(**kwargs)


def test_thruster_lag_gain():
    assert thruster_lag_gain(0.0, 0.1) == 1.0
    assert thruster_lag_gain(0.5, 0.1) == pytest.approx(1 - math.exp(-0.2))
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            thruster_lag_gain(bad, 0.1)


# ------------------------------------------------------------------ in the environment
def _rollout(env, seed: int, steps: int = 40):
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, info)]
    for k in range(steps):
        action = np.array([0.8, 0.2 * math.sin(k / 5), -0.1, 0.3 * math.cos(k / 7)])
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, info))
        if terminated or truncated:
            break
    return out


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return bool(np.array_equal(np.asarray(a), np.asarray(b)))


@pytest.mark.parametrize("scenario", ["mismatch", "current"])
def test_no_disturbances_is_the_release_bit_for_bit(scenario):
    plain = gym.make(DOCK, obs_mode="features", scenario=scenario)
    explicit = gym.make(DOCK, obs_mode="features", scenario=scenario,
                        disturbances=DockingDisturbances())
    for (o1, r1, i1), (o2, r2, i2) in zip(_rollout(plain, 3), _rollout(explicit, 3),
                                          strict=True):
        assert _same(o1, o2) and r1 == r2 and _same(i1, i2)
    assert "plant" not in i1 and "thrust" not in i1
    assert plain.unwrapped.np_random.bit_generator.state == \
        explicit.unwrapped.np_random.bit_generator.state


def test_varying_current_acts_on_the_vehicle_and_is_reported():
    disturbances = DockingDisturbances(current=GaussMarkovCurrent(
        speed_std=0.08, direction_std_deg=0.0, time_constant=3.0))
    env = gym.make(DOCK, obs_mode="state", scenario="current", current_direction=90.0,
                   disturbances=disturbances)
    steady = gym.make(DOCK, obs_mode="state", scenario="current", current_direction=90.0)
    assert env.unwrapped.calibration.disturbances == disturbances
    trace = _rollout(env, 5, steps=200)
    currents = np.array([info["current"] for _, _, info in trace])
    speeds = np.linalg.norm(currents, axis=1)
    assert speeds.std() > 0.02 and 0.0 <= speeds.min() and speeds.max() <= 1.5
    np.testing.assert_allclose(currents[:, 0], 0.0, atol=1e-12)  # direction held at 90 deg
    # The state observation carries the current that acted (its last three entries).
    np.testing.assert_allclose(trace[-1][0][13:], currents[-1], atol=1e-6)
    # It moves the vehicle differently from the steady 0.3 m/s current.
    final = trace[-1][2]["true_position"]
    steady_final = _rollout(steady, 5, steps=len(trace) - 1)[-1][2]["true_position"]
    assert np.linalg.norm(final - steady_final) > 0.05


def test_thrust_follows_the_command_with_the_first_order_lag():
    tau = 0.5
    env = gym.make(DOCK, obs_mode="state",
                   disturbances=DockingDisturbances(thruster_time_constant=tau))
    env.reset(seed=2)
    limit = env.unwrapped.calibration.thrust_limits[0]
    gain = 1 - math.exp(-0.1 / tau)
    thrust = []
    for _ in range(10):
        *_, info = env.step(np.array([1.0, 0.0, 0.0, 0.0]))
        thrust.append(info["thrust"][0])
    expected = [limit * (1 - (1 - gain) ** k) for k in range(1, 11)]
    np.testing.assert_allclose(thrust, expected, rtol=1e-12)
    assert thrust[4] == pytest.approx(limit * (1 - math.exp(-1)))  # 63 % after one T
    # A slower start than the ideal thrusters.
    ideal = gym.make(DOCK, obs_mode="state")
    ideal.reset(seed=2)
    for _ in range(10):
        *_, ideal_info = ideal.step(np.array([1.0, 0.0, 0.0, 0.0]))
    assert ideal_info["true_velocity"][0] > info["true_velocity"][0]


def test_perturbed_plant_is_simulated_and_integrated_correctly():
    spec = PlantPerturbation(mass=0.2, damping=0.5, net_buoyancy=20.0)
    env = gym.make(DOCK, obs_mode="state", disturbances=DockingDisturbances(plant=spec))
    nominal = env.unwrapped.calibration.nominal_params
    _, info = env.reset(seed=8)
    vehicle = env.unwrapped.vehicle
    assert vehicle != hovering_auv() and vehicle.mass == pytest.approx(
        hovering_auv().mass * info["plant"]["mass_scale"])
    assert env.unwrapped.calibration.nominal_params == nominal  # the controller's model stays
    model = env.unwrapped.physics.model
    assert model.body_mass[env.unwrapped.physics.hull_body] == vehicle.mass
    # The plant integrates the perturbed equations: the independent reference with the
    # episode's parameters agrees to the usual limits...
    error = env_plant_error(env, seed=8, command_seed=3, duration=5.0)
    assert error.position < LIMITS["position_m"] and error.velocity < LIMITS["velocity"]
    assert error.attitude_deg < LIMITS["attitude_deg"]
    # ...and a new episode draws a new vehicle.
    env.reset(seed=9)
    assert env.unwrapped.vehicle != vehicle


def test_perturbed_episode_survives_pickling():
    spec = DockingDisturbances(plant=PlantPerturbation(mass=0.2, damping=0.4),
                               current=GaussMarkovCurrent(speed_std=0.05),
                               thruster_time_constant=0.3)
    env = gym.make(DOCK, obs_mode="features", scenario="current", disturbances=spec).unwrapped
    env.reset(seed=6)
    for _ in range(5):
        env.step(np.array([0.5, 0.1, 0.0, 0.2]))
    clone = pickle.loads(pickle.dumps(env))
    assert clone.vehicle == env.vehicle
    for _ in range(20):
        a, b = env.step(np.array([0.6, -0.1, 0.1, 0.0])), clone.step(
            np.array([0.6, -0.1, 0.1, 0.0]))
        assert _same(a[0], b[0]) and a[1] == b[1] and _same(a[4], b[4])


def test_disturbances_argument_is_checked():
    with pytest.raises(TypeError, match="DockingDisturbances"):
        gym.make(DOCK, disturbances={"thruster_time_constant": 1.0})
    with pytest.raises(ValueError):
        DockingDisturbances(thruster_time_constant=-1.0)
    with pytest.raises(TypeError):
        DockingDisturbances(current=0.3)
    with pytest.raises(TypeError):
        DockingDisturbances(plant=0.1)
