"""LARS sun glint: the Cox–Munk / Longuet-Higgins model against independent computations,
and its effects on ``features`` and ``stereo`` observations."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from auv_envs.core.camera import CameraIntrinsics, project_few
from auv_envs.core.env import TaskEnv
from auv_envs.core.frames import GRAVITY
from auv_envs.core.ops import FLOATS
from auv_envs.datasets.lars import tracking_action
from auv_envs.tasks.lars.env import HARD_SEA, LARSCaptureTask
from auv_envs.tasks.lars.sea import (
    GlintField,
    SunGlint,
    cox_munk_slope_variance,
    fully_developed_wind_speed,
)
from auv_envs.tasks.lars.waves import SeaSpectrum


def _sun_at(elevation_deg: float, azimuth_deg: float = 0.0, **kwargs) -> SunGlint:
    elevation, azimuth = math.radians(elevation_deg), math.radians(azimuth_deg)
    return SunGlint(sun_elevation=(elevation, elevation), sun_azimuth=(azimuth, azimuth),
                    **kwargs)


# ---------------------------------------------------------------------- the model
def test_cox_munk_and_pierson_moskowitz_relations():
    assert cox_munk_slope_variance(0.0) == pytest.approx(0.003)
    assert cox_munk_slope_variance(10.0) == pytest.approx(0.0542)
    for hs in (0.1, 0.4, 2.0):  # Hs ~= 0.21 U^2 / g
        wind = fully_developed_wind_speed(hs)
        assert 0.21 * wind**2 / GRAVITY == pytest.approx(hs, rel=0.01)
    # HARD_SEA's wind and slopes, as documented
    assert fully_developed_wind_speed(HARD_SEA.hs) == pytest.approx(4.33, abs=0.01)
    assert SunGlint().slope_variance(HARD_SEA.hs) == pytest.approx(0.0252, abs=1e-4)
    assert SunGlint(wind_speed=5.0).slope_variance(None) == pytest.approx(0.0286)
    with pytest.raises(ValueError, match="wind_speed"):
        SunGlint().slope_variance(None)


def _random_surface(rng, n_points, n_waves=400, slope_variance=0.025):
    """Slopes (M, 2) and Hessians (M, 2, 2) of a long sum of plane waves with isotropic,
    random directions, wavenumbers log-uniform over a decade and random phases (a
    near-Gaussian isotropic surface), with its own slope variance and mean-square curvature."""
    k = np.exp(rng.uniform(math.log(5.0), math.log(50.0), n_waves))
    direction = rng.uniform(0.0, 2.0 * math.pi, n_waves)
    kv = k[:, None] * np.stack((np.cos(direction), np.sin(direction)), axis=-1)
    a = np.full(n_waves, 1.0)
    a *= math.sqrt(slope_variance / np.sum(a**2 * k**2 / 2.0))
    msc = float(np.sum(a**2 * k**4 / 2.0))  # E[(eta_xx + eta_yy)^2]
    slopes, hessians = [], []
    for _ in range(n_points // 10_000):
        phase = rng.uniform(0.0, 2.0 * math.pi, (10_000, n_waves))
        sin, cos = np.sin(phase) * a, np.cos(phase) * a
        slopes.append(-sin @ kv)  # eta = sum a cos(k.x + phase)
        hessians.append(-np.einsum("mn,ni,nj->mij", cos, kv, kv))
    return np.concatenate(slopes), np.concatenate(hessians), msc


def test_specular_point_density_on_a_random_surface():
    """n = p(slope) E|det H| = p msc / (2 sqrt 3) (Longuet-Higgins 1960), counted on a
    surface built from plane waves, independently of the model's formula."""
    rng = np.random.default_rng(0)
    sigma2 = 0.025
    slopes, hessians, msc = _random_surface(rng, 200_000, slope_variance=sigma2)
    assert np.mean(np.sum(slopes**2, axis=1)) == pytest.approx(sigma2, rel=0.02)
    det = np.abs(np.linalg.det(hessians))
    assert det.mean() == pytest.approx(msc / (2.0 * math.sqrt(3.0)), rel=0.03)
    # Specular points for a slope s0: E[|det H| ; slope within a small box] / box area.
    s0, half = np.array([0.1, -0.05]), 0.02
    inside = np.all(np.abs(slopes - s0) < half, axis=1)
    counted = det[inside].sum() / len(det) / (2.0 * half) ** 2
    # The model, with k_s^2 = msc / sigma^2, for a geometry that needs slope s0:
    # camera at nadir (view straight up) and the sun where a facet of slope s0 sends it.
    normal = np.array([-s0[0], -s0[1], 1.0]) / math.hypot(1.0, *s0)
    view = np.array([0.0, 0.0, 1.0])
    sun = 2.0 * (view @ normal) * normal - view  # law of reflection
    field = GlintField.towards(math.asin(sun[2]), math.atan2(sun[1], sun[0]), sigma2,
                               math.sqrt(msc / sigma2), FLOATS)
    assert np.allclose(field.sun, sun)
    assert field.density(*view, np) == pytest.approx(counted, rel=0.08)
    # and the Gaussian slope pdf of Cox & Munk at s0, times E|det H|
    gauss = math.exp(-(s0 @ s0) / sigma2) / (math.pi * sigma2)
    assert field.density(*view, np) == pytest.approx(gauss * msc / (2.0 * math.sqrt(3.0)), rel=1e-9)


