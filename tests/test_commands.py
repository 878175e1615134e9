"""The installed commands (console scripts) and the checkout's scripts run the same code."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path
from urllib.parse import quote

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {
    "auv-evaluate": "baselines.commands.evaluate:console",
    "auv-train": "baselines.commands.train:console",
    "auv-record": "auv_envs.record:main",
}


def test_console_scripts_are_declared():
    declared = {point.name: point.value for point in entry_points(group="console_scripts")}
    for name, target in COMMANDS.items():
        assert declared.get(name) == target


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_installed_command_runs(name):
    script = Path(sys.executable).parent / name
    assert script.exists(), f"{name} is not installed next to {sys.executable}"
    result = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=120,
                            cwd="/")  # outside the checkout: the installed package answers
    assert result.returncode == 0, result.stderr
    assert f"usage: {name}" in result.stdout


def test_installed_evaluate_lists_environments_and_agents():
    result = subprocess.run([str(Path(sys.executable).parent / "auv-evaluate"), "--list"],
                            capture_output=True, text=True, timeout=120, cwd="/")
    assert result.returncode == 0, result.stderr
    assert "auv_envs/DockingStation-v2" in result.stdout and "ofnmpc-ekf" in result.stdout


@pytest.mark.parametrize("script, usage", [("evaluate.py", "python evaluate.py"),
                                           ("train.py", "python train.py")])
def test_checkout_scripts_still_run(script, usage):
    result = subprocess.run([sys.executable, str(ROOT / script), "--help"], capture_output=True,
                            text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert f"usage: {usage}" in result.stdout


def test_evaluate_without_moviepy_runs_without_clips(tmp_path, monkeypatch, capsys):
    import evaluate

    monkeypatch.setitem(sys.modules, "moviepy", None)  # import moviepy now raises ImportError
    code = evaluate.main(["--envs", "LARSCapture-v0", "--agents", "random", "--seeds", "1",
                          "--workers", "1", "--no-progress", "--out", str(tmp_path)])
    assert code == 0
    assert "recording needs the video extra" in capsys.readouterr().err
    assert (tmp_path / "leaderboard.html").exists() and not (tmp_path / "videos").exists()
    assert "<video" not in (tmp_path / "leaderboard.html").read_text()


def test_evaluate_record_video_writes_mp4_and_gif_where_asked(tmp_path):
    import evaluate

    out, clips = tmp_path / "out", tmp_path / "clips"
    code = evaluate.main(["--envs", "LARSCapture-v0", "--agents", "ckf-pd", "--seeds",
                          "100001-100002", "--workers", "1", "--no-progress", "--out", str(out),
                          "--record-video", str(clips), "--video-size", "64x48",
                          "--difficulty", "easy"])
    assert code == 0
    stem = "LARSCapture-v0_ckf-pd_features_difficulty=easy_seed100001-episode-0"
    assert sorted(p.name for p in clips.iterdir()) == [f"{stem}.gif", f"{stem}.mp4"]
    assert f'src="../clips/{quote(stem)}.mp4"' in (out / "leaderboard.html").read_text()


def test_plot_seeds_aggregates_runs_with_bootstrap_intervals(tmp_path):
    from scripts import plot_seeds

    runs = []
    for k, successes in enumerate(((0.0, 0.5, 1.0), (0.0, 0.7, 1.0), (0.2, 0.6, 1.0))):
        run = tmp_path / f"run{k}"
        run.mkdir()
        lines = ["step,mean_return,std_return,success_rate,mean_length,episodes"]
        lines += [f"{step},{10 * s},0,{s},100,5" for step, s in zip((0, 100, 200), successes,
                                                                    strict=True)]
        (run / "eval_curve.csv").write_text("\n".join(lines) + "\n")
        runs.append(run)
    rows = plot_seeds.aggregate([plot_seeds.read_curve(r) for r in runs])
    assert [r["step"] for r in rows] == [0, 100, 200]
    assert rows[1]["success_rate"] == pytest.approx(0.6)
    assert rows[1]["success_rate_low"] <= 0.6 <= rows[1]["success_rate_high"]
    assert rows[2]["success_rate_low"] == rows[2]["success_rate_high"] == 1.0
    out = tmp_path / "curves.png"
    assert plot_seeds.main([*map(str, runs), "--out", str(out), "--csv",
                            str(tmp_path / "c.csv")]) == 0
    assert out.stat().st_size > 1000 and len((tmp_path / "c.csv").read_text().splitlines()) == 4
    with pytest.raises(SystemExit):
        plot_seeds.main([str(tmp_path), "--out", str(out)])  # no eval_curve.csv


def test_default_run_leaves_out_heavy_agents_and_says_so(tmp_path, capsys):
    """The default run covers paper and hard without the heavy image agents; it names
    them, and --all-agents (or naming them) brings them back."""
    from baselines.commands.evaluate import DEFAULT_LEVELS, build_parser, default_agents
    from baselines.registry import agent_names, agent_spec

    assert DEFAULT_LEVELS == ("paper", "hard")
    assert build_parser().parse_args([]).difficulty is None  # scenario_groups adds the levels
    heavy_everywhere = sorted(n for n in agent_names() if agent_spec(n).heavy)
    assert {"ofnmpc-ekf-image", "ofnmpc-mhe-image"} <= set(heavy_everywhere)
    agents, heavy = default_agents(["auv_envs/DockingStation-v2"])
    assert heavy == heavy_everywhere and not set(agents) & set(heavy)
    assert set(agents) | set(heavy) == set(agent_names())
    assert default_agents(["auv_envs/LARSCapture-v0"])[1] == []
    import evaluate

    code = evaluate.main(["--envs", "DockingStation-v2", "--seeds", "100000",
                          "--env-kwargs", "time_limit=0.5", "--difficulty", "easy",
                          "--workers", "1", "--no-progress", "--no-video",
                          "--out", str(tmp_path)])
    assert code == 0
    assert "left out of this run (--all-agents adds them): " \
        + ", ".join(heavy_everywhere) in capsys.readouterr().err
    ran = {r["agent"] for r in json.loads((tmp_path / "leaderboard.json").read_text())}
    assert ran and not ran & set(heavy_everywhere)


def test_reproduction_scripts_write_their_figures_as_json(tmp_path, capsys):
    import numpy as np

    from baselines.evaluation import write_figures

    path = tmp_path / "sub" / "figures.json"
    write_figures(path, {"rate": np.float64(0.75), "ci95": [0.5, np.float32(0.9)], "n": 20})
    assert json.loads(path.read_text()) == {"rate": 0.75, "ci95": [0.5, 0.8999999761581421],
                                            "n": 20}
    assert f"figures written to {path}" in capsys.readouterr().out


def test_image_sizes_parse_and_bad_ones_are_refused():
    import argparse

    from auv_envs.record import parse_image_size, parse_size

    assert parse_image_size("84x63") == (84, 63)
    assert parse_image_size("320X240") == (320, 240)
    assert parse_size("320x240") == (320, 240)
    for text in ("84", "84x", "axb", "0x10", "-4x4"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_image_size(text)
    for text in ("84x63", "8x8"):  # odd or under 16: no H.264 clip at that size
        with pytest.raises(argparse.ArgumentTypeError):
            parse_size(text)
