"""The README's batched snippet, timed from a fresh process: cold, then warm cache.

Runs the snippet (``gym.make_vec`` of ``auv_envs/DockingStationMJX-v2``, reset,
one step) twice, each in a new Python process with the same empty
``XDG_CACHE_HOME``: the first compiles and fills ``auv_envs/jax`` there, the
second loads the compiled programs. Prints the seconds from ``import`` to the
first step's observation for both and their ratio (same machine, same run).

    python benchmarks/vector_startup.py [--num-envs 1024] [--level paper]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

SNIPPET = """
import time
start = time.perf_counter()
import gymnasium as gym
import numpy as np
import auv_envs  # registers the ids
envs = gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs={n}, obs_mode="features",
                    difficulty="{level}")
obs, info = envs.reset(seed=0)
obs, reward, terminated, truncated, info = envs.step(np.zeros(({n}, 4)))
print("SECONDS", time.perf_counter() - start)
"""


def run(code: str, cache: str) -> tuple[float, str]:
    env = {**os.environ, "XDG_CACHE_HOME": cache}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout
    seconds = float(next(line for line in out.splitlines() if line.startswith("SECONDS"))
                    .split()[1])
    return seconds, out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--level", default="paper")
    args = parser.parse_args(argv)
    code = SNIPPET.format(n=args.num_envs, level=args.level)
    with tempfile.TemporaryDirectory() as cache:
        cold, printed = run(code, cache)
        warm, _ = run(code, cache)
        files = sum(1 for p in Path(cache, "auv_envs", "jax").rglob("*") if p.is_file())
    stray = [line for line in printed.splitlines() if not line.startswith("SECONDS")]
    print(f"num_envs {args.num_envs}, level {args.level}: cold {cold:.1f} s, warm {warm:.1f} s "
          f"(warm/cold {warm / cold:.2f}); {files} cached programs; other output: "
          f"{stray or 'none'}")


if __name__ == "__main__":
    main()
