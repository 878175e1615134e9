"""Irregular seas: spectra, realisations, body responses, and their wiring into LARSCapture."""

from __future__ import annotations

import math
import pickle

import cv2
import numpy as np
import pytest
from scipy.integrate import trapezoid
from scipy.signal import welch

from auv_envs.core.camera import points_in_camera, project
from auv_envs.core.env import TaskEnv
from auv_envs.core.ops import FLOATS
from auv_envs.core.sea import heave
from auv_envs.datasets.lars import tracking_action
from auv_envs.tasks.lars.env import LARSCaptureTask
from auv_envs.tasks.lars.scene import AUV_DIAMETER, AUV_FREEBOARD
from auv_envs.tasks.lars.sea import (
    AUV_RESPONSE,
    SHIP_ORIGIN,
    EpisodeSea,
    LARSSeaModel,
    ShipPose,
    analogs_in_play,
    wash_over_timing,
)
from auv_envs.tasks.lars.waves import (
    FloaterResponse,
    HarmonicSeries,
    SeaSpectrum,
    ShipResponse,
    WaveRealisation,
    fully_developed_peak_period,
    plane_average,
    sea_state_code,
    slope_average,
    typical_sea,
)

MODERATE = SeaSpectrum(0.5, 6.0)


# ------------------------------------------------------------------ spectra
@pytest.mark.parametrize("spectrum", [MODERATE, SeaSpectrum(2.0, 9.0, gamma=7.0),
                                      SeaSpectrum(1.0, 7.0, "pierson-moskowitz")])
def test_spectrum_is_normalised_to_hs(spectrum):
    assert 4.0 * math.sqrt(spectrum.moment(0)) == pytest.approx(spectrum.hs, rel=1e-6)
    # DNV-RP-C205 §3.5.5's fit of the normalisation, 1 - 0.287 ln(gamma).
    assert spectrum.normalisation == pytest.approx(
        1.0 - 0.287 * math.log(spectrum.effective_gamma), rel=0.02)


def test_jonswap_with_gamma_one_is_pierson_moskowitz():
    w = np.linspace(0.05, 5.0, 500)
    np.testing.assert_array_equal(SeaSpectrum(1.0, 8.0, gamma=1.0).density(w, np),
                                  SeaSpectrum(1.0, 8.0, "pierson-moskowitz").density(w, np))
    assert not np.allclose(SeaSpectrum(1.0, 8.0).density(w, np),
                           SeaSpectrum(1.0, 8.0, "pierson-moskowitz").density(w, np))


@pytest.mark.parametrize("gamma", [1.0, 3.3, 5.0])
def test_zero_crossing_period_matches_dnv(gamma):
    """DNV-RP-C205 §3.5.5: Tz / Tp = 0.6673 + 0.05037 g - 0.006230 g^2 + 0.0003341 g^3."""
    ratio = 0.6673 + 0.05037 * gamma - 0.006230 * gamma**2 + 0.0003341 * gamma**3
    spectrum = SeaSpectrum(1.0, 8.0, gamma=gamma)
    assert spectrum.zero_crossing_period / spectrum.tp == pytest.approx(ratio, rel=0.01)


def test_sea_state_codes_and_typical_seas():
    assert [sea_state_code(h) for h in (0.0, 0.05, 0.3, 0.5, 0.8, 2.0, 3.0, 20.0)] == [
        0, 1, 2, 2, 3, 4, 5, 9]
    assert fully_developed_peak_period(1.0) == pytest.approx(5.0, abs=0.01)
    sea = typical_sea(3)
    assert sea_state_code(sea.hs) == 3 and sea.tp == pytest.approx(5.0 * math.sqrt(sea.hs), 0.01)
    assert SeaSpectrum.dnv(1.0, 3.0).gamma == 5.0 and SeaSpectrum.dnv(1.0, 6.0).gamma == 1.0


