"""Bad input gets a clear error or a documented, tested fallback."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from auv_envs.core.assets import asset_path
from auv_envs.tasks import docking
from tests.conftest import ENV_IDS, make_env


@pytest.fixture(params=ENV_IDS)
def env(request):
    e = make_env(request.param, "state")
    yield e
    e.close()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_action_raises(env, bad):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0.0, bad, 0.0, 0.0], dtype=np.float32))


def test_wrong_action_shape_raises(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.unwrapped.step(np.zeros(3))


def test_out_of_range_action_is_clipped(env):
    other = make_env(env.spec.id, "state")
    try:
        env.reset(seed=3)
        other.reset(seed=3)
        big = np.array([5.0, -7.0, 2.0, -1.5])
        o1, r1, *_ = env.unwrapped.step(big)
        o2, r2, *_ = other.unwrapped.step(np.clip(big, -1, 1))
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2
    finally:
        other.close()


@pytest.mark.parametrize(
    ("kwargs", "exc", "listed"),
    [
        ({"obs_mode": "pixels"}, ValueError, "'state', 'features', 'image'"),
        ({"scenario": "storm"}, ValueError, "'mismatch', 'current'"),
        ({"colour": "red"}, TypeError, "obs_mode"),
    ],
)
def test_unknown_arguments_list_valid_values(kwargs, exc, listed):
    for env_id in ENV_IDS:
        args = dict(kwargs)
        with pytest.raises(exc, match=listed):
            make_env(env_id, args.pop("obs_mode", "state"), **args)


def test_unknown_render_mode_lists_valid_values():
    # Through gym.make, "human" is turned into rgb_array + a viewer wrapper by
    # Gymnasium itself, so check the constructor directly.
    with pytest.raises(ValueError, match="'rgb_array'"):
        docking.DockingStationEnv(render_mode="window")


def test_missing_asset_names_the_file():
    with pytest.raises(FileNotFoundError, match="no_such_station.xml"):
        asset_path("docking/no_such_station.xml")


def test_missing_layout_asset_fails_at_construction(monkeypatch):
    broken = dataclasses.replace(docking.SIX_LIGHTS, asset="docking/missing_layout.xml")
    monkeypatch.setattr(docking.DockingStationEnv, "layout", broken)
    with pytest.raises(FileNotFoundError, match="missing_layout.xml"):
        docking.DockingStationEnv()


def test_step_after_episode_end_raises(env):
    env.reset(seed=0)
    unwrapped = env.unwrapped
    terminated = truncated = False
    while not (terminated or truncated):
        _, _, terminated, truncated, _ = unwrapped.step(np.array([1.0, 1.0, 1.0, 1.0]))
    with pytest.raises(RuntimeError, match="reset"):
        unwrapped.step(np.zeros(4))


def test_calibration_is_read_only(env):
    cal = env.unwrapped.calibration
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.control_period = 1.0
    with pytest.raises(ValueError):
        cal.light_positions[0, 0] = 1.0
    with pytest.raises(ValueError):
        cal.target_position[0] = 1.0
