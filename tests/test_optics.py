"""Water optics: Jerlov coefficients, image formation, range from depth, lamp detection."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from auv_envs.core.rendering import CameraRenderer
from auv_envs.tasks.docking.optics import (
    JERLOV_TYPES,
    LampOutages,
    WaterOptics,
    degrade_image,
    detect_lamps,
)
from tests.conftest import DOCKING_IDS, SMALL_IMAGE

NOISELESS = {"shot_noise": 0.0, "read_noise": 0.0}
FOCAL = 500.0  # pixels, for the synthetic images

#: A flat-coloured patch (emissive, no lights) on a mocap body and a camera
#: looking along +x (the docking nose camera's axes); no skybox, so the
#: background is empty.
PATCH_SCENE = """
<mujoco>
  <statistic extent="20"/>
  <visual>
    <map znear="0.01" zfar="5"/><quality offsamples="0"/><headlight active="0"/>
  </visual>
  <asset><material name="flat" rgba="0.8 0.55 0.3 1" emission="1"/></asset>
  <worldbody>
    <body name="patch" mocap="true" pos="2 0 0">
      <geom type="box" size="0.01 0.5 0.4" pos="0.01 0 0" material="flat"/>
    </body>
    <camera name="eye" pos="0 0 0" xyaxes="0 -1 0 0 0 1" fovy="40"/>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def patch_scene():
    model = mujoco.MjModel.from_xml_string(PATCH_SCENE)
    data = mujoco.MjData(model)
    renderer = CameraRenderer(model, ("eye",), 64, 48)
    yield model, data, renderer
    renderer.close()


def _render_at(scene, distance: float):
    model, data, renderer = scene
    data.mocap_pos[0] = (distance, 0.0, 0.0)
    mujoco.mj_forward(model, data)
    return renderer.render_with_range(data)


def _rollout(env, seed: int, steps: int):
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    trace = [(obs, 0.0, info)]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        trace.append((obs, reward, info))
        if terminated or truncated:
            break
    return trace


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return bool(np.array_equal(np.asarray(a), np.asarray(b)))


# ------------------------------------------------------------------ water types
def test_jerlov_coefficients_are_the_table_interpolated_at_the_channel_wavelengths():
    # Jerlov (1976) Table XXVII, IB: K_d(600, 625) = 0.245, 0.315; (525, 550) = 0.054,
    # 0.072; (450, 475) = 0.036, 0.033; linear at 620, 540 and 460 nm.
    ib = WaterOptics.jerlov("IB")
    np.testing.assert_allclose(ib.attenuation, (0.245 + 0.8 * 0.070, 0.054 + 0.6 * 0.018,
                                                0.036 - 0.4 * 0.003), rtol=1e-12)
    assert ib.water_type == "IB"
    greens = [WaterOptics.jerlov(t).attenuation[1] for t in JERLOV_TYPES]
    assert greens == sorted(greens) and greens[0] < 0.06 < 0.6 < greens[-1]
    # Open water: the daylight left at 10 m, exposed to 0.3 in its brightest channel;
    # blue in oceanic water, green in coastal 5C (its dissolved matter absorbs blue).
    five_c = WaterOptics.jerlov("5C", depth=10.0, brightness=0.3)
    assert max(ib.veiling_light) == pytest.approx(0.3) == ib.veiling_light[2]
    assert max(five_c.veiling_light) == pytest.approx(0.3) == five_c.veiling_light[1]
    expected = np.exp(-10.0 * np.array(five_c.attenuation))
    np.testing.assert_allclose(five_c.veiling_light, 0.3 * expected / expected.max())


@pytest.mark.parametrize("make", [
    lambda: WaterOptics.jerlov("4C"),
    lambda: WaterOptics.jerlov("IB", depth=-1.0),
    lambda: WaterOptics.jerlov("IB", brightness=0.0),
    lambda: WaterOptics.jerlov("IB", brightness=float("nan")),
    lambda: WaterOptics((0.1, -0.1, 0.1), (0.1, 0.1, 0.1)),
    lambda: WaterOptics((0.1, float("nan"), 0.1), (0.1, 0.1, 0.1)),
    lambda: WaterOptics((0.1, 0.1), (0.1, 0.1, 0.1)),
    lambda: WaterOptics((0.1, 0.1, 0.1), (0.1, 1.5, 0.1)),
    lambda: WaterOptics.jerlov("IB", lamp_failure_probability=1.2),
    lambda: WaterOptics.jerlov("IB", occlusion_rate=-0.1),
    lambda: WaterOptics.jerlov("IB", occlusion_duration=0.0),
    lambda: WaterOptics.jerlov("IB", detection_contrast=float("inf")),
    lambda: WaterOptics.jerlov("IB", shot_noise=float("nan")),
    lambda: WaterOptics.jerlov("IB", glow_angle=-0.01),
])
def test_bad_values_raise(make):
    with pytest.raises(ValueError):
        make()