# ------------------------------------------------------------------ realisation
def _periodogram_checks(signal, dt, spectrum):
    f, p = welch(signal, fs=1.0 / dt, nperseg=2048)
    omega, density = 2.0 * math.pi * f, p / (2.0 * math.pi)  # one-sided, per rad/s
    m0 = trapezoid(density, omega)
    assert m0 == pytest.approx(spectrum.moment(0), rel=0.10)
    peak = omega[np.argmax(density)]
    assert 0.85 * spectrum.peak_frequency < peak < 1.15 * spectrum.peak_frequency


def test_elevation_periodogram_and_height_match_the_spectrum():
    waves = WaveRealisation.sample(MODERATE, np.random.default_rng(3), heading=0.4, xp=np)
    dt = 0.25
    t = np.arange(0.0, 4096.0, dt)
    eta = waves.elevation(t, 1.0, 2.0)
    _periodogram_checks(eta, dt, MODERATE)
    assert 4.0 * eta.std() == pytest.approx(MODERATE.hs, rel=0.05)
    assert waves.significant_height == pytest.approx(MODERATE.hs, rel=0.05)


def test_auv_heave_periodogram_matches_the_spectrum():
    waves = WaveRealisation.sample(MODERATE, np.random.default_rng(4), heading=2.0, xp=np)
    sea = EpisodeSea(LARSSeaModel.from_spectrum(MODERATE), waves, 0.0, 2.0, 0.08, 0.3, (),
                     FLOATS)
    dt = 0.25
    heaves = [sea(t).auv_heave for t in np.arange(0.0, 4096.0, dt).tolist()]
    _periodogram_checks(np.array(heaves), dt, MODERATE)


def test_rates_and_slopes_match_finite_differences():
    waves = WaveRealisation.sample(MODERATE, np.random.default_rng(5), heading=0.7, xp=np)
    t, x, y, h = 12.3, 0.4, -1.1, 1e-5
    eta = waves.elevation
    assert waves.elevation_rate(t, x, y) == pytest.approx(
        (eta(t + h, x, y) - eta(t - h, x, y)) / (2 * h), rel=1e-6)
    sx, sy = waves.slope(t, x, y)
    assert sx == pytest.approx((eta(t, x + h, y) - eta(t, x - h, y)) / (2 * h), rel=1e-6)
    assert sy == pytest.approx((eta(t, x, y + h) - eta(t, x, y - h)) / (2 * h), rel=1e-6)
    assert waves.at(t, x, y) == pytest.approx((eta(t, x, y), waves.elevation_rate(t, x, y)))
    # Every channel's rate of an episode's series (moving AUV, ship, analogs).
    sea = EpisodeSea(LARSSeaModel.from_spectrum(MODERATE), waves, 0.1, 2.0, 0.1, -0.2,
                     [(0.5, 2.4, 0.13)], FLOATS)
    a, b, mid = sea(t - h), sea(t + h), sea(t)
    for value, rate in (("auv_heave", "auv_heave_rate"), ("ship_heave", "ship_heave_rate"),
                        ("ship_roll", "ship_roll_rate"), ("ship_pitch", "ship_pitch_rate")):
        fd = (getattr(b, value) - getattr(a, value)) / (2 * h)
        assert getattr(mid, rate) == pytest.approx(fd, rel=1e-5, abs=1e-9)
    # The level along the moving track is the field's elevation at the AUV's place.
    assert mid.level == pytest.approx(float(eta(t, 0.1 + 0.1 * t, 2.0)), abs=1e-12)


