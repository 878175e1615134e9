"""The Ray backend on a real cluster of two nodes on this machine.

Ray allows several nodes on one machine when each gets its own temporary
directory: :class:`~baselines.evaluation.backends.LocalRayCluster` starts them
with ``ray start`` (a head, and a node that joins it), each with its own raylet,
object store and unpacked runtime environment, and kills them by process group
afterwards, even when the test fails. One evaluation runs on it with clips
recorded while one worker is killed in the middle of an episode; it must give
the local backend's board cell for cell, every clip on the driver's disk, and
the retry counted. This module is also the cluster's agent module: imported by
a worker of the cluster, it registers ``test-dies-once``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from baselines import leaderboard, registry
from baselines.agents.random_agent import RandomAgent
from baselines.evaluation import (
    EpisodeRow,
    LocalRayCluster,
    VideoSpec,
    evaluate_all,
    row_to_dict,
    summarise,
)
from baselines.registry import AgentSpec, register_agent

pytest.importorskip("ray", reason="the Ray backend needs ray (the test extra)")
pytest.importorskip("moviepy", reason="recording clips needs moviepy (the video extra)")

ROOT = Path(__file__).resolve().parents[1]
DOCK = "auv_envs/DockingStation-v2"
LARS = "auv_envs/LARSCapture-v0"
#: Set in the cluster's processes only: the file whose absence makes ``test-dies-once``
#: kill its worker; it creates the file first, so one worker dies, once.
KILL_MARKER = "AUV_TEST_KILL_MARKER"
#: The step of its episode on which the worker is killed.
KILL_AT_STEP = 5


def _claim(path: str) -> bool:
    """Create ``path``; whether this call created it (not another process before)."""
    try:
        with open(path, "x"):
            return True
    except FileExistsError:
        return False


class DiesOnceAgent(RandomAgent):
    """Random actions. In a process given :data:`KILL_MARKER`, the first episode anywhere
    to reach step :data:`KILL_AT_STEP` SIGKILLs its own process: no exception, no
    cleanup, as when the OOM killer or a lost machine takes a worker."""

    def __init__(self, env):
        super().__init__(env)
        self._steps = 0

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._steps = 0

    def act(self, observation, info: dict):
        self._steps += 1
        marker = os.environ.get(KILL_MARKER)
        if marker and self._steps == KILL_AT_STEP and _claim(marker):
            os.kill(os.getpid(), signal.SIGKILL)
        return super().act(observation, info)


DIES_ONCE = AgentSpec("test-dies-once", DiesOnceAgent, "state", None,
                      "random actions; kills its Ray worker once (cluster test)")
if os.environ.get(KILL_MARKER):  # a worker of the test's cluster
    register_agent(DIES_ONCE)


def _comparable(row: EpisodeRow) -> dict:
    """A row as JSON data without its wall time, which differs between runs."""
    return {k: v for k, v in row_to_dict(row).items() if k != "wall_time_s"}


def _board(rows: list[EpisodeRow]) -> str:
    return leaderboard.markdown(summarise(rows))


@pytest.fixture
def cluster(tmp_path, one_ray_cluster_at_a_time):
    """Two nodes of one CPU each; their processes know :data:`KILL_MARKER`."""
    with LocalRayCluster(nodes=2, cpus=1,
                         env={KILL_MARKER: str(tmp_path / "killed")}) as nodes:
        yield nodes


def test_a_two_node_cluster_gives_the_local_board_and_clips_despite_a_killed_worker(
        cluster, tmp_path, monkeypatch):
    # In this process the agent never kills (no KILL_MARKER): registered for this test only.
    monkeypatch.setitem(registry._REGISTRY, DIES_ONCE.name, DIES_ONCE)
    args = dict(env_ids=[DOCK, LARS], agents=["random", "pd-state", DIES_ONCE.name],
                seeds=[100000, 100001], env_kwargs=[{DOCK: {"time_limit": 5.0}}],
                agent_modules=("tests.test_ray_cluster",))
    local = evaluate_all(**args)
    # A relative clip directory, as evaluate.py's default: a worker that wrote its clips
    # where it was told would write them under its own working directory.
    monkeypatch.chdir(tmp_path)
    clips = tmp_path / "clips"
    video = VideoSpec("clips", size=(64, 48))
    ray_args = dict(args, backend="ray", ray_address=cluster.address,
                    cache_dir=tmp_path / "cache", video=video)
    remote = evaluate_all(**ray_args)

    # The board, cell for cell, and every row.
    assert remote.stats.ran == len(local.rows) == 10 and remote.stats.failed == 0
    assert [_comparable(r) for r in remote.rows] == [_comparable(r) for r in local.rows]
    assert _board(remote.rows) == _board(local.rows)

    # One worker was killed in an episode; Ray ran that episode again, and said so.
    assert (tmp_path / "killed").exists()
    assert remote.stats.retried == 1

    # Every clip (MP4 and its GIF) is on the driver's disk, whichever node recorded it.
    pairs = {(t.env_id, t.agent) for t in remote.tasks}
    assert len(remote.clips) == len(pairs) == 5
    expected = {p.name for mp4 in remote.clips.values() for p in (mp4, mp4.with_suffix(".gif"))}
    assert all(mp4.parent == Path("clips") for mp4 in remote.clips.values())
    assert {p.name for p in clips.iterdir()} == expected  # nothing half-written
    assert all(path.stat().st_size > 0 for path in clips.iterdir())

    # The second node ran episodes in its own unpacked copy of the tree, policies included.
    shipped = [p for p in Path(cluster.temp_dirs[1]).glob(
        "session_2*/runtime_resources/working_dir_files/_ray_pkg_*") if p.is_dir()]
    assert len(shipped) == 1
    assert (shipped[0] / "assets" / "policies").is_dir()
    assert not (shipped[0] / ".git").exists() and not (shipped[0] / ".venv").exists()

    # A second run finds every episode and clip here: nothing runs again.
    again = evaluate_all(**ray_args)
    assert again.stats.cached == 10 and again.stats.ran == 0
    assert [_comparable(r) for r in again.rows] == [_comparable(r) for r in local.rows]


def test_a_ray_running_elsewhere_is_not_taken_for_the_named_cluster(one_ray_cluster_at_a_time):
    # In a process of its own: a process that used Ray keeps its state past ray.shutdown.
    script = """
import ray
from baselines.evaluation.backends import ray_session
ray.init(num_cpus=1, include_dashboard=False)
running = ray.get_runtime_context().gcs_address
try:
    with ray_session("127.0.0.1:1", None, purpose="evaluate.py --backend ray"):
        raise SystemExit("the named cluster was taken for the running Ray")
except ValueError as error:
    assert "127.0.0.1:1" in str(error) and running in str(error), error
host, port = running.rsplit(":", 1)
with ray_session(f"localhost:{port}" if host == "127.0.0.1" else running, None) as same:
    assert same.get(same.put(3)) == 3
assert ray.is_initialized()  # the caller's Ray, left running
with ray_session(None, None) as same:
    assert same.is_initialized()
ray.shutdown()
print("checked")
"""
    run = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, env={**os.environ, "RAY_AUTH_MODE": "disabled"})
    assert run.returncode == 0 and "checked" in run.stdout, run.stderr[-3000:]
