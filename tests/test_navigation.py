"""Navigation sensors: their statistics against their stated models, the USBL fix
against the Cramer-Rao bound of its array, the fix schedule, and the ``nav`` modes."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest
from scipy import stats

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.core import frames
from auv_envs.core.ops import FLOATS, jax_ops
from auv_envs.tasks.docking.navigation import (
    AHRS,
    DVL,
    USBL,
    USBL_ACOUSTICS,
    DepthSensor,
    Navigation,
    NavigationSensors,
)

C = USBL_ACOUSTICS.sound_speed
QUIET = dataclasses.replace(USBL_ACOUSTICS, sound_speed_error_std=0.0)
#: A transceiver 10 m up, turned 0.4 rad, and a transponder 160 m away, between the surface
#: (z = 50) and the bottom (z = -2).
YAW = 0.4
ROWS = np.array(frames.rotation_rows(0.0, 0.0, YAW, FLOATS))
TRANSCEIVER = np.array([0.0, 0.0, 10.0])
TRANSPONDER = np.array([150.0, 60.0, 0.0])
TRUE_FIX = (TRANSPONDER - TRANSCEIVER) @ ROWS  # body axes


def fixes(usbl: USBL, n: int, seed: int, sound_speed: float = C) -> tuple[np.ndarray, np.ndarray]:
    array = usbl.array(50.0, -2.0)
    rng = np.random.default_rng(seed)
    out = [usbl.fix(array, TRANSCEIVER, ROWS, TRANSPONDER, sound_speed, rng, np) for _ in range(n)]
    return np.array([v for v, _ in out]), np.array([f for _, f in out])


def test_usbl_fix_is_efficient_against_the_cramer_rao_bound():
    """Errors of noise-only fixes: unbiased, and their covariance's trace within 10 % of the
    Cramer-Rao bound of the four elements' arrival times (each with the acoustic model's
    timing standard deviation at its SNR), which the plane-wave fit reaches."""
    usbl = USBL(acoustics=QUIET)
    vectors, found = fixes(usbl, 4000, seed=11)
    assert found.all()
    errors = vectors - TRUE_FIX
    array = usbl.array(50.0, -2.0)
    offsets = TRUE_FIX - np.asarray(usbl.elements)
    ranges = np.linalg.norm(offsets, axis=1)
    snr = array.snr_db(ranges[None, :], array.path_loss[:1], xp=np)
    sigma = array.noise_std(snr, np.ones_like(snr), np)[0][0, 0]  # (4,) s
    units = offsets / ranges[:, None]
    information = sum(np.outer(u, u) / (C * s) ** 2 for u, s in zip(units, sigma, strict=True))
    bound = np.trace(np.linalg.inv(information))
    ratio = np.trace(np.cov(errors.T)) / bound
    assert 0.9 < ratio < 1.1, ratio
    # Nearly unbiased: normalising a noisy direction shortens it by about half the squared
    # bearing error (1e-4 here, 2 cm at 160 m), against 2.4 m of noise.
    assert np.linalg.norm(errors.mean(axis=0)) < 0.02 * math.sqrt(bound)


def test_usbl_sound_speed_error_scales_the_range():
    """Water faster than the nominal speed: the fix's range shrinks by c_nominal / c_true."""
    usbl = USBL(acoustics=QUIET)
    true_speed = C * 1.004
    vectors, _ = fixes(usbl, 1000, seed=12, sound_speed=true_speed)
    measured = np.linalg.norm(vectors, axis=1).mean()
    expected = np.linalg.norm(TRUE_FIX - np.mean(usbl.elements, axis=0)) * C / true_speed
    assert measured == pytest.approx(expected, abs=0.05)
    assert abs(measured - np.linalg.norm(TRUE_FIX)) > 0.5  # a 0.4 % error is 0.65 m here


def test_usbl_shadowed_direct_path_fixes_the_nearest_mirror_image():
    """With the direct path always shadowed the fix is the nearer mirror image (the
    bottom's, 2 m below the transponder, against the surface's 50 m above)."""
    usbl = USBL(acoustics=QUIET.noise_free(), shadowing=1.0)
    vectors, found = fixes(usbl, 5, seed=13)
    assert found.all()
    image = np.array([TRANSPONDER[0], TRANSPONDER[1], 2 * -2.0 - TRANSPONDER[2]])
    expected = (image - TRANSCEIVER) @ ROWS
    np.testing.assert_allclose(vectors, np.broadcast_to(expected, vectors.shape), atol=1e-6)