def test_ship_pose_velocity_matches_finite_differences():
    waves = WaveRealisation.sample(SeaSpectrum(1.5, 7.0), np.random.default_rng(6), heading=1.2,
                                   xp=np)
    sea = EpisodeSea(LARSSeaModel.from_spectrum(SeaSpectrum(1.5, 7.0)), waves, 0, 2, 0, 0, (),
                     FLOATS)
    t, h = 7.0, 1e-5
    point = lambda s: (0.3 + 0.2 * s, 1.9 - 0.1 * s, 1.2 + 0.05 * s)  # noqa: E731
    carried = [ShipPose(SHIP_ORIGIN, sea(s), FLOATS).carry(*point(s), 0.2, -0.1, 0.05)
               for s in (t - h, t, t + h)]
    fd = (np.array(carried[2][:3]) - carried[0][:3]) / (2 * h)
    np.testing.assert_allclose(carried[1][3:], fd, rtol=1e-5, atol=1e-9)
    pose = ShipPose(SHIP_ORIGIN, sea(t), FLOATS)
    np.testing.assert_allclose(pose.to_ship(carried[1][:3], np), point(t), atol=1e-12)
    rot, shift = pose.transform()
    np.testing.assert_allclose(rot @ point(t) + shift, carried[1][:3], atol=1e-12)


def test_same_seed_same_realisation_different_seeds_differ():
    a, b, c = (WaveRealisation.sample(MODERATE, np.random.default_rng(s), xp=np) for s in (1, 1, 2))
    for name in ("omega", "amplitude", "phase"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.phase, c.phase)
    assert not np.array_equal(a.elevation(np.arange(10.0)), c.elevation(np.arange(10.0)))


# ------------------------------------------------------------------ responses
def test_averages_are_the_numerical_averages_over_the_waterplane():
    s = np.linspace(-1.0, 1.0, 20001)
    for k in (0.3, 1.7, 4.0):
        wave = np.exp(-1j * k * s)
        assert plane_average(k, np) == pytest.approx(trapezoid(wave, s).real / 2.0, abs=1e-8)
        fit = trapezoid(s * wave, s) / trapezoid(s * s, s)  # least-squares slope
        assert fit == pytest.approx(-1j * k * slope_average(k, np), abs=1e-6)


def test_long_waves_are_followed_and_short_ones_filtered():
    w = np.array([1e-3, 0.05, 20.0])
    k = w**2 / 9.81
    heave, roll, pitch = FloaterResponse(1.8, 0.2).transfer(w, k, 0.4, FLOATS)
    assert abs(heave[0]) == pytest.approx(1.0) and abs(heave[2]) < 0.05
    assert pitch[1] == pytest.approx(-1j * k[1] * math.cos(0.4), rel=0.03)
    assert roll[1] == pytest.approx(-1j * k[1] * math.sin(0.4), rel=0.03)
    ship = ShipResponse().transfer(w, k, 0.4, FLOATS)
    assert abs(ship[0][0]) == pytest.approx(1.0, abs=1e-6)
    assert max(abs(r[2]) for r in ship) < 1e-3


def test_wash_over_and_analogs_follow_hs():
    calm, moderate, rough = (SeaSpectrum(h, 6.0) for h in (0.08, 0.5, 2.0))
    assert wash_over_timing(calm) == (math.inf, 0.0)
    assert wash_over_timing(rough)[0] < wash_over_timing(moderate)[0]
    assert wash_over_timing(rough)[1] > wash_over_timing(moderate)[1] > 0
    assert [analogs_in_play(h) for h in (0.05, 0.3, 0.8, 3.0)] == [0, 1, 2, 2]


# ------------------------------------------------------------------ LARS wiring
def _rollout(env, seed, steps=30, options=None):
    obs, info = env.reset(seed=seed, options=options)
    trace = [(obs, 0.0, info)]
    actions = np.random.default_rng(seed).uniform(-0.2, 0.2, (steps, 3)).astype(np.float32)
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        trace.append((obs, reward, info))
        if terminated or truncated:
            break
    return trace


def _leaves(x):
    if isinstance(x, dict):
        for key in sorted(x):
            yield from _leaves(x[key])
    else:
        yield x


