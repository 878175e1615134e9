"""Each family's configuration and parameters (``auv_envs/tasks/<family>/config.py``): what
``gym.make`` builds is ``params(default_config(env_id))``, built without an environment,
and the batched environment is built from it without a Gymnasium environment."""

from __future__ import annotations

import dataclasses
import importlib

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.families import FAMILIES, family

ALL_IDS = [env_id for entry in FAMILIES for env_id in (entry.env_id, *entry.previous)]


def config_module(env_id: str):
    return importlib.import_module(family(env_id).config)


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gym_make_builds_the_ids_default_configuration(env_id):
    env = gym.make(env_id).unwrapped
    assert env.setup.config == config_module(env_id).default_config(env_id)
    env.close()


@pytest.mark.parametrize("env_id", [entry.env_id for entry in FAMILIES])
def test_params_without_an_environment_are_the_environments(env_id, monkeypatch):
    module = config_module(env_id)
    config = module.default_config(env_id).replace(difficulty="hard")
    env = gym.make(env_id, difficulty="hard").unwrapped
    # No Gymnasium environment, nor the task it runs, may be built on the way.
    monkeypatch.setattr(type(env), "__init__", _refuse)
    monkeypatch.setattr(type(env.task), "__init__", _refuse)
    setup = module.params(config)
    assert setup.config == env.setup.config
    assert setup.observation_space == env.observation_space
    assert setup.action_space == env.action_space
    assert setup.max_episode_steps == env.max_episode_steps and setup.dt == env.dt
    assert setup.model_source.xml == env.model_source.xml
    assert _fields(setup.params) == _fields(env.params)


def test_a_configuration_changes_only_by_replace_and_names_its_fields():
    from auv_envs.tasks.docking.config import default_config

    config = default_config("auv_envs/LampArrayDocking-v2")
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.difficulty = "hard"
    assert config.replace(difficulty="hard").difficulty == "hard"
    assert config.difficulty == "easy"
    with pytest.raises(TypeError, match="no field colour; its fields are .*'difficulty'"):
        config.replace(colour="red")


@pytest.mark.parametrize("env_id, argument", [
    ("auv_envs/DockingMission-v0", {"lights_lost_timeout": 3.0}),
    ("auv_envs/DockingStation-v2", {"mission": True}),
    ("auv_envs/DockingStation-v2", {"layout": "lamp_array"}),
])
def test_an_id_refuses_the_arguments_it_does_not_take(env_id, argument):
    from auv_envs.tasks.docking.config import config_of

    with pytest.raises(TypeError, match=next(iter(argument))):
        config_of(env_id, **argument)


@pytest.mark.parametrize("module, bad, error", [
    ("docking", {"scenario": "storm"}, ValueError),
    ("docking", {"optics": "murky"}, TypeError),
    ("lars", {"baseline": 0.0}, ValueError),
    ("acoustic", {"draw_detections": 1}, TypeError),
])
def test_params_checks_every_value(module, bad, error):
    config = importlib.import_module(f"auv_envs.tasks.{module}.config")
    with pytest.raises(error, match=next(iter(bad))):
        config.params(config.default_config().replace(**bad))


def test_params_refuses_another_familys_configuration():
    from auv_envs.tasks.docking import config as docking
    from auv_envs.tasks.lars import config as lars

    with pytest.raises(TypeError, match="DockingConfig"):
        docking.params(lars.default_config())


@pytest.mark.parametrize("env_id", [entry.env_id for entry in FAMILIES])
def test_the_batched_env_builds_no_gymnasium_env(env_id, monkeypatch):
    pytest.importorskip("jax")
    from auv_envs.batched.functional import FunctionalEnv

    entry = family(env_id)
    module, name = entry.task.split(":")
    monkeypatch.setattr(getattr(importlib.import_module(module), name), "__init__", _refuse)
    env = FunctionalEnv(env_id, difficulty="paper")
    assert env.task.setup.config == entry.setup(obs_mode=env.obs_mode,
                                                difficulty="paper").config


def _refuse(*args, **kwargs):
    raise AssertionError("a Gymnasium environment was built")


def _fields(params) -> dict:
    """A transition's parameters as comparable values."""
    return {field.name: _comparable(getattr(params, field.name))
            for field in dataclasses.fields(params)}


def _comparable(value):
    """``value`` as something ``==`` compares by content: arrays as lists, objects without a
    ``repr`` of their own by their public attributes."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if " object at 0x" in repr(value):
        return {key: _comparable(item) for key, item in vars(value).items()
                if not key.startswith("_")}
    return repr(value)
