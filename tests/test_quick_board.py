"""The default run's design (baselines/evaluation/quick.py): which episodes it plays."""

from __future__ import annotations

from collections import Counter

import pytest

import auv_envs
from baselines.commands.evaluate import default_agents
from baselines.evaluation import plan, quick
from baselines.registry import agent_groups, group_members
from baselines.seeds import default_seeds
from baselines.stats import ALPHA, paired_p_value

DOCK = "auv_envs/DockingStation-v2"
ACOUSTIC = "auv_envs/AcousticTracking-v2"


def _planned(env_ids, agents, levels=("paper", "hard")):
    seeds = default_seeds(quick.max_episodes())
    variants = [{e: {"difficulty": level} for e in env_ids} for level in levels]
    tasks, _ = plan(env_ids, agents, seeds, None, variants)
    return quick.thin(tasks, seeds, agent_groups()), seeds


def test_each_table_plays_its_episodes_on_the_first_seeds():
    tasks, seeds = _planned([DOCK, ACOUSTIC], ["random", "pd-state", "ls-kf"])
    count = Counter((t.env_id, dict(t.env_kwargs)["difficulty"], t.agent) for t in tasks)
    assert count[DOCK, "paper", "random"] == 10 and count[DOCK, "paper", "pd-state"] == 10
    assert count[DOCK, "hard", "random"] == 30 and count[DOCK, "hard", "pd-state"] == 30
    assert count[ACOUSTIC, "paper", "ls-kf"] == 20 and count[ACOUSTIC, "hard", "random"] == 10
    hard_seeds = sorted(t.seed for t in tasks if t.env_id == DOCK and t.agent == "random"
                        and dict(t.env_kwargs)["difficulty"] == "hard")
    assert hard_seeds == seeds[:30]


def test_a_groups_training_seeds_take_the_evaluation_seeds_in_turn():
    group = "cppo-docking-features-hard"
    members = group_members(group)
    assert len(members) == 3
    tasks, seeds = _planned([DOCK], [*members, "random"], levels=("hard",))
    by_seed = {t.seed: t.agent for t in tasks if t.agent != "random"}
    # Every evaluation seed played once by the group, member i mod 3 on seed i.
    assert sorted(by_seed) == seeds[:30]
    for i, seed in enumerate(seeds[:30]):
        assert by_seed[seed] == sorted(members)[i % 3]
    random_seeds = sorted(t.seed for t in tasks if t.agent == "random")
    assert random_seeds == sorted(by_seed)  # the same seeds as every other agent


def test_the_quick_board_leaves_the_full_board_agents_out_and_says_which():
    quick_agents, left_out = default_agents(auv_envs.ENVIRONMENTS, quick_board=True)
    full_agents, heavy = default_agents(auv_envs.ENVIRONMENTS, quick_board=False)
    groups = agent_groups()
    for name in quick.FULL_BOARD_ONLY:
        assert name in left_out and name not in quick_agents
        assert not any(groups.get(a) == name for a in quick_agents)
        assert name in full_agents or any(groups.get(a) == name for a in full_agents)
    assert "ofnmpc-ekf" in quick_agents and "pd-state" in quick_agents
    assert set(heavy) <= set(left_out)


@pytest.mark.parametrize("level", ["easy", "paper", "hard"])
def test_every_level_has_a_count(level):
    assert quick.episodes_for(DOCK, {"difficulty": level}) >= 10
    assert quick.episodes_for(ACOUSTIC, {"difficulty": level}) >= 10


@pytest.mark.parametrize("env_id", list(auv_envs.ENVIRONMENTS))
@pytest.mark.parametrize("level", ["easy", "paper", "hard"])
def test_every_table_can_tell_its_best_agent_from_random_by_rank(env_id, level):
    """Paired on the table's seeds, a row that succeeds (or tracks better) on all but two
    of them beats random's failures at 5 %: the ranks, not only the intervals, can tell
    the best agent from random."""
    n = quick.episodes_for(env_id, {"difficulty": level})
    seeds = [str(s) for s in range(n)]
    best = {s: float(i < n - 2) for i, s in enumerate(seeds)}
    random = dict.fromkeys(seeds, 0.0)
    assert paired_p_value(best, random) < ALPHA


def test_the_quick_board_on_other_seeds_takes_each_tables_first_ones(tmp_path):
    """``--design quick --seeds``: the design on fresh seeds, each table its first seeds."""
    import json

    import evaluate

    code = evaluate.main(["--design", "quick", "--seeds", "300000-300011", "--envs",
                          "LARSCapture-v0", "--agents", "random", "--difficulty", "paper",
                          "--workers", "1", "--no-progress", "--no-video",
                          "--out", str(tmp_path)])
    assert code == 0
    episodes = json.loads((tmp_path / "episodes.json").read_text())
    assert sorted(e["seed"] for e in episodes) == list(range(300000, 300010))  # LARS paper: 10


def test_the_quick_board_refuses_an_episode_count(tmp_path, capsys):
    import evaluate

    with pytest.raises(SystemExit) as exit_info:
        evaluate.main(["--design", "quick", "--episodes", "3", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "--episodes sets the full board's episodes" in capsys.readouterr().err


def test_the_help_gives_the_tables_sizes_without_markup():
    from baselines.commands.evaluate import build_parser

    text = build_parser("python evaluate.py").format_help()
    assert "``" not in text and ":mod:" not in text and ":class:" not in text
    flat = " ".join(text.split())
    for family, table in quick.EPISODES.items():
        name = family.split("/")[-1]
        assert name in flat
        for level in ("paper", "hard"):
            assert f"{table[level]} at {level}" in flat
