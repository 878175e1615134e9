"""Headless rendering: correct images, independent renderers, clean interpreter exit."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np

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


def test_render_mode_rgb_array_matches_image_observation():
    env = make_env(DOCKING_IDS[0], "image", render_mode="rgb_array")
    try:
        obs, _ = env.reset(seed=2)
        np.testing.assert_array_equal(env.render(), obs["image"])
    finally:
        env.close()


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
