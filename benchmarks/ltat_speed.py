"""LTAT perception speed: stereo pairs per second at 640x480 ([LTAT]'s real-time bar: 25 FPS).

Renders a severe-sea episode once (wash-overs and analogs; the arm follows
the AUV with the dataset exporter's privileged tracking action), then times
the LTAT front end (both views: Siamese tracker, online detector and its
retraining, corner extraction, stereo check) over the stored frames --
rendering excluded -- and, for reference, the Siamese tracker alone. Best of
``--repeats`` passes, one torch thread.

    python benchmarks/ltat_speed.py [--frames 150] [--repeats 3] [--seed 100012]

Target: LTAT >= 25 stereo pairs/s on this 2-core CPU; the printed
ratio is LTAT's rate over 25.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from auv_envs.core.env import TaskEnv
from auv_envs.datasets.lars import tracking_action
from auv_envs.tasks.lars.env import CONTROL_PERIOD, LARSCaptureTask
from baselines.lars.perception.front_end import LTATFrontEnd
from baselines.lars.perception.siamese import Pyramid, SiameseTracker, marker_box

TARGET_FPS = 25.0


def render_episode(seed: int, frames: int):
    """Stereo observations of a severe-sea episode, the env's calibration, frame-0 truth."""
    env = TaskEnv(LARSCaptureTask, obs_mode="stereo", sea_state="severe", control="position",
                         time_limit=frames * CONTROL_PERIOD + 1.0)
    obs, info = env.reset(seed=seed)
    truth = info["true_pixels"]
    observations = []
    for _ in range(frames):
        observations.append(obs)
        obs, _, terminated, truncated, info = env.step(tracking_action(env, info))
        if terminated or truncated:
            break
    calibration = env.calibration
    env.close()
    return observations, calibration, truth


def time_front_end(front_end: LTATFrontEnd, observations, repeats: int) -> float:
    best = 0.0
    for r in range(repeats):
        front_end.reset(r)
        start = time.perf_counter()
        for obs in observations:
            front_end(obs, {})
        best = max(best, len(observations) / (time.perf_counter() - start))
    return best


def time_siamese(net, observations, truth, repeats: int) -> float:
    boxes = [marker_box(truth[v]) for v in range(2)]
    best = 0.0
    for _ in range(repeats):
        tracker = SiameseTracker(net)
        tracker.init([Pyramid(observations[0][k]) for k in ("left", "right")], boxes)
        start = time.perf_counter()
        for obs in observations:
            tracker.track([Pyramid(obs["left"]), Pyramid(obs["right"])])
        best = max(best, len(observations) / (time.perf_counter() - start))
    return best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=100012)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    observations, calibration, truth = render_episode(args.seed, args.frames)
    front_end = LTATFrontEnd(calibration)
    ltat = time_front_end(front_end, observations, args.repeats)
    stats = front_end.stats()
    siamese = time_siamese(front_end.ltat.net, observations, truth, args.repeats)
    w, h = calibration.stereo.left.width, calibration.stereo.left.height
    print(f"{len(observations)} stereo frames at {w}x{h}, severe sea (seed {args.seed}), "
          f"torch threads {torch.get_num_threads()}")
    print(f"last pass: {stats}")
    print("| pipeline | stereo pairs/s | ms per pair | ratio to 25 FPS |")
    print("|---|---|---|---|")
    for name, fps in (("LTAT front end (both views)", ltat), ("Siamese tracker alone", siamese)):
        print(f"| {name} | {fps:.1f} | {1e3 / fps:.1f} | {fps / TARGET_FPS:.2f} |")
    print(f"target >= {TARGET_FPS:.0f} stereo pairs/s met: {bool(ltat >= TARGET_FPS)}")


if __name__ == "__main__":
    main()