def test_glints_in_an_image_are_the_density_integrated_over_its_footprint():
    """Sum of pixel_means over a tilted camera's pixels = the integral of n over the water
    the image sees, found by projecting a fine grid of the water plane (core.camera)."""
    field = GlintField.towards(math.radians(60.0), math.radians(30.0), 0.025, 100.0, FLOATS)
    width, height, focal = 64, 48, 60.0
    camera = (0.3, -0.2, 1.5)  # 1.5 m above water at z = 0
    tilt = math.radians(15.0)  # optical axis down and tilted towards -y
    # camera -> world rows (OpenCV axes): looking down, then tilted about world x
    down = np.diag([1.0, -1.0, -1.0])
    c, s = math.cos(tilt), math.sin(tilt)
    rows = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]) @ down
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    cam_rays = np.stack(((u - width / 2) / focal, (v - height / 2) / focal, np.ones_like(u)), -1)
    rays = cam_rays @ rows.T
    total = field.pixel_means(rays, camera[2], focal, np).sum()
    intr = CameraIntrinsics(width, height, focal, focal, width / 2, height / 2)
    step = 0.005
    xs = np.arange(-2.5, 3.0, step)
    gx, gy = np.meshgrid(xs, xs - 0.5)
    points = np.stack((gx.ravel(), gy.ravel(), np.zeros(gx.size)), axis=-1)
    _, seen = project_few(intr, points.tolist(), camera, rows.tolist(), FLOATS)
    seen = np.array(seen)
    assert not seen[[0, -1]].any()  # the grid covers the footprint
    view = np.asarray(camera) - points[seen]
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    integral = field.density(view[:, 0], view[:, 1], view[:, 2], np).sum() * step**2
    assert total == pytest.approx(integral, rel=0.01)


def test_hand_worked_nadir_case():
    """Sun at the zenith, camera looking straight down: at the image centre no slope is
    needed, n = k_s^2 / (2 sqrt(3) pi) per m^2 and a pixel covers (h / f)^2."""
    glint = _sun_at(90.0, wind_speed=4.0)
    field = glint.sample(np.random.default_rng(0), glint.slope_variance(None), FLOATS)
    means = field.pixel_means(np.array([0.0, 0.0, -1.0]), 0.8, 415.0, np)
    assert means == pytest.approx(100.0**2 / (2.0 * math.sqrt(3.0) * math.pi) * (0.8 / 415) ** 2)
    # 20 deg off the specular direction in the sun's plane: the facet tilts by 10 deg.
    off = field.density(math.sin(math.radians(20.0)), 0.0, math.cos(math.radians(20.0)), np)
    sigma2 = cox_munk_slope_variance(4.0)
    assert off / field.peak_density == pytest.approx(
        math.exp(-math.tan(math.radians(10.0)) ** 2 / sigma2))


def test_glint_grows_with_hs():
    """Off the specular direction, rougher (windier) seas glint more; at it, no fewer."""
    view = (math.sin(math.radians(30.0)), 0.0, math.cos(math.radians(30.0)))
    off, at = [], []
    for hs in (0.1, 0.3, 0.4, 0.8, 1.5):
        sigma2 = SunGlint().slope_variance(hs)
        field = GlintField.towards(math.radians(70.0), math.pi, sigma2, 100.0, FLOATS)
        off.append(float(field.density(*view, np)))
        at.append(float(field.density(-field.sun[0], 0.0, field.sun[2], np)))
    assert np.all(np.diff(off) > 0)
    assert np.allclose(at, at[0])
    # In the env: the same sun over a rougher sea sends more glints into the images.
    expected = []
    for hs in (0.2, 0.6):
        env = TaskEnv(LARSCaptureTask, obs_mode="stereo", image_size=(160, 120), control="position",
                             sea=SeaSpectrum(hs, 7.0), glint=_sun_at(45.0, 90.0))
        _, info = env.reset(seed=4)
        expected.append(info["glint_expected"].sum())
        env.close()
    assert expected[1] > 1.5 * expected[0]