@pytest.mark.parametrize("obs_mode", ["state", "features"])
def test_default_is_the_sinusoid_bit_identical_without_extra_draws(obs_mode):
    plain = TaskEnv(LARSCaptureTask, obs_mode=obs_mode, control="position")
    none = TaskEnv(LARSCaptureTask, obs_mode=obs_mode, control="position", sea=None)
    a, b = _rollout(plain, 7), _rollout(none, 7)
    for (oa, ra, ia), (ob, rb, ib) in zip(a, b, strict=True):
        for x, y in zip(_leaves(oa), _leaves(ob), strict=True):
            np.testing.assert_array_equal(x, y)
        assert ra == rb and set(ia) == set(ib)
        for x, y in zip(_leaves(ia), _leaves(ib), strict=True):
            np.testing.assert_array_equal(x, y)
    assert plain.np_random.bit_generator.state == none.np_random.bit_generator.state
    # The [LTAT] sinusoid and a ship at rest.
    m = none.auv_motion
    for k, (_, _, info) in enumerate(b):
        z = heave(k * none.dt, m.heave_amplitude, m.omega, m.heave_phase, FLOATS)[0]
        assert info["true_position"][2] == z + (AUV_FREEBOARD - AUV_DIAMETER / 2.0)
        assert info["true_pitch"] == m.pitch and "ship_motion" not in info
    q = none.physics.data.qpos
    np.testing.assert_array_equal(b[-1][2]["end_position"],
                                  none.calibration.arm.forward_kinematics(q))
    # No draws beyond the documented ones: motion (8) and arm offset (2) uniforms,
    # then the pixel noise (12 normals per observation) in features mode.
    rng = np.random.default_rng(7)
    rng.random(8)
    rng.random(2)
    for _ in range(len(b) if obs_mode == "features" else 0):
        rng.normal(0.0, 1.0, 12)
    assert none.np_random.bit_generator.state == rng.bit_generator.state
    sea = TaskEnv(LARSCaptureTask, obs_mode=obs_mode, control="position", sea=MODERATE)
    _rollout(sea, 7)
    assert sea.np_random.bit_generator.state != rng.bit_generator.state


def test_ship_motion_moves_the_cameras_and_the_auv_rolls():
    env = TaskEnv(LARSCaptureTask,
                  obs_mode="features", control="position", sea=SeaSpectrum(1.0, 7.0))
    cal = env.calibration
    _, info = env.reset(seed=2, options={"wave_heading": math.pi / 2})
    shift_px, rolls, ship_roll = [], [], []
    for k in range(120):
        q = env.physics.data.qpos.copy()
        rolls.append(info["true_roll"])
        ship_roll.append(info["ship_motion"][1])
        # The same AUV seen from the cameras of a ship at rest (forward kinematics and
        # hand-eye only) and from the cameras hanging from the ship-carried arm end.
        at_rest = cal.camera_poses(q)[0]
        carried = at_rest.copy()
        carried[:3, 3] += info["end_position"] - cal.arm.forward_kinematics(q)
        pixels = [project(cal.stereo.left, points_in_camera(
            info["true_corners"], pose[:3, 3], pose[:3, :3]))[0] for pose in (carried, at_rest)]
        np.testing.assert_allclose(pixels[0], info["true_pixels"][0], atol=1e-6)
        shift_px.append(np.abs(pixels[1] - info["true_pixels"][0]).max())
        _, _, terminated, truncated, info = env.step(np.zeros(3, dtype=np.float32) + 0.1 * (k % 2))
        assert not (terminated or truncated)
    assert max(shift_px) > 5.0
    assert np.degrees(np.std(rolls)) > 0.3 and np.degrees(np.std(ship_roll)) > 0.3


