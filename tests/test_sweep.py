"""Training sweeps on Ray (``train.py --sweep-dir``, :mod:`baselines.rl.sweep`), on a
local cluster of two nodes (:class:`~baselines.evaluation.backends.LocalRayCluster`):
every seed x variant a run directory like a single run's, a failing run reported while
the others finish, a summary table, and the same command continuing an unfinished
sweep."""

from __future__ import annotations

import contextlib
import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

import train as train_cli  # noqa: E402
from baselines.evaluation import LocalRayCluster  # noqa: E402
from baselines.rl import sweep  # noqa: E402
from baselines.rl.config import ConfigError  # noqa: E402

#: A tiny PPO run: 64 steps, one held-out episode at 32 and 64.
TINY = ["--algo", "ppo", "--env", "DockingStation-v2", "--n-timesteps", "64",
        "--set", "n_envs=1", "--set", "n_steps=32", "--set", "batch_size=16",
        "--set", "n_eval_episodes=1", "--set", "eval_freq=32"]
#: One variant that trains and one whose env cannot be built (a negative time limit is
#: refused when the run builds its env, after the sweep has started).
GRID = ["--grid", "env_kwargs.time_limit=5.0,-1.0"]
GOOD, BAD = "s1-env_kwargs_time_limit=5.0", "s1-env_kwargs_time_limit=-1.0"


@pytest.fixture(scope="module")
def cluster(one_ray_cluster_at_a_time):
    with LocalRayCluster(nodes=2) as running:
        yield running


ROOT = Path(__file__).resolve().parents[1]


def train_py(*args: str) -> tuple[int, str]:
    """``python train.py ARGS`` as a user runs it, in a process of its own (a sweep's
    driver connects to Ray once a process); its exit code and standard output."""
    run = subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=ROOT,
                         capture_output=True, text=True, timeout=900)
    return run.returncode, run.stdout


def summary(sweep_dir) -> dict[str, dict]:
    with open(sweep_dir / "summary.csv", newline="") as handle:
        return {row["run"]: row for row in csv.DictReader(handle)}


def test_a_sweep_trains_every_run_reports_the_failing_one_and_resumes(tmp_path, cluster):
    out = tmp_path / "sweep"
    on_cluster = ["--ray-address", cluster.address]
    code, printed = train_py(*TINY, *GRID, *on_cluster, "--sweep-dir", str(out),
                             "--seeds", "1", "2")
    assert code == 1  # not every run finished
    rows = summary(out)
    assert len(rows) == 4
    for seed in (1, 2):
        good = rows[GOOD.replace("s1", f"s{seed}")]
        assert (good["status"], good["exit_code"]) == ("finished", "0"), \
            (out / good["log"]).read_text()[-4000:]
        assert good["steps"] == "64" and good["seed"] == str(seed)
        run_dir = out / good["run"]
        # The files of a single train.py run, its config with the seed and the variant.
        for name in ("config.yml", "run.json", "eval_curve.csv", "final/model.zip"):
            assert (run_dir / name).exists(), name
        info = json.loads((run_dir / "run.json").read_text())
        assert info["status"] == "finished" and info["seed"] == seed
        assert "--run-dir " + good["run"] in info["command"]
        assert "time_limit: 5.0" in (run_dir / "config.yml").read_text()
        bad = rows[BAD.replace("s1", f"s{seed}")]
        assert bad["status"] == "failed" and bad["exit_code"] == "2"
        assert "time_limit must be a positive number" in (out / bad["log"]).read_text()
    assert "| " + GOOD + " | 1 | env_kwargs.time_limit=5.0 | finished | 0 | 64 |" in printed
    assert "not finished: " in printed and BAD in printed

    # The same command again: the finished runs are kept as they are; an unfinished run
    # with a checkpoint is continued; one without is set aside and started again.
    kept = (out / GOOD / "run.json").read_text()
    unfinished = out / GOOD.replace("s1", "s2")
    # Stopped at its first checkpoint (as Ctrl-C leaves a run): step 0 of 64.
    shutil.rmtree(unfinished / "checkpoints" / "step-0000000064")
    (unfinished / "checkpoints" / "latest").write_text(
        json.dumps({"checkpoint": "step-0000000000"}))
    info = json.loads((unfinished / "run.json").read_text())
    (unfinished / "run.json").write_text(json.dumps({**info, "status": "interrupted",
                                                     "steps": 0}))
    (out / BAD).mkdir()
    (out / BAD / "run.json").write_text(json.dumps({"status": "running"}))
    code, printed = train_py(*TINY, *GRID, *on_cluster, "--sweep-dir", str(out),
                             "--seeds", "1", "2")
    assert code == 1
    assert f"{GOOD}: finished before, kept" in printed
    assert f"{unfinished.name}: continuing from its checkpoint" in printed
    assert (out / GOOD / "run.json").read_text() == kept
    resumed = json.loads((unfinished / "run.json").read_text())
    assert resumed["status"] == "finished" and len(resumed["segments"]) == 2
    assert (out / f"{BAD}.attempt-1" / "run.json").exists()  # nothing lost
    assert summary(out)[unfinished.name]["status"] == "finished"