# ---------------------------------------------------------------------- the env
def _rollout(steps=20, **kwargs):
    env = TaskEnv(LARSCaptureTask, control="position", **kwargs)
    obs, info = env.reset(seed=11)
    out = [obs]
    for _ in range(steps):
        obs, *_, info = env.step(tracking_action(env, info))
        out.append(obs)
    return env, out


def _same(a, b):
    if isinstance(a, dict):
        return all(np.array_equal(a[k], b[k]) for k in a)
    return np.array_equal(a, b)


def test_off_draws_nothing():
    plain, obs_plain = _rollout(obs_mode="features")
    off, obs_off = _rollout(obs_mode="features", glint=False)
    assert all(_same(a, b) for a, b in zip(obs_plain, obs_off, strict=True))
    assert plain.np_random.bit_generator.state == off.np_random.bit_generator.state
    # hard without glint: the same as hard was; with it, state observations (no per-step
    # draws) are unchanged and the reset draws exactly two more uniforms, last.
    on, obs_on = _rollout(obs_mode="state", difficulty="hard")
    off, obs_off = _rollout(obs_mode="state", difficulty="hard", glint=False)
    assert all(_same(a, b) for a, b in zip(obs_on, obs_off, strict=True))
    rng = np.random.default_rng()
    rng.bit_generator.state = off.np_random.bit_generator.state
    rng.random(2)
    assert rng.bit_generator.state == on.np_random.bit_generator.state
    assert on.glint is not None and off.glint is None
    _, info = off.reset(seed=1)
    assert "glint" not in info
    _, info = on.reset(seed=1)
    assert set(info["glint"]) == {"sun_elevation", "sun_azimuth", "slope_variance"}
    assert math.radians(40.0) <= info["glint"]["sun_elevation"] <= math.radians(80.0)


def test_paper_has_no_glint_and_bad_arguments():
    assert TaskEnv(LARSCaptureTask, difficulty="paper").glint is None
    assert TaskEnv(LARSCaptureTask).glint is None
    with pytest.raises(TypeError, match="glint"):
        TaskEnv(LARSCaptureTask, glint="on")
    with pytest.raises(ValueError, match="wind_speed"):
        TaskEnv(LARSCaptureTask, glint=SunGlint())  # no sea, no wind
    with pytest.raises(ValueError, match="sun_elevation"):
        SunGlint(sun_elevation=(0.5, 2.0))
    with pytest.raises(ValueError, match="bloom"):
        SunGlint(bloom=-1)


def test_features_corruption_rate_matches_the_model():
    """Over a seeded tracking run under a high sun, corners corrupted = sum of the model's
    probabilities (within 4 binomial standard deviations); the corrupted ones read as
    documented (near the corner, or lost)."""
    glint = _sun_at(85.0, 200.0, detector_radius=16.0, bloom=4)
    env = TaskEnv(LARSCaptureTask, obs_mode="features", control="position", difficulty="hard",
                         glint=glint)
    probability, corrupted = [], []
    for seed in (1, 2):
        obs, info = env.reset(seed=seed)
        for _ in range(300):
            obs, _, terminated, truncated, info = env.step(tracking_action(env, info))
            p, state = info["glint_probability"], info["glint_corners"]
            probability.append(p)
            corrupted.append(state)
            true_px, seen = info["true_pixels"], info["true_visible"].astype(bool)
            assert np.all(p[~seen] == 0.0) and np.all(state[~seen] == 0)
            assert np.all(obs["visible"][state == 2] == 0)
            assert np.all(obs["visible"][(state != 2) & seen] == 1)
            far = np.linalg.norm(obs["pixels"] - true_px, axis=-1)
            assert np.all(far[state == 1] < glint.detector_radius + 4 * 3.0 + 1.0)
            assert np.all(far[(state == 0) & seen] < 6 * 3.0)
            if terminated or truncated:
                break
    probability, corrupted = np.array(probability), np.array(corrupted) > 0
    expected = probability.sum()
    assert expected > 30  # the geometry puts glint there often enough to test
    spread = math.sqrt(np.sum(probability * (1.0 - probability)))
    assert abs(corrupted.sum() - expected) < 4.0 * spread
    assert np.all(probability[:, :, 2] == 0.0)  # the apex is inside the hull's waterline
    env.close()