def test_env_checks_the_optics_argument():
    with pytest.raises(TypeError, match="WaterOptics"):
        gym.make(DOCKING_IDS[0], optics="IB")


# ------------------------------------------------------------------ image formation
def test_patch_fades_into_the_veiling_light_as_the_formula_says(patch_scene):
    optics = WaterOptics.jerlov("5C", **NOISELESS)
    beta, veil = np.array(optics.attenuation), 255.0 * np.array(optics.veiling_light)
    rng = np.random.default_rng(0)
    centre = (slice(20, 28), slice(28, 36))
    measured = {}
    for d in (1.5, 5.0):
        clear, distance = _render_at(patch_scene, d)
        ray = distance[centre] / d  # the rays' lengths (>= 1): range = d * ray
        j = clear[centre].astype(float)
        assert np.ptp(j, axis=(0, 1)).max() == 0  # a flat-coloured patch
        t = np.exp(-beta * (d * ray)[..., None])
        expected = j * t + veil * (1.0 - t)
        seen = degrade_image(clear, distance, optics, FOCAL, rng)[centre].astype(float)
        np.testing.assert_allclose(seen, expected, atol=0.51)  # rounding to grey levels
        measured[d] = seen.mean(axis=(0, 1))
    # The patch's contrast against open water falls as exp(-beta * range difference).
    ratio = (measured[5.0] - veil) / (measured[1.5] - veil)
    np.testing.assert_allclose(ratio, np.exp(-beta * 3.5), rtol=0.06)


def test_pixel_at_infinity_is_the_veiling_light():
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    optics = WaterOptics.jerlov("3C", **NOISELESS)
    out = degrade_image(image, np.full((12, 16), np.inf, np.float32), optics, FOCAL, rng)
    assert (out == np.rint(255 * np.array(optics.veiling_light))).all()


def test_clear_water_returns_the_image_unchanged():
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    image[10:14, 10:14] = 255  # a lamp
    distance = rng.uniform(0.5, 40.0, (30, 40)).astype(np.float32)
    distance[:5] = np.inf
    optics = WaterOptics((0.0, 0.0, 0.0), (0.1, 0.5, 0.4), **NOISELESS)
    state = rng.bit_generator.state
    np.testing.assert_array_equal(degrade_image(image, distance, optics, FOCAL, rng), image)
    assert rng.bit_generator.state == state  # no noise, no draws


def _lamp_image(distance: float, optics: WaterOptics) -> np.ndarray:
    """A 7x7-pixel lamp at ``distance`` in front of open water, through ``optics``."""
    image = np.zeros((101, 101, 3), dtype=np.uint8)
    image[47:54, 47:54] = 255
    ranges = np.full((101, 101), np.inf, dtype=np.float32)
    ranges[47:54, 47:54] = distance
    return degrade_image(image, ranges, optics, FOCAL, np.random.default_rng(0))


@pytest.mark.parametrize("distance, radiance", [(2.0, 1.2), (6.0, 6.0)])
def test_glow_keeps_the_lamps_light_and_widens_with_range(distance, radiance):
    # Radiances that keep every pixel below saturation: the glow moves light, it
    # neither adds nor removes any.
    beta, angle = 0.2, 0.01
    optics = WaterOptics((beta,) * 3, (0.0, 0.0, 0.0), lamp_radiance=radiance,
                         glow_angle=angle, **NOISELESS)
    image = _lamp_image(distance, optics)[:, :, 1].astype(float)
    assert image.max() < 255
    transmission = math.exp(-beta * distance)
    assert image.sum() == pytest.approx(49 * 255 * radiance * transmission, rel=0.02)
    # Second moment along x: the lamp's own (49 pixels: 4 px^2) plus, for the share
    # that glows, the glow's width FOCAL * angle * tau_s squared.
    glow_share = 1 - transmission  # glow_rate 1, tau_s = beta d
    glow_width = FOCAL * angle * beta * distance
    x = np.arange(101) - 50
    variance = (image * x[None, :] ** 2).sum() / image.sum()
    assert variance == pytest.approx(4.0 + glow_share * (glow_width ** 2 + 1 / 12), rel=0.05)