def test_usbl_outliers_are_uniform_in_range_and_direction():
    usbl = USBL(acoustics=QUIET, outlier_rate=1.0, max_range=500.0)
    vectors, found = fixes(usbl, 2000, seed=14)
    assert found.all()
    ranges = np.linalg.norm(vectors, axis=1)
    assert stats.kstest(ranges, stats.uniform(0, 500).cdf).pvalue > 1e-3
    cos_polar = vectors[:, 2] / ranges
    assert stats.kstest(cos_polar, stats.uniform(-1, 2).cdf).pvalue > 1e-3


def test_usbl_noise_free_fix_is_exact():
    usbl = USBL(acoustics=QUIET.noise_free())
    vectors, _ = fixes(usbl, 3, seed=15)
    np.testing.assert_allclose(vectors, np.broadcast_to(TRUE_FIX, vectors.shape), atol=1e-6)


def test_dvl_statistics_validity_and_dropouts():
    dvl = DVL(noise_std=0.02, scale_std=0.01, min_altitude=0.5, max_altitude=30.0, dropout=0.1)
    rng = np.random.default_rng(21)
    scales = np.array([dvl.draw_scale(rng, FLOATS) for _ in range(3000)])
    assert np.std(scales) == pytest.approx(0.01, rel=0.05)
    velocity = np.array([1.0, -0.5, 0.2])
    scale = np.array([0.01, -0.02, 0.0])
    readings, valid = zip(*(dvl.read(velocity, 10.0, scale, rng, FLOATS) for _ in range(5000)),
                          strict=True)
    readings, valid = np.array(readings), np.array(valid)
    assert stats.binomtest(int((~valid).sum()), len(valid), 0.1).pvalue > 1e-3
    errors = readings[valid] - (1 + scale) * velocity
    assert np.abs(errors.mean(axis=0)).max() < 4 * 0.02 / math.sqrt(valid.sum())
    assert np.std(errors) == pytest.approx(0.02, rel=0.05)
    assert np.all(readings[~valid] == 0.0)
    for altitude in (0.4, 30.5):  # out of bottom lock
        reading, ok = DVL(min_altitude=0.5, max_altitude=30.0).read(velocity, altitude,
                                                                    scale, rng, FLOATS)
        assert not ok and np.all(np.asarray(reading) == 0.0)


def test_ahrs_noise_and_gyro_bias_random_walk():
    ahrs = AHRS(roll_pitch_std=0.01, heading_std=0.02, rate_noise_density=0.003,
                bias_instability=0.001, bias_time=50.0)
    rng = np.random.default_rng(22)
    dt = 0.1
    euler, rates = (0.1, -0.2, 3.0), (0.05, 0.0, -0.1)
    bias0 = np.zeros(3)
    out = [ahrs.read(euler, rates, bias0, dt, rng, FLOATS, 0.0) for _ in range(6000)]
    attitude = np.array([a for a, _, _ in out])
    error = attitude - euler
    error[:, 2] = frames.wrap_angle(error[:, 2])
    np.testing.assert_allclose(error.std(axis=0), [0.01, 0.01, 0.02], rtol=0.05)
    rate_error = np.array([r for _, r, _ in out]) - rates
    np.testing.assert_allclose(rate_error.std(axis=0), 0.003 / math.sqrt(dt), rtol=0.05)
    # The bias wanders: its increments over k steps have variance k (b^2 dt / T).
    steps = np.array([b for _, _, b in out])
    variance = ahrs.bias_instability ** 2 * dt / ahrs.bias_time
    assert np.var(steps) == pytest.approx(variance, rel=0.05)
    walk = bias0
    for _ in range(2000):
        walk = ahrs.read(euler, rates, walk, dt, rng, FLOATS, 0.0)[2]
    assert np.all(np.isfinite(walk))
    assert len(ahrs.draw_bias(rng, FLOATS)) == 3