def test_a_bad_sweep_is_refused_before_anything_runs(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert train_cli.main([*TINY, "--sweep-dir", str(out), "--seeds", "1",
                           "--grid", "learning_rate=-1.0"]) == 2
    assert "learning_rate" in capsys.readouterr().err and not out.exists()
    with pytest.raises(SystemExit):
        train_cli.main([*TINY, "--sweep-dir", str(out), "--seeds", "1", "--seed", "2"])
    with pytest.raises(SystemExit):
        train_cli.main([*TINY, "--seeds", "1", "2"])  # no --sweep-dir
    with pytest.raises(ConfigError, match="repeats a seed"):
        sweep.plan([1, 1], {}, [])
    with pytest.raises(ConfigError, match="key=value1,value2"):
        sweep.parse_grid(["learning_rate"])
    runs = sweep.plan([0, 1], sweep.parse_grid(["gamma=0.9,0.99", "n_steps=32,64"]), ["-x"])
    assert len(runs) == 8 and len({run.name for run in runs}) == 8
    assert runs[0].argv == ("-x", "--seed", "0", "--set", "gamma=0.9", "--set", "n_steps=32")


class _LosingRay:
    """Ray's task calls as the sweep makes them, run in this process, the first result of
    each run lost as Ray loses one (its owner gone): to check that such a run runs again."""

    exceptions = ray.exceptions

    def __init__(self, losses: int):
        self.losses, self.calls = losses, []

    def remote(self, **options):
        def wrap(function):
            outer = self

            class Remote:
                @staticmethod
                def remote(*args):
                    outer.calls.append(args[0])
                    return (len(outer.calls), function, args)
            return Remote
        return wrap

    def wait(self, refs, num_returns):
        return refs[:num_returns], refs[num_returns:]

    def get(self, ref):
        number, function, args = ref
        if self.calls[:number].count(args[0]) <= self.losses:
            raise self.exceptions.OwnerDiedError("ab" * 14, "", "")
        return {"exit_code": 0, "log": f"ran {args[0]}\n", "archive": None}


@pytest.mark.parametrize("losses, expected", [(1, 2), (sweep.LOST_RUN_RETRIES + 1, 3)])
def test_a_run_whose_result_ray_loses_runs_again(tmp_path, monkeypatch, losses, expected):
    fake = _LosingRay(losses)
    monkeypatch.setattr("baselines.evaluation.backends.ray_session",
                        lambda *args, **kwargs: contextlib.nullcontext(fake))
    told = []
    runs = sweep.plan([3], {}, ["--algo", "ppo"])
    rows = sweep.sweep(runs, tmp_path, "ppo", echo=told.append)
    name = runs[0].name
    assert fake.calls == [name] * expected
    assert sum("Ray lost it (OwnerDiedError); running it again" in line
               for line in told) == expected - 1
    log = (tmp_path / "logs" / f"{name}.log").read_text()
    if losses <= sweep.LOST_RUN_RETRIES:  # the last try delivered
        assert rows[0]["exit_code"] == 0 and log == f"ran {name}\n"
    else:  # every try lost: reported, not silently missing
        assert rows[0]["exit_code"] == 1 and "Ray could not run it" in log
