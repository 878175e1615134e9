"""Ship a finished training run as a named policy under ``assets/policies/<name>/``.

A shipped policy directory holds what :class:`baselines.rl.policy.PolicyAgent`
loads (``model.zip``, ``vecnormalize.pkl`` when training normalised) and what a
reader needs to trust it: the resolved ``config.yml``, the held-out evaluation
curve and the training episodes (CSV), a plot of both (``curve.png``, when the run
recorded either) and
``policy.json`` (command, seed, budget in steps, wall time, package versions,
SHA-256 of every file the agent loads).
"""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

from baselines.rl.config import FRONT_END_WORDS
from baselines.rl.manifest import MANIFEST_FILE, policies_root, read_manifest, verify_files
from baselines.rl.training import RunDirectory

NAME = re.compile(r"^[a-z0-9][a-z0-9._-]*$")


def read_csv(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def plot_curve(run: RunDirectory, out: Path, title: str) -> None:
    """Held-out evaluation return (mean ± std) and success, and the training episodes' return.

    Drawn on a bare Agg ``Figure`` (as :mod:`baselines.leaderboard` does), so
    exporting never switches the caller's pyplot backend.
    """
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    evals = read_csv(run.eval_curve)
    episodes = read_csv(run.train_episodes)
    fig = Figure(figsize=(7, 6))
    FigureCanvasAgg(fig)
    top, bottom = fig.subplots(2, 1, sharex=True)
    if episodes:
        step = np.array([float(r["step"]) for r in episodes])
        ret = np.array([float(r["return"]) for r in episodes])
        top.plot(step, ret, ".", ms=2, alpha=0.3, color="tab:gray", label="training episodes")
        window = max(1, len(ret) // 30)
        smooth = np.convolve(ret, np.ones(window) / window, mode="valid")
        top.plot(step[window - 1:], smooth, color="tab:gray", label=f"mean of {window}")
    if evals:
        step = np.array([float(r["step"]) for r in evals])
        mean = np.array([float(r["mean_return"]) for r in evals])
        std = np.array([float(r["std_return"]) for r in evals])
        top.plot(step, mean, "o-", color="tab:blue", label="held-out evaluation")
        top.fill_between(step, mean - std, mean + std, color="tab:blue", alpha=0.2)
        bottom.plot(step, [float(r["success_rate"]) for r in evals], "o-", color="tab:green")
    top.set_ylabel("episode return")
    if evals or episodes:
        top.legend(loc="best", fontsize=8)
    top.set_title(title)
    bottom.set_ylabel("held-out success rate")
    bottom.set_ylim(-0.05, 1.05)
    bottom.set_xlabel("environment steps")
    fig.tight_layout()
    fig.savefig(out, dpi=80)


def export_policy(run_dir: str | Path, name: str, dest_root: str | Path | None = None,
                  group: str | None = None) -> Path:
    """Copy a finished run's final policy and records to ``dest_root/name``.

    Args:
        run_dir: a finished run directory (with ``final/``).
        name: the agent name, e.g. ``ppo-docking-state`` (lower case, digits, ``.-_``).
        dest_root: where policies live (default: :func:`policies_root`).
        group: the agent this policy is a training seed of (recorded in
            ``policy.json``; the leaderboard pools a group's seeds into one row).

    Returns:
        The policy directory.
    """
    for label, value in (("policy name", name), ("group", group)):
        if value is not None and not NAME.match(value):
            raise ValueError(f"{label} {value!r} must match {NAME.pattern}")
    run = RunDirectory(run_dir)
    manifest = read_manifest(run.final)
    verify_files(run.final, manifest["files"])
    info = json.loads(run.info.read_text())
    if info.get("status") != "finished":
        raise ValueError(f"{run.path} has not finished (status {info.get('status')!r})")
    dest = Path(dest_root or policies_root()) / name
    tmp = dest.with_name(f".{name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for file in manifest["files"]:
        shutil.copy2(run.final / file, tmp / file)
    shutil.copy2(run.config, tmp / "config.yml")
    for source in (run.eval_curve, run.train_episodes):
        if source.is_file():
            shutil.copy2(source, tmp / source.name)
    evals = read_csv(run.eval_curve)
    if evals or read_csv(run.train_episodes):  # nothing to draw after cppo's evals: 0
        plot_curve(run, tmp / "curve.png",
                   f"{name}\n{manifest['env_id']}, {manifest['obs_mode']}")
    policy = {
        **manifest,
        "name": name,
        "command": info["command"],
        "seed": info["seed"],
        "budget_steps": info["n_timesteps"],
        "steps": info["steps"],
        "wall_time_s": info["wall_time_s"],
        "segments": len(info["segments"]),
        "package_version": info["package_version"],
        "versions": {k: info[k] for k in ("stable_baselines3", "torch", "gymnasium", "python",
                                          "jax", "optax") if k in info},
        "final_heldout_eval": (
            {k: float(v) if k != "step" and k != "episodes" else int(v)
             for k, v in evals[-1].items()} if evals else None
        ),
        **({"group": group} if group else {}),
        "description": (
            f"{manifest.get('description') or manifest['algo'].upper()} on "
            f"{manifest['obs_mode']} observations"
            + "".join(f" through {words}" for name, words in FRONT_END_WORDS.items()
                      if manifest.get(name))
            + f", {info['steps']} steps"
        ),
    }
    (tmp / MANIFEST_FILE).write_text(json.dumps(policy, indent=2))
    if dest.exists():
        shutil.rmtree(dest)
    tmp.replace(dest)
    return dest
