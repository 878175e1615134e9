"""What the navigation sensors of each ``difficulty`` level measure (``docs/navigation.md``).

Draws each sensor of the docking ids' ``nav`` presets many times at fixed truths and
prints its error statistics: the USBL fix's RMSE and bearing error at several slant
ranges (static geometry: transceiver 5 m above the seabed at the station's depth, the
transponder at the station), with its Cramer-Rao bound, and the rates of lost, mirror-path
and spurious fixes; the DVL's, AHRS's and depth sensor's noise and faults.

    python scripts/navigation_figures.py [--fixes N] [--seed S]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from auv_envs.core import frames
from auv_envs.core.ops import FLOATS
from auv_envs.tasks.docking.env import EASY_NAVIGATION, HARD_NAVIGATION, PAPER_NAVIGATION

LEVELS = {"easy": EASY_NAVIGATION, "paper": PAPER_NAVIGATION, "hard": HARD_NAVIGATION}
RANGES = (10.0, 50.0, 150.0, 300.0)
SEABED_Z = -2.0


def usbl_row(sensors, slant: float, n: int, rng) -> dict:
    usbl = sensors.usbl
    array = usbl.array(sensors.station_depth, SEABED_Z)
    transponder = np.asarray(sensors.transponder, dtype=float)
    bearing = math.radians(30.0)
    horizontal = math.sqrt(max(slant**2 - 9.0, 0.0))
    transceiver = transponder + np.array([-horizontal * math.cos(bearing),
                                          -horizontal * math.sin(bearing), 3.0])
    rows = np.array(frames.rotation_rows(0.02, -0.03, bearing, FLOATS))
    truth = (transponder - transceiver) @ rows
    c_true = array.draw_sound_speed(rng, np)
    out = [usbl.fix(array, transceiver, rows, transponder, c_true, rng, np) for _ in range(n)]
    vectors = np.array([v for v, _ in out])
    found = np.array([f for _, f in out])
    errors = np.linalg.norm(vectors[found] - truth, axis=1)
    good = errors < 0.1 * slant  # not a mirror-path or spurious fix
    angles = np.arccos(np.clip((vectors[found] @ truth) / (np.linalg.norm(vectors[found], axis=1)
                                                           * np.linalg.norm(truth)), -1, 1))
    return {"range": slant, "found": found.mean(), "rmse": math.sqrt(np.mean(errors[good] ** 2)),
            "median": float(np.median(errors)), "bearing": math.degrees(
                math.sqrt(np.mean(angles[good] ** 2))), "gross": 1 - good.mean()}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fixes", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print("USBL fixes per level and slant range (static geometry; RMSE and bearing of the "
          "fixes within 10 % of the range; gross = mirror-path and spurious fixes):\n")
    print("| level | range m | fixes found | RMSE m | RMSE % of range | bearing RMS deg "
          "| median error m | gross fixes |")
    print("|---|---|---|---|---|---|---|---|")
    for level, sensors in LEVELS.items():
        rng = np.random.default_rng(args.seed)
        for slant in RANGES:
            r = usbl_row(sensors, slant, args.fixes, rng)
            print(f"| {level} | {slant:.0f} | {r['found']:.3f} | {r['rmse']:.3f} "
                  f"| {100 * r['rmse'] / slant:.2f} | {r['bearing']:.2f} | {r['median']:.3f} "
                  f"| {r['gross']:.3f} |")
    print("\nDVL, AHRS, depth (1 m/s forward, 10 m altitude; each level's noise):\n")
    print("| level | DVL noise m/s | DVL lost | roll/pitch deg | heading deg | gyro noise "
          "deg/s (0.1 s) | gyro bias after 100 s deg/h | depth noise m | heading deviation per "
          "episode deg |")
    print("|---|---|---|---|---|---|---|---|---|")
    for level, sensors in LEVELS.items():
        rng = np.random.default_rng(args.seed)
        n = args.fixes
        scale = np.zeros(3)
        dvl = [sensors.dvl.read((1.0, 0.0, 0.0), 10.0, scale, rng, FLOATS) for _ in range(n)]
        readings = np.array([r for r, ok in dvl if ok])
        lost = 1 - len(readings) / n
        ahrs = [sensors.ahrs.read((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), np.zeros(3), 0.1, rng,
                                   FLOATS, 0.0)
                for _ in range(n)]
        attitude = np.array([a for a, _, _ in ahrs])
        rates = np.array([r for _, r, _ in ahrs])
        biases = []
        for _ in range(200):  # 200 gyros over 100 s of 0.1 s steps
            bias = sensors.ahrs.draw_bias(rng, FLOATS)
            for _ in range(1000):
                bias = sensors.ahrs.read((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), bias, 0.1, rng,
                                         FLOATS, 0.0)[2]
            biases.append(bias)
        bias = np.array(biases)
        depth = np.array([sensors.depth.read(20.0, rng, FLOATS) for _ in range(n)])
        deviation = np.array([sensors.ahrs.draw_heading_bias(rng, FLOATS) for _ in range(n)])
        print(f"| {level} | {np.std(readings - [1.0, 0.0, 0.0]):.4f} | {lost:.3f} "
              f"| {math.degrees(attitude[:, :2].std()):.3f} "
              f"| {math.degrees(attitude[:, 2].std()):.3f} | {math.degrees(rates.std()):.4f} "
              f"| {math.degrees(bias.std()) * 3600:.2f} | {depth.std():.4f} "
              f"| {math.degrees(deviation.std()):.2f} |")


if __name__ == "__main__":
    main()