def test_rendered_marker_follows_the_sea():
    """The rendered stereo image (AUV posed with roll and pitch, head on the moving
    ship) shows the marker where the env's geometry projects it."""
    env = TaskEnv(LARSCaptureTask, obs_mode="stereo", control="position", image_size=(160, 120),
                         sea=SeaSpectrum(1.0, 7.0))
    obs, info = env.reset(seed=2, options={"wave_heading": math.pi / 2})
    for k in range(41):
        if k % 10 == 0:
            hsv = cv2.cvtColor(obs["left"], cv2.COLOR_RGB2HSV)
            red = (((hsv[..., 0] < 8) | (hsv[..., 0] > 172)) & (hsv[..., 1] > 150)
                   & (hsv[..., 2] > 80))
            ys, xs = np.nonzero(red)
            assert xs.size > 50
            centroid = np.array([xs.mean() + 0.5, ys.mean() + 0.5])
            np.testing.assert_allclose(centroid, info["true_pixels"][0].mean(axis=0), atol=1.5)
        obs, _, _, _, info = env.step(tracking_action(env, info))


def test_sea_info_and_calibration():
    env = TaskEnv(LARSCaptureTask,
                  obs_mode="features", sea_state="severe", sea=SeaSpectrum(1.0, 7.0))
    _, info = env.reset(seed=0)
    sea = info["sea"]
    assert sea["components"] == env.calibration.sea.n_components
    assert sea["hs_realised"] == pytest.approx(1.0, rel=0.1) and sea["analogs"] == 2
    assert sea["wash_period"] is not None and 0 <= sea["wave_heading"] < 2 * math.pi
    assert env.calibration.sea.spectrum == SeaSpectrum(1.0, 7.0)
    assert env.calibration.sea.auv == AUV_RESPONSE
    assert TaskEnv(LARSCaptureTask).calibration.sea is None


# ------------------------------------------------------------------ errors, pickling
@pytest.mark.parametrize("kwargs", [
    {"hs": 0.0, "tp": 6.0}, {"hs": math.nan, "tp": 6.0}, {"hs": 1.0, "tp": -1.0},
    {"hs": 1.0, "tp": 6.0, "kind": "bretschneider"}, {"hs": 1.0, "tp": 6.0, "gamma": 0.5},
    {"hs": 5.0, "tp": 2.0},
])
def test_bad_spectra_raise(kwargs):
    with pytest.raises(ValueError):
        SeaSpectrum(**kwargs)


def test_bad_inputs_raise():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="n_components"):
        WaveRealisation.sample(MODERATE, rng, n_components=0, xp=np)
    with pytest.raises(ValueError, match="band"):
        WaveRealisation.sample(MODERATE, rng, band=(2.0, 1.0), xp=np)
    with pytest.raises(ValueError, match="sea"):
        TaskEnv(LARSCaptureTask, sea="severe")
    with pytest.raises(ValueError, match="wave_heading"):
        TaskEnv(LARSCaptureTask).reset(seed=0, options={"wave_heading": 0.0})
    with pytest.raises(ValueError, match="wave_heading"):
        TaskEnv(LARSCaptureTask, sea=MODERATE).reset(seed=0, options={"wave_heading": math.inf})
    with pytest.raises(ValueError):
        sea_state_code(-1.0)
    with pytest.raises(ValueError):
        typical_sea(0)
    with pytest.raises(ValueError):
        HarmonicSeries([(np.ones(2), np.ones((1, 3)))], np)


def test_pickling_round_trips():
    waves = WaveRealisation.sample(MODERATE, np.random.default_rng(0), xp=np)
    copy = pickle.loads(pickle.dumps(waves))
    np.testing.assert_array_equal(copy.elevation(np.arange(5.0)), waves.elevation(np.arange(5.0)))
    assert pickle.loads(pickle.dumps(MODERATE)) == MODERATE
    env = TaskEnv(LARSCaptureTask, obs_mode="features", sea_state="severe", control="position",
                         sea=MODERATE)
    env.reset(seed=4)
    action = np.full(3, 0.1, dtype=np.float32)
    for _ in range(5):
        env.step(action)
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(5):
        a, b = env.step(action), clone.step(action)
        for x, y in zip(_leaves(a[0]), _leaves(b[0]), strict=True):
            np.testing.assert_array_equal(x, y)
        assert a[1] == b[1]
        np.testing.assert_array_equal(a[4]["ship_motion"], b[4]["ship_motion"])