def test_ahrs_heading_deviation_is_drawn_once_per_episode():
    """The heading's deviation from the station's frame is one draw per episode, with
    ``heading_bias_std``, carried through every step; with 0 nothing is drawn (the
    presets without it keep their streams)."""
    quiet = dict(roll_pitch_std=0.0, heading_std=0.0, rate_noise_density=0.0,
                 bias_instability=0.0)
    suite = dataclasses.replace(_exact_suite(), ahrs=AHRS(heading_bias_std=0.1, **quiet))
    nav = Navigation(suite, seabed_z=-20.0, dt=0.1)
    truth = {"position": (-20.0, 0.0, 0.0), "euler": (0.0, 0.0, 3.1),
             "velocity": [0.0] * 6, "seabed_clearance": 15.0}
    deviations = []
    for seed in range(400):
        rng = np.random.default_rng(seed)
        state = nav.start(truth, rng, FLOATS)
        first = float(frames.wrap_angle(state.attitude[2] - 3.1))
        for k in range(1, 4):
            state = nav.advance(state, truth, 0.1 * k, rng, FLOATS)
            assert float(frames.wrap_angle(state.attitude[2] - 3.1)) == pytest.approx(first)
        assert float(state.heading_bias) == pytest.approx(first)
        deviations.append(first)
    assert np.std(deviations) == pytest.approx(0.1, rel=0.12)
    assert abs(np.mean(deviations)) < 4 * 0.1 / math.sqrt(400)
    # No deviation: no draw, so the generator is where it was.
    rng = np.random.default_rng(5)
    before = rng.bit_generator.state
    assert float(AHRS(**quiet).draw_heading_bias(rng, FLOATS)) == 0.0
    assert rng.bit_generator.state == before
    AHRS(heading_bias_std=0.1, **quiet).draw_heading_bias(rng, FLOATS)
    assert rng.bit_generator.state != before

def test_depth_noise_and_resolution():
    sensor = DepthSensor(noise_std=0.05, resolution=0.01)
    rng = np.random.default_rng(23)
    readings = np.array([sensor.read(12.3456, rng, FLOATS) for _ in range(5000)])
    np.testing.assert_allclose(readings / 0.01, np.round(readings / 0.01), atol=1e-6)
    assert readings.std() == pytest.approx(0.05, rel=0.05)
    assert readings.mean() == pytest.approx(12.3456, abs=4 * 0.05 / math.sqrt(5000) + 0.005)


@pytest.mark.parametrize("kwargs", [{"noise_std": -1.0}, {"dropout": 2.0},
                                    {"min_altitude": 5.0, "max_altitude": 1.0},
                                    {"noise_std": math.nan}])
def test_bad_dvl_parameters_raise(kwargs):
    with pytest.raises(ValueError):
        DVL(**kwargs)


def test_bad_suite_raises():
    with pytest.raises(TypeError):
        NavigationSensors(dvl="fast")
    with pytest.raises(ValueError):
        NavigationSensors(transponder=(0.0, 1.0))
    with pytest.raises(ValueError):
        USBL(period=0.0)
    with pytest.raises(TypeError, match="NavigationSensors"):
        gym.make("auv_envs/DockingStation-v2", obs_mode="nav", navigation={"dvl": None})


def _exact_suite() -> NavigationSensors:
    return NavigationSensors(
        dvl=DVL(noise_std=0.0, scale_std=0.0),
        ahrs=AHRS(roll_pitch_std=0.0, heading_std=0.0, rate_noise_density=0.0,
                  bias_instability=0.0),
        depth=DepthSensor(noise_std=0.0, resolution=0.0),
        usbl=USBL(acoustics=QUIET.noise_free(), processing_delay=0.25))


def test_fix_schedule_and_age():
    """Pings every period; a fix arrives after its two-way travel time and the processing
    delay and is then observed with its age."""
    nav = Navigation(_exact_suite(), seabed_z=-2.0, dt=0.1)
    truth = {"position": (-20.0, 0.0, 0.0), "euler": (0.0, 0.0, 0.0),
             "velocity": [0.0] * 6, "seabed_clearance": 1.5}
    rng = np.random.default_rng(24)
    state = nav.start(truth, rng, FLOATS)
    ages, valid = [], []
    for k in range(1, 31):
        state = nav.advance(state, truth, k * 0.1, rng, FLOATS)
        obs = Navigation.observation(state, k * 0.1, FLOATS)
        ages.append(float(obs["usbl_age"][0]))
        valid.append(int(obs["usbl_valid"][0]))
    travel = 2 * math.dist((-20.0, 0.0, 0.0), (0.5, 0.0, 1.0)) / C  # 0.027 s
    first = math.ceil((travel + 0.25) / 0.1 - 1e-9)  # the step the first fix arrives
    assert valid[:first - 1] == [0] * (first - 1) and all(valid[first - 1:])
    # Age since the ping at 0 s, then since the ping at 1 s once that fix arrives.
    np.testing.assert_allclose(ages[first - 1:10 + first - 1],
                               0.1 * np.arange(first, first + 10), atol=1e-6)
    assert ages[10 + first - 1] == pytest.approx(0.1 * first, abs=1e-6)
    expected = np.array([0.5, 0.0, 1.0]) - np.array([-20.0, 0.0, 0.0])
    np.testing.assert_allclose(obs["usbl"], expected, atol=1e-5)


@pytest.mark.parametrize("env_id", ["auv_envs/DockingStation-v2",
                                    "auv_envs/LampArrayDocking-v2"])
