"""How far a noise-free USBL fix in float32 lies from the float64 one, for the two ways of
solving it: :meth:`USBL.fix` (least squares by ``jnp.linalg.lstsq``, what the batched
tasks run) and :meth:`USBL.solve` (scalar arithmetic, a modified Gram-Schmidt QR: what
``sensors="compiled"`` runs on the CPU). The reference is :meth:`USBL.solve` in float64.

Every path detected, none shadowed, no outlier and no timing noise; the vehicle at random
bearings and attitudes, 10 per range. Needs JAX (``pip install -e ".[jax]"``)::

    python scripts/usbl_fix_precision.py
"""

from __future__ import annotations

import argparse
import math

import jax.numpy as jnp
import numpy as np

from auv_envs.core import frames
from auv_envs.core.ops import FLOATS, jax_ops
from auv_envs.tasks.docking.config import PAPER_NAVIGATION
from auv_envs.tasks.docking.navigation import Navigation


class NoiseFree:
    """A fix's draws without chance: its first three uniforms (the paths' detection) 0,
    every other uniform 0.999 (no shadowing, no outlier), every normal 0."""

    def __init__(self, xp):
        self.xp, self.calls = xp, 0

    def random(self, size=None):
        self.calls += 1
        if size == 3 and self.calls == 1:
            return self.xp.zeros(3)
        return self.xp.full((), 0.999) if size is None else self.xp.full(size, 0.999)

    def standard_normal(self, size=None):
        return self.xp.zeros(()) if size is None else self.xp.zeros(size)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ranges", type=float, nargs="+", default=[3, 20, 80, 160, 300, 400])
    parser.add_argument("--poses", type=int, default=10, help="poses per range")
    args = parser.parse_args()
    navigation = Navigation(PAPER_NAVIGATION, -5.0, 0.1)
    usbl, array = PAPER_NAVIGATION.usbl, navigation.array
    transponder = np.asarray(navigation._transponder, dtype=float)
    speed = usbl.acoustics.sound_speed
    rng = np.random.default_rng(0)
    print("| range, m | lstsq (float32) | scalar QR (float32) |")
    print("|---|---|---|")
    for distance in args.ranges:
        worst = [0.0, 0.0]
        for _ in range(args.poses):
            bearing = rng.normal(size=3)
            position = transponder + distance * bearing / np.linalg.norm(bearing)
            euler = np.array([*rng.uniform(-0.3, 0.3, 2), rng.uniform(-math.pi, math.pi)])
            reference, _ = usbl.solve(array, position.tolist(), euler.tolist(),
                                      transponder.tolist(), speed, NoiseFree(np), FLOATS)
            position32 = jnp.asarray(position, jnp.float32)
            euler32 = jnp.asarray(euler, jnp.float32)
            rows = frames.rotation_from_euler(*euler32, ops=jnp)
            by_lstsq, _ = usbl.fix(array, position32, rows, transponder, speed,
                                   NoiseFree(jnp), jnp)
            by_qr, _ = usbl.solve(array, list(position32), list(euler32),
                                  transponder.tolist(), speed, NoiseFree(jnp), jax_ops())
            for k, vector in enumerate((by_lstsq, jnp.stack(by_qr))):
                error = float(np.linalg.norm(np.asarray(vector, float) - np.asarray(reference)))
                worst[k] = max(worst[k], error)
        print(f"| {distance:g} | {worst[0]:.2e} m | {worst[1]:.2e} m |")


if __name__ == "__main__":
    main()