def test_stereo_glints_are_saturated_where_the_model_says():
    """Glints change only water pixels' neighbourhoods, to white; their number and place
    follow the model's mean map, computed here from the calibration's camera poses."""
    width, height = 160, 120
    env = TaskEnv(LARSCaptureTask,
                  obs_mode="stereo", image_size=(width, height), control="position",
                         glint=_sun_at(80.0, 120.0, wind_speed=4.3))  # a still ship (no sea)
    obs, info = env.reset(seed=3)
    cal = env.calibration
    f = cal.stereo.left.fx
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    cam_rays = np.stack(((u - width / 2) / f, (v - height / 2) / f, np.ones_like(u)), -1)
    field = env.glint_field
    counts = expected = 0.0
    spot_sum, spot_pixels, model_sum = np.zeros(2), 0, np.zeros(2)
    for _ in range(25):
        obs, *_, info = env.step(tracking_action(env, info))
        clean, ranges = env.camera_renderer.render_with_range(env.physics.scene_data)  # no glint
        left = obs["left"]
        changed = np.any(left != clean[:, :width], axis=-1)
        assert np.all(left[changed] == 255)
        pose = cal.camera_poses(env.physics.data.qpos)[0]
        rays = cam_rays @ pose[:3, :3].T
        h = pose[2, 3] - info["water_level"]
        water = np.abs(ranges[:, :width] - h * np.linalg.norm(rays, axis=-1)) < 0.005
        means = field.pixel_means(rays, h, f, np) * water
        near_water = np.zeros_like(water)  # water pixels grown by the bloom (1 px)
        for di, dj in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
            near_water |= np.roll(water, (di, dj), axis=(0, 1))
        assert not np.any(changed & ~near_water)
        assert info["glint_expected"][0] == pytest.approx(means.sum(), rel=1e-3)
        counts += info["glints_in_view"][0]
        expected += means.sum()
        spot_sum += (u[changed].sum(), v[changed].sum())  # the bloom is symmetric
        spot_pixels += changed.sum()
        model_sum += ((u * means).sum(), (v * means).sum())
    assert expected > 100
    assert abs(counts - expected) < 4.0 * math.sqrt(expected)
    # where they fall: the centroid of the glints matches the model's (within a few px)
    assert np.allclose(spot_sum / spot_pixels, model_sum / expected, atol=4.0)
    env.close()


def test_glitter_centres_on_the_suns_mirror_image():
    """On a nearly glassy sea the glints cluster where a flat mirror shows the sun: the
    water point ``H tan(zenith)`` from the camera's nadir towards the sun's azimuth."""
    width, height = 160, 120
    elevation, azimuth = 65.0, 300.0
    env = TaskEnv(LARSCaptureTask,
                  obs_mode="stereo", image_size=(width, height), control="position",
                         glint=_sun_at(elevation, azimuth, wind_speed=0.5))
    obs, info = env.reset(seed=8)
    cal = env.calibration
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    offsets = []
    for _ in range(10):
        obs, *_, info = env.step(tracking_action(env, info))
        clean = env.camera_renderer.render(env.physics.scene_data)[:, :width]
        changed = np.any(obs["left"] != clean, axis=-1)
        pose = cal.camera_poses(env.physics.data.qpos)[0]
        camera = pose[:3, 3]
        reach = (camera[2] - info["water_level"]) / math.tan(math.radians(elevation))
        mirror = camera + (reach * math.cos(math.radians(azimuth)),
                           reach * math.sin(math.radians(azimuth)), 0.0)
        mirror[2] = info["water_level"]
        (pixel,), (inside,) = project_few(cal.stereo.left, [tuple(mirror)], tuple(camera),
                                          pose[:3, :3].tolist(), FLOATS)
        assert inside
        offsets.append((u[changed].mean() - pixel[0], v[changed].mean() - pixel[1]))
    assert np.all(np.abs(np.mean(offsets, axis=0)) < 2.0)
    env.close()


def test_pickle_mid_episode_continues_identically():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", difficulty="hard", control="position",
                         glint=_sun_at(85.0))
    _, info = env.reset(seed=5)
    for _ in range(5):
        _, *_, info = env.step(tracking_action(env, info))
    twin = pickle.loads(pickle.dumps(env))
    for _ in range(5):
        a = env.step(tracking_action(env, info))
        b = twin.step(tracking_action(twin, info))
        info = a[-1]
        assert _same(a[0], b[0])
        assert np.array_equal(a[-1]["glint_corners"], b[-1]["glint_corners"])