def test_sensor_noise_has_the_modelled_variance():
    optics = WaterOptics((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), shot_noise=0.5, read_noise=4.0)
    rng = np.random.default_rng(3)
    distance = np.ones((200, 200), np.float32)
    for level in (40, 160):
        image = np.full((200, 200, 3), level, dtype=np.uint8)
        out = degrade_image(image, distance, optics, FOCAL, rng).astype(float)
        assert out.mean() == pytest.approx(level, abs=0.05)
        # Rounding to grey levels adds 1/12.
        assert out.var() == pytest.approx(0.5 * level + 4.0 + 1 / 12, rel=0.03)


def test_range_is_read_from_the_depth_buffer(patch_scene):
    model, _, renderer = patch_scene
    clear, distance = _render_at(patch_scene, 3.0)
    np.testing.assert_array_equal(clear, renderer.render(patch_scene[1]))  # same image
    focal = 0.5 * 48 / math.tan(math.radians(20.0))
    x = (np.arange(64) + 0.5 - 32) / focal
    y = (np.arange(48) + 0.5 - 24) / focal
    expected = 3.0 * np.sqrt(1 + x[None, :] ** 2 + y[:, None] ** 2)
    hit = np.isfinite(distance)
    # The patch (1 m x 0.8 m at 3 m) fills the middle; the corners see nothing.
    assert hit[24, 32] and hit[15:33, 22:42].all() and not hit[0, 0] and not hit[-1, -1]
    np.testing.assert_allclose(distance[hit], expected[hit], rtol=1e-4)
    assert (clear[~hit] == 0).all()


# ------------------------------------------------------------------ features
def test_detection_probability_falls_with_range_and_matches_the_draws():
    optics = WaterOptics.jerlov("5C")
    ranges = np.array([2.0, 6.0, 9.0, 11.0, 14.0])
    p = optics.detection_probability(ranges, np)
    assert (np.diff(p) < 0).all() and p[0] > 0.99 and p[-1] < 0.05
    n_lamps, trials = len(ranges), 4000
    rng = np.random.default_rng(4)
    outages = LampOutages(np.zeros(n_lamps, bool), np.zeros(n_lamps, bool))
    pixels = np.full((n_lamps, 2), 100.0)
    hits = np.zeros(n_lamps)
    errors = []
    for _ in range(trials):
        seen, detected = detect_lamps(pixels, np.ones(n_lamps, bool), ranges, outages,
                                      optics, FOCAL, rng, np)
        hits += detected
        errors.append(np.where(detected[:, None], seen - pixels, np.nan))
    tolerance = 4 * np.sqrt(p * (1 - p) / trials) + 1e-3
    np.testing.assert_array_less(np.abs(hits / trials - p), tolerance)
    # Centroid noise grows with the glow: its model's standard deviation per axis.
    spread = np.nanstd(np.array(errors)[:, :3], axis=0).mean(axis=1)
    np.testing.assert_allclose(spread, optics.centroid_std(ranges[:3], FOCAL, np), rtol=0.1)


def test_occluders_follow_their_two_state_process():
    optics = WaterOptics.jerlov("IB", occlusion_rate=0.5, occlusion_duration=1.0)
    rng = np.random.default_rng(5)
    outages = LampOutages.start(optics, 6, rng)
    hidden = []
    for _ in range(20_000):
        outages = outages.advance(optics, 0.1, rng)
        hidden.append(outages.occluded)
    hidden = np.array(hidden)
    assert hidden.mean() == pytest.approx(0.5 / 1.5, abs=0.02)  # rate T / (1 + rate T)
    # Mean spell hidden: T (in steps of 0.1 s, geometric with the exact rate).
    starts = (hidden[1:] & ~hidden[:-1]).sum()
    assert hidden.sum() * 0.1 / starts == pytest.approx(1.0 / (1 - math.exp(-0.1)) * 0.1,
                                                         rel=0.05)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_failed_lamps_never_appear(env_id):
    optics = WaterOptics.jerlov("IB", lamp_failure_probability=0.5)
    env = gym.make(env_id, obs_mode="features", optics=optics)
    labels = env.unwrapped.calibration.light_labels
    seen_failed = seen_working = 0
    for seed in range(3):
        trace = _rollout(env, seed, 20)
        failed = np.isin(labels, trace[0][2]["optics"]["failed_lamps"])
        visible = np.array([obs["visible"] for obs, _, _ in trace], dtype=bool)
        pixels = np.array([obs["pixels"] for obs, _, _ in trace])
        seen_failed += visible[:, failed].sum() + np.abs(pixels[:, failed]).sum()
        seen_working += visible[:, ~failed].sum()
    assert seen_failed == 0 and seen_working > 0
    env.close()


