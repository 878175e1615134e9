"""Every shipped RL policy still works with its environment.

Each group's training seeds play two fixed episodes each at the level the group is
ranked on; the group must end them where a working policy does, far from where
``random`` ends them: docking near the entrance, LARS captured, acoustic tracked. A
policy whose environment changed under it (observation layout, normalisation, the
plant) fails here before it fails on the leaderboard. The image policy
(``distill-docking-image``, a minute an episode) is left to the leaderboard.
"""

from __future__ import annotations

import statistics

import gymnasium as gym
import pytest
import torch

from baselines.evaluation import run_episode
from baselines.registry import agent_spec, group_members, make_agent
from baselines.rl.agents import SHIPPED

#: Fixed seeds, clear of the leaderboard's (100000 on) and of every training range.
SEEDS = (424200, 424201)
#: Group -> (level, extra env arguments, what its episodes must show).
CHECKS = {
    "cppo-docking-features": ("paper", {}, "near"),
    "cppo-docking-features-hard": ("hard", {}, "near"),
    "cppo-lamp-array-features": ("paper", {}, "near"),
    "cppo-lamp-array-features-hard": ("hard", {}, "near"),
    "cppo-mission-nav-filter": ("paper", {}, "near"),
    # Trained at easy (the release's water and plant), where they dock; half and a third at
    # paper on the published board.
    "ppo-docking-features": ("easy", {}, "near"),
    "ppo-lamp-array-features": ("easy", {}, "near"),
    "ppo-lars-features": ("paper", {}, "captured"),
    "cppo-lars-features": ("paper", {}, "captured"),
    "ppo-acoustic-measurements": ("paper", {"time_limit": 10.0}, "tracked"),
    "cppo-acoustic-measurements": ("paper", {"time_limit": 10.0}, "tracked"),
    "cppo-acoustic-track": ("hard", {"time_limit": 10.0}, "tracked"),
}


def _episode(name: str, level: str, kwargs: dict, seed: int,
             env_id: str | None = None) -> dict:
    spec = agent_spec(name)
    env = gym.make(env_id or spec.env_ids[0], obs_mode=spec.obs_mode, difficulty=level,
                   **{**spec.env_kwargs, **kwargs})
    try:
        return run_episode(env, make_agent(name, env), seed, env.spec.id, name).metrics
    finally:
        env.close()


def test_every_shipped_group_is_checked():
    # The shipped policies' groups (other tests in this process may register their own).
    shipped = {agent_spec(name).group for name in SHIPPED} - {"distill-docking-image", None}
    assert shipped == set(CHECKS)


@pytest.mark.parametrize("group", sorted(CHECKS))
def test_a_shipped_policy_still_does_its_task(group):
    torch.set_num_threads(1)
    level, kwargs, check = CHECKS[group]
    episodes = [_episode(name, level, kwargs, seed)
                for name in group_members(group) for seed in SEEDS]
    if check == "near":  # docked, or failed at the entrance; random ends metres away
        distance = statistics.median(e["final_distance"] for e in episodes)
        assert distance < 1.0, (group, [e["final_distance"] for e in episodes])
        assert any(e["success"] for e in episodes), group
    elif check == "captured":
        assert sum(e["success"] for e in episodes) >= len(episodes) - 1, group
    else:  # tracked: RMSE in decimetres where random's is some 140 m
        assert max(e["rmse"] for e in episodes) < 1.0, (group, [e["rmse"] for e in episodes])


def test_the_check_fails_for_random():
    """The thresholds separate a working policy from one that does nothing useful."""
    episodes = [_episode("random", "paper", {}, seed, "auv_envs/DockingStation-v2")
                for seed in SEEDS]
    assert statistics.median(e["final_distance"] for e in episodes) > 1.0
