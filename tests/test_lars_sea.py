"""LARS sea states: wash-over occlusion and look-alike distractors, counted in rendered images."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from auv_envs.core.env import TaskEnv
from auv_envs.core.sea import WashOver, segments_cross_box
from auv_envs.datasets.lars import tracking_action
from auv_envs.tasks.lars.env import LARSCaptureTask


def test_segments_cross_box_cases():
    centre, half = np.zeros(3), np.array([1.0, 1.0, 1.0])
    starts = np.array([[0.0, 0.0, 5.0], [3.0, 0.0, 5.0], [0.0, 0.0, 5.0], [3.0, 0.5, 0.5],
                       [3.0, 2.0, 0.5], [0.5, 0.5, 5.0], [0.5, 0.5, 5.0]])
    ends = np.array([[0.0, 0.0, -5.0], [3.0, 0.0, -5.0], [0.0, 0.0, 2.0], [-3.0, 0.5, 0.5],
                     [-3.0, 2.0, 0.5], [5.0, 0.5, 0.5], [0.9, 0.5, -1.0]])
    np.testing.assert_array_equal(
        segments_cross_box(starts, ends, centre, half, np),
        [True, False, False, True, False, False, True],
    )


def test_wash_over_schedule():
    wash = WashOver(period=4.0, duration=1.0, phase=0.5)
    assert wash.offset(0.4) is None
    assert wash.offset(0.5) == pytest.approx(-wash.sweep)
    assert wash.offset(1.0) == pytest.approx(0.0)
    assert wash.offset(4.5) == pytest.approx(-wash.sweep)
    assert wash.offset(2.0) is None


def _red_mask(image):
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    return ((hsv[..., 0] < 8) | (hsv[..., 0] > 172)) & (hsv[..., 1] > 150) & (hsv[..., 2] > 80)


def _count_in_rendered_episode(sea_state, seed, steps=150):
    """Frames (left image) where a crest hides the marker's paint, and frames
    with more red triangles than the one marker, counted from the pixels."""
    size = (160, 120)
    env = TaskEnv(LARSCaptureTask, obs_mode="stereo", sea_state=sea_state, control="position",
                         image_size=size)
    try:
        obs, info = env.reset(seed=seed)
        occluded_frames = distractor_frames = 0
        for _ in range(steps):
            mask = _red_mask(obs["left"])
            n, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8))
            distractor_frames += int(np.sum(stats[1:, cv2.CC_STAT_AREA] >= 12)) > 1
            tri = info["true_pixels"][0]
            if np.all((tri >= 0) & (tri < size)):
                # The marker projects fully into the image: how much paint shows?
                inside = np.zeros(mask.shape, np.uint8)
                cv2.fillPoly(inside, [np.round(tri * 16).astype(np.int32)], 1, shift=4)
                shown = np.sum(mask & (inside > 0)) / max(inside.sum(), 1)
                occluded_frames += shown < 0.7
            obs, _, terminated, truncated, info = env.step(tracking_action(env, info))
            if terminated or truncated:
                break
        return occluded_frames, distractor_frames
    finally:
        env.close()


@pytest.mark.parametrize("seed", [0, 1])
def test_severe_sea_hides_the_marker_and_shows_distractors(seed):
    occluded, distractors = _count_in_rendered_episode("severe", seed)
    assert occluded >= 3
    assert distractors >= 10


@pytest.mark.parametrize("seed", [0, 1])
def test_calm_sea_has_neither(seed):
    assert _count_in_rendered_episode("calm", seed) == (0, 0)


def test_severe_info_flags_match_geometry():
    env = TaskEnv(LARSCaptureTask, obs_mode="features", sea_state="severe", control="position")
    _, info = env.reset(seed=2)
    occluded = hidden_corner = 0
    for _ in range(200):
        _, _, te, tr, info = env.step(tracking_action(env, info))
        occluded += info["marker_occluded"]
        if info["marker_occluded"]:
            assert info["marker_visible"] < 3
            hidden_corner += 1
        if te or tr:
            break
    assert occluded > 0 and hidden_corner == occluded
    assert math.isfinite(info["capture_error"])