def test_failed_lamps_are_dark_in_the_image():
    optics = WaterOptics.jerlov("IB", lamp_failure_probability=1.0, **NOISELESS)
    env = gym.make(DOCKING_IDS[0], obs_mode="image", image_size=(160, 120), optics=optics)
    _, info = env.reset(seed=0)
    assert info["optics"]["failed_lamps"] == env.unwrapped.calibration.light_labels
    clear = env.unwrapped.camera_renderer.render(env.unwrapped.physics.data)
    assert not (clear == 255).all(axis=2).any()
    env.close()


# ------------------------------------------------------------------ the environments
@pytest.mark.parametrize("env_id", DOCKING_IDS)
@pytest.mark.parametrize("obs_mode", ["features", "image"])
def test_default_is_clear_water_bit_for_bit_without_extra_draws(env_id, obs_mode, monkeypatch):
    # Clear water never reaches the optics code: no depth read, no optics draws.
    def refuse(*args, **kwargs):
        raise AssertionError("the optics code ran without optics")

    monkeypatch.setattr("auv_envs.tasks.docking.env.degrade_image", refuse)
    monkeypatch.setattr("auv_envs.tasks.docking.transition.detect_lamps", refuse)
    for name in ("occluded_share", "occlusions_after"):
        monkeypatch.setattr(LampOutages, name, refuse)
    monkeypatch.setattr(CameraRenderer, "render_with_range", refuse)
    size = {"image_size": SMALL_IMAGE} if obs_mode == "image" else {}
    plain = gym.make(env_id, obs_mode=obs_mode, scenario="current", **size)
    explicit = gym.make(env_id, obs_mode=obs_mode, scenario="current", optics=None, **size)
    first, second = _rollout(plain, 7, 30), _rollout(explicit, 7, 30)
    for (o1, r1, i1), (o2, r2, i2) in zip(first, second, strict=True):
        assert _same(o1, o2) and r1 == r2 and _same(i1, i2)
    assert "optics" not in second[0][2] and explicit.unwrapped.calibration.optics is None
    assert plain.unwrapped.np_random.bit_generator.state == \
        explicit.unwrapped.np_random.bit_generator.state
    if obs_mode == "image":  # today's image: the plain render of the forward camera
        u = explicit.unwrapped
        np.testing.assert_array_equal(o2["image"], u.camera_renderer.render(u.physics.data))
    plain.close()
    explicit.close()


def test_clear_features_are_exact_and_water_changes_them():
    clear = gym.make(DOCKING_IDS[1], obs_mode="features")
    murky = gym.make(DOCKING_IDS[1], obs_mode="features", optics=WaterOptics.jerlov("7C"))
    obs, info = clear.reset(seed=2)
    np.testing.assert_array_equal(obs["pixels"], info["true_pixels"].astype(np.float32))
    obs, info = murky.reset(seed=2)
    assert info["true_visible"].all() and not obs["visible"].all()  # 7C at 8-12 m
    assert murky.unwrapped.calibration.optics == WaterOptics.jerlov("7C")


@pytest.mark.parametrize("obs_mode", ["features", "image"])
def test_env_with_optics_survives_pickling(obs_mode):
    size = {"image_size": SMALL_IMAGE} if obs_mode == "image" else {}
    optics = WaterOptics.jerlov("3C", lamp_failure_probability=0.3, occlusion_rate=0.2)
    env = gym.make(DOCKING_IDS[0], obs_mode=obs_mode, optics=optics, **size).unwrapped
    env.reset(seed=3)
    for _ in range(5):
        env.step(np.array([0.5, 0.1, 0.0, 0.2]))
    clone = pickle.loads(pickle.dumps(env))
    assert clone.calibration.optics == optics
    np.testing.assert_array_equal(clone.physics.model.geom_matid, env.physics.model.geom_matid)
    for _ in range(10):
        a = env.step(np.array([0.6, -0.1, 0.1, 0.0]))
        b = clone.step(np.array([0.6, -0.1, 0.1, 0.0]))
        assert _same(a[0], b[0]) and a[1] == b[1] and _same(a[4], b[4])
    env.close()
    clone.close()
