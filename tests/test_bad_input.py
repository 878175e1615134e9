"""Bad input gets a clear error or a documented, tested fallback."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from auv_envs.core.assets import asset_path
from auv_envs.core.env import TaskEnv
from auv_envs.tasks.docking import config as docking_config
from auv_envs.tasks.docking import env as docking
from tests.conftest import DOCKING_IDS, ENV_IDS, leaves, make_env


@pytest.fixture(params=ENV_IDS)
def env(request):
    e = make_env(request.param, "state")
    yield e
    e.close()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_action_raises(env, bad):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        action = env.action_space.sample()
        action[-1] = bad
        env.step(action)


def test_wrong_action_shape_raises(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.unwrapped.step(np.zeros(env.action_space.shape[0] + 1))


def test_out_of_range_action_is_clipped(env):
    other = make_env(env.spec.id, "state")
    try:
        env.reset(seed=3)
        other.reset(seed=3)
        space = env.action_space
        span = space.high - space.low
        big = np.where(np.arange(space.shape[0]) % 2 == 0, space.high + 3 * span,
                       space.low - 2 * span).astype(np.float64)
        o1, r1, *_ = env.unwrapped.step(big)
        o2, r2, *_ = other.unwrapped.step(np.clip(big, space.low, space.high))
        for leaf1, leaf2 in zip(leaves(o1), leaves(o2), strict=True):
            np.testing.assert_array_equal(leaf1, leaf2)
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
    for env_id in DOCKING_IDS:
        args = dict(kwargs)
        with pytest.raises(exc, match=listed):
            make_env(env_id, args.pop("obs_mode", "state"), **args)


def test_unknown_render_mode_lists_valid_values():
    # Through gym.make, "human" is turned into rgb_array + a viewer wrapper by
    # Gymnasium itself, so check the constructor directly.
    with pytest.raises(ValueError, match="'rgb_array'"):
        TaskEnv(docking.DockingStationTask, render_mode="window")


def test_missing_asset_names_the_file():
    with pytest.raises(FileNotFoundError, match="no_such_station.xml"):
        asset_path("docking/no_such_station.xml")


def test_missing_layout_asset_fails_at_construction(monkeypatch):
    broken = dataclasses.replace(docking_config.SIX_LIGHTS, asset="docking/missing_layout.xml")
    monkeypatch.setitem(docking_config.LAYOUTS, "six_lights", broken)
    with pytest.raises(FileNotFoundError, match="missing_layout.xml"):
        TaskEnv(docking.DockingStationTask)


def test_unknown_argument_is_a_type_error_naming_valid_ones(env):
    with pytest.raises(TypeError, match="obs_mode"):
        make_env(env.spec.id, "state", colour="red")


def test_unknown_obs_mode_lists_valid_values(env):
    with pytest.raises(ValueError, match="'state'"):
        make_env(env.spec.id, "no-such-mode")


def test_step_after_episode_end_raises(env):
    env.reset(seed=0)
    unwrapped = env.unwrapped
    action = env.action_space.high.copy()
    for _ in range(100_000):
        _, _, terminated, truncated, _ = unwrapped.step(action)
        if terminated or truncated:
            break
    assert terminated or truncated
    with pytest.raises(RuntimeError, match="reset"):
        unwrapped.step(action)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_docking_calibration_is_read_only(env_id):
    env = make_env(env_id, "state")
    cal = env.unwrapped.calibration
    env.close()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.control_period = 1.0
    with pytest.raises(ValueError):
        cal.light_positions[0, 0] = 1.0
    with pytest.raises(ValueError):
        cal.target_position[0] = 1.0


def test_calibration_is_a_frozen_dataclass_with_read_only_arrays(env):
    cal = env.unwrapped.calibration
    assert dataclasses.is_dataclass(cal)
    field = dataclasses.fields(cal)[0].name
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(cal, field, None)
    for f in dataclasses.fields(cal):
        value = getattr(cal, f.name)
        if isinstance(value, np.ndarray):
            assert not value.flags.writeable, f.name


@pytest.mark.parametrize("env_id", DOCKING_IDS)
@pytest.mark.parametrize("size, match", [((4, 4), "at least 8x8"), ((64, 48, 3), "width, height")])
def test_docking_rejects_a_bad_image_size(env_id, size, match):
    with pytest.raises(ValueError, match=match):
        make_env(env_id, "image", image_size=size)


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, 0.0, -1.0])
def test_time_limit_must_be_a_positive_finite_number(env_id, bad):
    with pytest.raises(ValueError, match="time_limit must be"):
        make_env(env_id, "state", time_limit=bad)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, 0.0])
def test_docking_lights_lost_timeout_must_be_a_positive_finite_number(env_id, bad):
    with pytest.raises(ValueError, match="lights_lost_timeout must be"):
        make_env(env_id, "state", lights_lost_timeout=bad)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
@pytest.mark.parametrize("bad", [0, -1, 1.5, 2.0, True, "2", None])
def test_docking_physics_substeps_must_be_a_positive_integer(env_id, bad):
    with pytest.raises(ValueError, match="physics_substeps must be a positive integer"):
        make_env(env_id, "state", physics_substeps=bad)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_docking_rejects_an_unknown_integrator(env_id):
    with pytest.raises(ValueError, match="unknown integrator 'implicit'.*'rk4', 'euler'"):
        make_env(env_id, "state", integrator="implicit")
