"""One name for one thing: pooled names work wherever a name does,
unknown names get the closest matches, a bare env id gets a hint about its namespace."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import pytest

import auv_envs
from baselines import registry
from baselines.commands.evaluate import listing
from baselines.evaluation import evaluate_all
from baselines.registry import agent_groups, agent_spec, group_members, resolve_agent_names

DOCK = "auv_envs/DockingStation-v2"


@pytest.fixture
def test_group(monkeypatch):
    """Two cheap training-seed stand-ins pooled under one group name, for this test only."""
    base = agent_spec("random")
    for seed in (0, 1):
        name = f"test-pooled-s{seed}"
        monkeypatch.setitem(registry._REGISTRY, name,
                            dataclasses.replace(base, name=name, group="test-pooled"))
    return "test-pooled"


def test_a_group_name_stands_for_its_seeds(test_group):
    assert group_members(test_group) == ["test-pooled-s0", "test-pooled-s1"]
    assert resolve_agent_names(["random", test_group, "random"]) == \
        ["random", "test-pooled-s0", "test-pooled-s1"]
    assert agent_spec(test_group).name == "test-pooled-s0"  # one episode: the first seed
    run = evaluate_all(env_ids=[DOCK], agents=[test_group], seeds=[3],
                       env_kwargs=({DOCK: {"time_limit": 1.0}},))
    assert sorted(r.agent for r in run.rows) == ["test-pooled-s0", "test-pooled-s1"]
    shipped = sorted(set(agent_groups().values()) - {test_group})
    assert shipped, "the catalogue ships pooled RL agents"
    text = listing()
    for group in shipped:
        assert f"  {group} = {', '.join(group_members(group))}" in text


def test_unknown_names_get_the_closest_matches():
    with pytest.raises(ValueError, match=r"'pd-stat' \(did you mean pd-state"):
        resolve_agent_names(["pd-stat"])
    with pytest.raises(KeyError, match="did you mean random"):
        agent_spec("randon")
    with pytest.raises(ValueError, match=r"'zzzz-qqqq'; `python evaluate.py --list`"):
        resolve_agent_names(["zzzz-qqqq"])


@pytest.mark.filterwarnings("ignore:.*out of date")
@pytest.mark.parametrize("env_id", [*auv_envs.ENVIRONMENTS, *auv_envs.PREVIOUS_VERSIONS])
def test_a_bare_env_id_names_its_namespace(env_id):
    with pytest.raises(gym.error.NameNotFound, match=f"gym.make\\('{env_id}'\\)"):
        gym.make(env_id.split("/")[-1])
