"""Agents: registry, protocol, and the reference controller proving the task is solvable."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.evaluation import run_episode
from baselines.registry import agent_names, agent_spec, make_agent
from tests.conftest import DOCKING_IDS, make_env


def assert_docked(row, tolerances) -> None:
    """The episode ended docked, its final lateral and vertical errors inside the env's
    tolerances (shared by the docking agents' episode tests)."""
    assert row.success, row.failure_reason
    assert abs(row.metrics["final_lateral_error"]) <= tolerances.lateral
    assert abs(row.metrics["final_vertical_error"]) <= tolerances.vertical


def test_registry_lists_builtin_agents():
    assert {"random", "pd-state"} <= set(agent_names())


def test_unknown_agent_names_the_closest_and_where_to_list_all():
    with pytest.raises(KeyError, match="did you mean pd-state"):
        agent_spec("pd-stat")
    with pytest.raises(KeyError, match="--list"):
        agent_spec("no-such-agent")


@pytest.mark.parametrize("env_id", DOCKING_IDS)
@pytest.mark.parametrize("seed", [100_000, 100_001, 100_002])
def test_pd_reference_controller_docks_in_mismatch_scenario(env_id, seed):
    env = make_env(env_id, "state", scenario="mismatch")
    try:
        row = run_episode(env, make_agent("pd-state", env), seed, env_id, "pd-state")
    finally:
        env.close()
    tol = env.unwrapped.calibration.tolerances
    assert_docked(row, tol)
    assert abs(row.metrics["final_heading_error_deg"]) <= tol.heading_deg
    assert row.metrics["docking_time"] < 100.0


def test_pd_agent_rejects_non_state_observations():
    env = make_env(DOCKING_IDS[0], "features")
    try:
        with pytest.raises(ValueError, match="state"):
            make_agent("pd-state", env)
    finally:
        env.close()


def test_random_agent_is_seeded_and_in_bounds():
    env = make_env(DOCKING_IDS[0], "state")
    try:
        a, b = make_agent("random", env), make_agent("random", env)
        a.reset(5)
        b.reset(5)
        acts_a = [a.act(None, {}) for _ in range(20)]
        acts_b = [b.act(None, {}) for _ in range(20)]
        np.testing.assert_array_equal(acts_a, acts_b)
        assert all(env.action_space.contains(x) for x in acts_a)
        b.reset(6)
        assert not np.array_equal(acts_a[0], b.act(None, {}))
    finally:
        env.close()


def test_random_agent_does_not_dock():
    env = make_env(DOCKING_IDS[0], "state")
    try:
        rows = [run_episode(env, make_agent("random", env), s, DOCKING_IDS[0], "random")
                for s in (1, 2)]
    finally:
        env.close()
    assert not any(r.success for r in rows)