def test_nav_modes_read_the_truth_through_exact_sensors(env_id):
    env = gym.make(env_id, obs_mode="nav_features", navigation=_exact_suite())
    obs, info = env.reset(seed=3)
    env.action_space.seed(3)
    station_depth = env.unwrapped.navigation.station_depth
    for _ in range(15):
        obs, _, terminated, truncated, info = env.step(env.action_space.sample())
        assert not (terminated or truncated)
        velocity = info["true_velocity"]
        np.testing.assert_allclose(obs["dvl_velocity"], velocity[:3], atol=1e-5)
        np.testing.assert_allclose(obs["rates"], velocity[3:], atol=1e-5)
        np.testing.assert_allclose(obs["attitude"], info["true_euler"], atol=1e-5)
        assert obs["depth"][0] == pytest.approx(station_depth - info["true_position"][2],
                                                abs=1e-4)
        assert set(obs) >= {"pixels", "visible", "usbl", "usbl_age"}
        assert obs in env.observation_space
    assert obs["usbl_valid"][0] == 1 and obs["dvl_valid"][0] == 1


def test_nav_presets_and_override():
    env = gym.make("auv_envs/DockingStation-v2", obs_mode="nav", difficulty="hard")
    assert env.unwrapped.navigation.usbl.period == 2.0
    mine = NavigationSensors(station_depth=20.0)
    env = gym.make("auv_envs/DockingStation-v2", obs_mode="nav", difficulty="hard",
                   navigation=mine)
    assert env.unwrapped.navigation is mine
    assert gym.make("auv_envs/DockingStation-v2", obs_mode="nav").unwrapped.navigation.usbl \
        .acoustics.sound_speed_error_std == 0.0  # easy: no faults


def test_navigation_runs_under_jax_as_on_numpy():
    """The same functions under ``jit`` with a JAX key's draws: with exact sensors the
    readings equal NumPy's to float32 round-off."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    from auv_envs.batched.functional import KeyDraws

    nav = Navigation(_exact_suite(), seabed_z=-2.0, dt=0.1)
    truth = {"position": (-12.0, 1.0, -0.5), "euler": (0.02, -0.03, 0.3),
             "velocity": [0.3, 0.01, -0.02, 0.001, 0.002, 0.05], "seabed_clearance": 1.0}
    expected = nav.start(truth, np.random.default_rng(0), FLOATS)
    expected = nav.advance(expected, truth, 0.1, np.random.default_rng(1), FLOATS)

    @jax.jit
    def run(key):
        first, second = jax.random.split(key)
        jtruth = {k: (jnp.asarray(v) if k != "velocity" else jnp.asarray(v)) for k, v in
                  truth.items()}
        state = nav.start(jtruth, KeyDraws(first), jax_ops())
        return nav.advance(state, jtruth, 0.1, KeyDraws(second), jax_ops())

    got = run(jax.random.PRNGKey(0))
    for name in ("dvl", "attitude", "rates", "depth", "pending", "next_ping"):
        np.testing.assert_allclose(np.asarray(getattr(got, name)), getattr(expected, name),
                                   atol=2e-4, err_msg=name)
    assert bool(got.pending_valid)


def test_heading_deviation_under_jax():
    """Under ``jit`` the episode's heading deviation is drawn from the key and carried in
    the state: the heading reads the truth plus it."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    from auv_envs.batched.functional import KeyDraws

    quiet = dict(roll_pitch_std=0.0, heading_std=0.0, rate_noise_density=0.0,
                 bias_instability=0.0)
    suite = dataclasses.replace(_exact_suite(), ahrs=AHRS(heading_bias_std=0.1, **quiet))
    nav = Navigation(suite, seabed_z=-2.0, dt=0.1)
    truth = {"position": jnp.asarray((-12.0, 1.0, -0.5)), "euler": jnp.asarray((0.0, 0.0, 0.3)),
             "velocity": jnp.zeros(6), "seabed_clearance": jnp.asarray(1.0)}

    @jax.jit
    def run(key):
        first, second = jax.random.split(key)
        state = nav.start(truth, KeyDraws(first), jax_ops())
        return state, nav.advance(state, truth, 0.1, KeyDraws(second), jax_ops())

    deviations = []
    for seed in range(3):
        start, after = run(jax.random.PRNGKey(seed))
        bias = float(start.heading_bias)
        assert bias != 0.0 and abs(bias) < 1.0
        assert float(after.heading_bias) == bias
        assert float(after.attitude[2]) == pytest.approx(0.3 + bias, abs=1e-6)
        deviations.append(bias)
    assert len(set(deviations)) == 3  # one draw per key
