"""Headless rendering: correct images, independent renderers, clean interpreter exit."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest

from tests.conftest import DOCKING_IDS, make_env


def test_closing_one_renderer_leaves_another_intact():
    # Regression: freeing one MuJoCo render context while another was current
    # deleted the other's framebuffers, which then rendered black.
    reference = make_env(DOCKING_IDS[1], "image")
    expected, _ = reference.reset(seed=1)
    reference.close()

    first = make_env(DOCKING_IDS[0], "image")
    first.reset(seed=1)
    second = make_env(DOCKING_IDS[1], "image")
    first.close()
    obs, _ = second.reset(seed=1)
    second.close()
    np.testing.assert_array_equal(obs["image"], expected["image"])


def test_image_is_dark_water_with_bright_lamps():
    env = make_env(DOCKING_IDS[0], "image", image_size=(160, 120))
    try:
        obs, info = env.reset(seed=0)
        image = obs["image"].astype(float)
        assert image.shape == (120, 160, 3)
        assert np.median(image) < 40  # dark, attenuating water
        assert image.max() > 200  # bright lamps
        assert info["lights_visible"] >= 3
    finally:
        env.close()


def test_onboard_render_matches_image_observation():
    env = make_env(DOCKING_IDS[0], "image", image_size=(96, 72), render_mode="rgb_array",
                   render_camera="onboard", render_size=(96, 72))
    try:
        obs, _ = env.reset(seed=2)
        np.testing.assert_array_equal(env.render(), obs["image"])
    finally:
        env.close()


def _hull_mask(frame: np.ndarray) -> np.ndarray:
    """The docking vehicle's orange paint: red well above green, little blue."""
    r, g, b = (frame[..., k].astype(int) for k in range(3))
    return (r > 90) & (r > g + 30) & (b < 70)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_chase_view_shows_vehicle_station_and_water(env_id):
    env = make_env(env_id, "state", render_mode="rgb_array", render_size=(320, 240))
    try:
        env.reset(seed=5)
        frame = env.render()
        assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
        # Readable: lit, neither black nor washed out; open water is the water's colour.
        assert 20 < frame.mean() < 120
        water = frame[:20].reshape(-1, 3).mean(axis=0)
        assert water[2] > water[0] + 10  # blue-green, not black
        hull = _hull_mask(frame)
        assert hull.sum() > 300  # the vehicle is in view, large enough to see
        # The station's grey steel (grey: balanced channels, brighter than the water).
        grey = (np.ptp(frame.astype(int), axis=2) < 25) & (frame.mean(axis=2) > 70)
        assert grey.sum() > 30
    finally:
        env.close()


def test_chase_view_follows_the_vehicle_and_shows_its_turn():
    env = make_env(DOCKING_IDS[0], "state", render_mode="rgb_array", render_size=(320, 240))
    try:
        env.reset(seed=5)
        before = _hull_mask(env.render())
        station_before = (np.ptp(env.render().astype(int), axis=2) < 25).sum()
        for _ in range(40):  # surge towards the station while yawing hard
            env.step(np.array([1.0, 0.0, 0.0, 1.0]))
        frame = env.render()
        after = _hull_mask(frame)
        overlap = (before & after).sum() / (before | after).sum()
        assert overlap < 0.8  # the hull's pixels moved: the picture shows the turn
        # The camera follows the vehicle: its hull stays near the image centre.
        rows, cols = np.nonzero(after)
        assert abs(cols.mean() - 160) < 60 and abs(rows.mean() - 120) < 60
        assert station_before != (np.ptp(frame.astype(int), axis=2) < 25).sum()
    finally:
        env.close()


