"""The published leaderboard and the README's front door say what is true today: the board
names only the newest registered ids and agents that exist, the README's headline table
is the one the published board gives, and the README's agent table lists every agent."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

import auv_envs
from baselines import leaderboard
from baselines.evaluation import publish
from baselines.registry import agent_groups, agent_names

ROOT = Path(__file__).resolve().parents[1]
BOARD = ROOT / "docs" / "published" / "leaderboard.json"


@pytest.fixture(scope="module")
def board() -> list[dict]:
    return json.loads(BOARD.read_text())


def test_the_published_board_names_todays_ids_and_existing_agents(board):
    known = set(agent_names()) | set(agent_groups().values())
    for row in board:
        assert row["env_id"] in auv_envs.ENVIRONMENTS, f"{row['env_id']} is not today's id"
        if not leaderboard.is_reference(row):
            assert row["agent"] in known, f"{row['agent']} is not a registered agent"
    assert {r["env_id"] for r in board} == set(auv_envs.ENVIRONMENTS)  # every id on it
    assert {r["env_kwargs"]["difficulty"] for r in board} == set(publish.LEVELS)


def test_the_published_rows_carry_their_ranks(board):
    ranked = [r for r in board if r["rank"] is not None]
    assert ranked and all(isinstance(r["tied"], bool) for r in board)
    recomputed = publish.headline_table(board)  # from the rows, ranks computed afresh
    assert recomputed.count("(rank 1)") >= len(auv_envs.ENVIRONMENTS)


def test_the_page_says_what_was_run_where_and_when(board):
    page = (ROOT / "docs" / "leaderboard.md").read_text()
    header = page.split("\n## ", 1)[0]
    assert "python -m baselines.evaluation.publish" in header
    assert re.search(r"commit: `[0-9a-f]{7,}`", header)
    assert re.search(r"date: 20\d\d-\d\d-\d\d", header)
    assert re.search(r"wall time: [0-9.]+ min", header)
    for env_id in auv_envs.ENVIRONMENTS:
        assert env_id in header
    seeds = sorted({s for r in board for s in r["seeds"]})
    assert f"seeds {seeds[0]}–{seeds[-1]}" in header


def test_the_readme_headline_table_is_the_published_boards(board):
    readme = (ROOT / "README.md").read_text()
    assert publish.readme_table(readme) == publish.headline_table(board)


def test_writing_needs_an_evaluation_first(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        publish.main(["--write-only", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "run without --write-only first" in capsys.readouterr().err


def test_the_readme_markers_are_needed():
    with pytest.raises(ValueError, match="markers"):
        publish.readme_with("| table |", "# a README without them\n")


def test_the_readme_lists_every_agent_group_and_nothing_else():
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Agents", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    listed = {name for row in rows for name in re.findall(r"`([^`]+)`", row.split("|")[1])}
    # The catalogue's and the shipped policies' agents (this process's registry may hold
    # agents that other tests registered).
    from baselines.catalogue import builtin_specs

    expected = {spec.group or spec.name for spec in builtin_specs()}
    assert listed == expected, (f"missing from the README: {sorted(expected - listed)}; "
                                f"not agents: {sorted(listed - expected)}")


def test_the_readme_stays_short():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 200


def _readme_python_blocks() -> list[str]:
    readme = (ROOT / "README.md").read_text()
    return re.findall(r"```python\n(.*?)```", readme, re.S)


def test_the_readme_environment_snippet_runs_quietly_twice():
    """The README's first snippet, run as a user would, twice: it works and prints no error
    or warning line either time."""
    import subprocess
    import sys

    snippet = _readme_python_blocks()[0]
    assert "gym.make(" in snippet
    for _ in range(2):
        result = subprocess.run([sys.executable, "-c", snippet], capture_output=True,
                                text=True, cwd=ROOT, timeout=300)
        assert result.returncode == 0, result.stderr
        assert not result.stderr.strip(), result.stderr
