"""Image labels of the docking lamps: the segmentation draw and ``lamps_in_image``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from tests.conftest import DOCKING_IDS


@pytest.fixture(params=DOCKING_IDS)
def image_env(request):
    env = gym.make(request.param, obs_mode="image")
    yield env.unwrapped
    env.close()


def test_geom_ids_name_real_geoms_and_leave_the_next_render_alone(image_env):
    env = image_env
    env.reset(seed=3)
    before = env.camera_renderer.render(env.physics.data)
    ids = env.camera_renderer.render_geom_ids(env.physics.data)
    after = env.camera_renderer.render(env.physics.data)
    np.testing.assert_array_equal(before, after)  # the segmentation flags are put back
    assert ids.shape == before.shape[:2] and ids.dtype == np.int32
    assert ids.min() >= -1 and ids.max() < env.physics.model.ngeom
    assert (ids == -1).any()  # open water
    # Every lamp in view shows as its own geom, where the clear render has white pixels.
    lamps = env.physics.lamp_geoms
    assert np.isin(lamps, ids).any()
    white = (before == 255).all(axis=-1)
    assert white[np.isin(ids, lamps)].mean() > 0.9


def test_a_lamp_in_full_view_is_labelled_at_its_centre(image_env):
    """A sphere's pixels are centred on its centre's projection (to under a pixel:
    perspective and the pixel grid); a lamp hidden from its centre ray may still show."""
    env = image_env
    _, info = env.reset(seed=5)
    pixels, shown = env.lamps_in_image()
    assert shown.shape == (len(pixels),) and shown.dtype == bool
    full = info["true_visible"]
    assert full.any()
    assert shown[full].all()
    np.testing.assert_allclose(pixels[full], info["true_pixels"][full], atol=1.0)
    assert np.isnan(pixels[~shown]).all()


def test_partly_hidden_lamp_is_labelled_where_it_shows():
    """Six lights, seed 1: light 1's centre ray is blocked by the station's frame, but
    part of its sphere shows; its label is the centroid of that part."""
    env = gym.make(DOCKING_IDS[0], obs_mode="image")
    try:
        _, info = env.reset(seed=1)
        pixels, shown = env.unwrapped.lamps_in_image()
        hidden = np.flatnonzero(shown & ~info["true_visible"])
        assert hidden.size >= 1
        ids = env.unwrapped.camera_renderer.render_geom_ids(env.unwrapped.physics.data)
        for i in hidden:
            rows, cols = np.nonzero(ids == env.unwrapped.physics.lamp_geoms[i])
            np.testing.assert_allclose(pixels[i], (cols.mean() + 0.5, rows.mean() + 0.5))
    finally:
        env.close()


def test_labels_need_the_camera_renderer():
    env = gym.make(DOCKING_IDS[0], obs_mode="features")
    try:
        env.reset(seed=0)
        with pytest.raises(RuntimeError, match="obs_mode='image'"):
            env.unwrapped.lamps_in_image()
    finally:
        env.close()


def test_a_failed_lamp_is_not_labelled():
    from auv_envs.tasks.docking.optics import WaterOptics

    optics = WaterOptics.jerlov("1C", lamp_failure_probability=1.0)
    env = gym.make(DOCKING_IDS[1], obs_mode="image", optics=optics)
    try:
        _, info = env.reset(seed=5)
        assert info["true_visible"].any()
        pixels, shown = env.unwrapped.lamps_in_image()
        assert not shown.any() and np.isnan(pixels).all()
    finally:
        env.close()
