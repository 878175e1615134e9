"""Instructions a step, counted by Valgrind's callgrind: each env against ``HalfCheetah-v5``.

Wall-clock ratios (``benchmarks/throughput.py``'s 0.8x target) swing by 10-20 %
from run to run on a shared 2-core machine. An instruction count does not: it is the
same on every run of the same tree, so it shows whether a change made a step cheaper.
It is not the target: a Python-heavy step runs fewer instructions a cycle than
MuJoCo's C, so at equal counts our envs are slower in wall time than HalfCheetah.

Each (env, mode) runs twice under ``valgrind --tool=callgrind`` (1 step and ``1 +
--steps`` steps of the same seeded uniform actions, the start-up the same in both); the
difference over ``--steps`` is the cost of a step. About 70 s of start-up per run (the
imports, under Valgrind); the two runs of a row go in parallel.

    python benchmarks/instructions.py --envs auv_envs/LARSCapture-v0:features
    python benchmarks/instructions.py --lars-physics   # the arm's model against the scene's

Needs ``valgrind`` on the PATH. Valgrind 3.19 cannot run MuJoCo 3.17's ellipsoid fluid
model (an unhandled AVX instruction in ``mjd_ellipsoidFluid``): the acoustic envs, whose
rig moves in that model, cannot be counted.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

from auv_envs.core.env import TaskEnv

REFERENCE = "HalfCheetah-v5"

#: The child: ``python instructions.py --child ENV MODE STEPS`` steps the env.
_CHILD = "--child"


#: ``--lars-physics``'s rows: a LARS control period (``mj_step`` of 4 physics steps) on
#: the model the env steps (the arm's) and on the whole scene's, which it renders.
LARS_MODELS = {"arm": "model", "scene": "scene_model"}


def _child(env_id: str, mode: str, n_steps: int) -> None:
    import gymnasium as gym
    import numpy as np

    import auv_envs  # noqa: F401  (registers the ids)

    if env_id in LARS_MODELS:
        import mujoco

        from auv_envs.tasks.lars.env import FRAME_SKIP, LARSCaptureTask

        model = getattr(TaskEnv(LARSCaptureTask).physics, LARS_MODELS[env_id])
        data = mujoco.MjData(model)
        data.qpos[:], data.ctrl[:] = (0.1, 0.2, -0.5), (0.1, -0.2, 0.3)
        for _ in range(n_steps):
            mujoco.mj_step(model, data, FRAME_SKIP)
        return

    env = gym.make(env_id) if mode == "-" else gym.make(env_id, obs_mode=mode)
    env.reset(seed=0)
    space = env.action_space
    actions = np.random.default_rng(0).uniform(space.low, space.high,
                                               (n_steps, *space.shape)).astype(space.dtype)
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()


def _instructions(env_id: str, mode: str, n_steps: int, workdir: str) -> list[int]:
    """Instructions of the child run with 1 and 1 + ``n_steps`` steps (in parallel)."""
    runs = []
    for steps in (1, 1 + n_steps):
        out = os.path.join(workdir, f"callgrind.{len(runs)}")
        command = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                   sys.executable, os.path.abspath(__file__), _CHILD, env_id, mode,
                   str(steps)]
        runs.append(subprocess.Popen(command, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONHASHSEED": "0"}))
    counts = []
    for run in runs:
        _, err = run.communicate()
        found = re.search(r"Collected : (\d+)", err)
        if run.returncode != 0 or found is None:
            raise RuntimeError(f"callgrind run of {env_id} failed:\n{err[-2000:]}")
        counts.append(int(found.group(1)))
    return counts


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=[],
                        help="ENV_ID:OBS_MODE entries, e.g. auv_envs/LARSCapture-v0:features")
    parser.add_argument("--lars-physics", action="store_true",
                        help="also a LARS control period on the arm's and the scene's model")
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args(argv)
    if not args.envs and not args.lars_physics:
        parser.error("give --envs, --lars-physics or both")
    if shutil.which("valgrind") is None:
        sys.exit("valgrind is not on the PATH")
    rows = [(REFERENCE, "-")] + [tuple(entry.split(":", 1)) for entry in args.envs]
    if args.lars_physics:
        rows += [(name, "physics") for name in LARS_MODELS]
    per_step = {}
    with tempfile.TemporaryDirectory() as workdir:
        for env_id, mode in rows:
            first, last = _instructions(env_id, mode, args.steps, workdir)
            per_step[env_id, mode] = (last - first) / args.steps
            print(f"{env_id} {mode}: {per_step[env_id, mode]:,.0f} instructions a step",
                  flush=True)
    reference = per_step[REFERENCE, "-"]
    print(f"\n| env | obs_mode | instructions a step | {REFERENCE} | ratio (reference / env) |")
    print("|---|---|---|---|---|")
    for (env_id, mode), count in per_step.items():
        if env_id != REFERENCE:
            print(f"| {env_id} | {mode} | {count:,.0f} | {reference:,.0f} | "
                  f"{reference / count:.2f} |")


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == _CHILD:
        _child(sys.argv[2], sys.argv[3], int(sys.argv[4]))
    else:
        main()