def _auv_centroid(frame: np.ndarray) -> np.ndarray:
    """Centre of the LARS AUV's white hull below the horizon (lower two thirds)."""
    lower = frame[frame.shape[0] // 3:].astype(int)
    white = (lower.min(axis=2) > 150) & (np.ptp(lower, axis=2) < 40)
    rows, cols = np.nonzero(white)
    assert rows.size > 30, "the AUV is not in view"
    return np.array([rows.mean(), cols.mean()])


def test_lars_side_view_shows_ship_arm_auv_and_sea():
    env = make_env("auv_envs/LARSCapture-v0", "state", render_mode="rgb_array",
                   render_size=(320, 240))
    try:
        env.reset(seed=7)
        first = env.render()
        assert first.shape == (240, 320, 3)
        assert 60 < first.mean() < 200
        sky, sea = first[:10].reshape(-1, 3).mean(0), first[-10:].reshape(-1, 3).mean(0)
        assert sky.mean() > 150 and sea[2] > sea[0] + 30  # light sky above, blue sea below
        yellow = (first[..., 0] > 150) & (first[..., 1] > 120) & (first[..., 2] < 80)
        assert yellow.sum() > 100  # the arm
        start = _auv_centroid(first)
        for _ in range(60):  # 2.4 s, or until the idle arm hits something
            *_, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
            if terminated or truncated:
                break
        assert np.linalg.norm(_auv_centroid(env.render()) - start) > 2.0  # it drifts
    finally:
        env.close()


def test_lars_stereo_render_is_the_observation_pair():
    env = make_env("auv_envs/LARSCapture-v0", "stereo", image_size=(64, 48),
                   render_mode="rgb_array", render_camera="stereo", render_size=(64, 48))
    try:
        obs, _ = env.reset(seed=3)
        np.testing.assert_array_equal(env.render(), np.hstack([obs["left"], obs["right"]]))
    finally:
        env.close()


@pytest.mark.parametrize("env_id", [*DOCKING_IDS, "auv_envs/LARSCapture-v0"])
def test_render_arguments_are_checked(env_id):
    with pytest.raises(ValueError, match="render_camera"):
        make_env(env_id, "state", render_camera="periscope")
    with pytest.raises(ValueError, match="render_size|image_size"):
        make_env(env_id, "state", render_mode="rgb_array", render_size=(4, 4))


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_rendering_leaves_image_observations_unchanged(env_id):
    # The chase view draws fog and the skybox; the observation camera must not.
    plain = make_env(env_id, "image", image_size=(64, 48))
    viewed = make_env(env_id, "image", image_size=(64, 48), render_mode="rgb_array",
                      render_size=(64, 48))
    try:
        a, _ = plain.reset(seed=4)
        b, _ = viewed.reset(seed=4)
        for _ in range(5):
            np.testing.assert_array_equal(a["image"], b["image"])
            viewed.render()
            action = np.array([0.5, 0.1, 0.0, 0.2])
            a, *_ = plain.step(action)
            b, *_ = viewed.step(action)
        np.testing.assert_array_equal(a["image"], b["image"])
    finally:
        plain.close()
        viewed.close()


def test_interpreter_exit_without_close_prints_no_egl_traceback():
    script = textwrap.dedent(
        f"""
        import gymnasium as gym, auv_envs
        env = gym.make({DOCKING_IDS[0]!r}, obs_mode="image", image_size=(64, 48))
        env.reset(seed=0)
        other = gym.make({DOCKING_IDS[1]!r}, obs_mode="image", image_size=(64, 48))
        other.reset(seed=0)
        print("rendered")
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert "rendered" in result.stdout
    assert "Traceback" not in result.stderr
    assert "EGLError" not in result.stderr


@pytest.mark.parametrize("env_id", [DOCKING_IDS[0], "auv_envs/LARSCapture-v0",
                                    "auv_envs/AcousticTracking-v2"])
def test_human_mode_shows_the_rgb_frames_in_a_window(env_id, monkeypatch):
    # gym.make wraps an rgb_array env in Gymnasium's HumanRendering (a pygame
    # window); SDL's dummy driver gives it a window without a display.
    pygame = pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    env = gym.make(env_id, render_mode="human", render_size=(160, 120))
    try:
        assert isinstance(env, gym.wrappers.HumanRendering)
        env.reset(seed=1)
        for _ in range(3):
            env.step(np.zeros(env.action_space.shape, dtype=env.action_space.dtype))
        shown = pygame.surfarray.array3d(env.window).swapaxes(0, 1)
        np.testing.assert_array_equal(shown, env.unwrapped.render())
        assert shown.std() > 10
    finally:
        env.close()


def test_round_geoms_are_drawn_with_fewer_sides_in_small_images():
    from auv_envs.core.rendering import outline_slices

    # n >= pi sqrt(H / 3): a circle of radius H/3 px within half a pixel of its outline.
    assert outline_slices(84, 28) == 17
    assert outline_slices(221, 28) == 27
    assert [outline_slices(h, 28) for h in (222, 240, 480, 960)] == [28] * 4  # as before
    assert outline_slices(12, 28) == 8  # floor
    assert outline_slices(84, 12) == 12  # never more than the model asks
    for height in (24, 84, 120, 221):
        n = outline_slices(height, 1000)
        radius = height / 3.0
        assert radius * (1.0 - np.cos(np.pi / n)) <= 0.5
        assert radius * (1.0 - np.cos(np.pi / (n - 1))) > 0.5 or n == 8


def test_renderer_leaves_the_models_visual_settings_as_they_were():
    from auv_envs.core.rendering import CameraRenderer

    env = make_env(DOCKING_IDS[0], "state")
    model = env.unwrapped.physics.model
    quality = model.vis.quality
    before = (quality.numslices, quality.numstacks)
    renderer = CameraRenderer(model, (env.unwrapped.physics.camera_name,), 84, 84,
                              hidden_groups=(1,), fit_outlines=True)
    renderer.close()
    assert (quality.numslices, quality.numstacks) == before
    with pytest.raises(ValueError, match="geom group"):
        CameraRenderer(model, (env.unwrapped.physics.camera_name,), 84, 84, hidden_groups=(6,))
    env.close()


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_the_nose_camera_never_sees_its_own_hull(env_id):
    # The image observation leaves the hull out (0.25 ms of a 0.89 ms 84x84
    # frame) on the geometric argument of camera_sees_hull; a renderer that draws
    # it must find no hull pixel, and the images must be the same.
    from auv_envs.core.rendering import CameraRenderer

    env = make_env(env_id, "image", image_size=(96, 72))
    physics = env.unwrapped.physics
    assert not physics.camera_sees_hull(96, 72)
    assert env.unwrapped.camera_renderer._option.geomgroup[1] == 0
    drawing_hull = CameraRenderer(physics.model, (physics.camera_name,), 96, 72,
                                  fit_outlines=True, detail=physics.detail_levels())
    hull = physics.hull_geoms[0]
    try:
        env.reset(seed=5)
        env.action_space.seed(5)
        for _ in range(40):
            obs, *_ = env.step(env.action_space.sample())
            assert not np.any(drawing_hull.render_geom_ids(physics.data) == hull)
            np.testing.assert_array_equal(drawing_hull.render(physics.data), obs["image"])
        # The argument can fail: a camera looking back over the hull sees it.
        saved = physics.camera_mat_body.copy()
        physics.camera_mat_body[:] = -saved
        try:
            assert physics.camera_sees_hull(96, 72)
        finally:
            physics.camera_mat_body[:] = saved
    finally:
        drawing_hull.close()
        env.close()
