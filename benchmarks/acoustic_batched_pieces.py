"""Where a batched acoustic step goes: the rig's kinematics, a rig period, a whole step.

Times, at one batch size, each piece as one compiled ``vmap`` call (best of
``--repeats`` after compiling):

* MJX's ``smooth.kinematics`` of the rig against
  :class:`~auv_envs.tasks.acoustic.mjx_plant.ChainKinematics` (the same fields);
* one sample period of the rig (:meth:`RigPlantMJX.period`: two MJX steps with the
  ellipsoid fluid force);
* one step of the batched acoustic env
  (:class:`~auv_envs.batched.functional.FunctionalEnv`) in ``state`` and in
  ``measurements`` mode (the estimate held at the tank's centre);
* the random draws of one ``measurements`` step alone: every draw the step makes (read
  off a trace of it), made from JAX keys at the same shapes, and the count of numbers
  (on the CPU JAX's generator, not the arithmetic, bounds the batched step's speed);
* the detection fixes of a ``measurements`` observation per environment
  (:func:`baselines.rl.detection_fixes.observe`, what ``cppo-acoustic-measurements``'
  front end adds), and the ``measurements`` step through
  :class:`~baselines.rl.detection_fixes.DetectionFixesMJX`.

    python benchmarks/acoustic_batched_pieces.py [--batch 64] [--difficulty hard]
        [--skip-mjx-kinematics]
"""

from __future__ import annotations

import argparse
import math
import time

import gymnasium as gym
import jax
import jax.numpy as jnp
from mujoco.mjx._src import smooth

import auv_envs  # noqa: F401
from auv_envs.batched import functional
from auv_envs.batched.functional import FunctionalEnv, KeyDraws
from auv_envs.core.difficulty import LEVELS
from auv_envs.tasks.acoustic.mjx_plant import RigPlantMJX
from auv_envs.tasks.acoustic.transition import NOMINAL_POSTURE
from baselines.rl.detection_fixes import DetectionFixesMJX, observe


def best_ms(fn, args, repeats: int) -> float:
    """Milliseconds of the compiled ``fn(*args)``, best of ``repeats`` after one call."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - start)
    return best * 1e3


class _RecordedDraws(KeyDraws):
    """:class:`KeyDraws` that notes the kind and shape of every uniform and normal draw
    (``normal`` goes through ``standard_normal``; ``integers`` and ``permutation``, which
    only a reset's plan draws, are not noted)."""

    noted: list = []

    def random(self, size=None):
        self.noted.append(("uniform", self._shape(size)))
        return super().random(size)

    def standard_normal(self, size=None):
        self.noted.append(("normal", self._shape(size)))
        return super().standard_normal(size)

    def uniform(self, low=0.0, high=1.0, size=None):
        self.noted.append(("uniform", self._shape(size)))
        return super().uniform(low, high, size)


def step_draws(env: FunctionalEnv, states) -> list[tuple[str, tuple]]:
    """The (kind, shape) of every draw one environment's step makes (a trace of
    ``env._step``, no episode ending)."""
    one = jax.tree_util.tree_map(lambda leaf: leaf[0], states)
    _RecordedDraws.noted = []
    functional.KeyDraws = _RecordedDraws
    try:
        jax.eval_shape(env._step, one, jnp.zeros(3, jnp.float32))
    finally:
        functional.KeyDraws = KeyDraws
    return list(_RecordedDraws.noted)


def make_draws(draws, key):
    """The draws ``draws`` made from ``key`` by :class:`KeyDraws`, as the step makes them;
    returns their sum, so none is left out of the compiled call."""
    source = KeyDraws(key)
    total = jnp.float32(0.0)
    for kind, shape in draws:
        sample = source.standard_normal if kind == "normal" else source.random
        total = total + jnp.sum(sample(shape))
    return total


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--difficulty", default="hard", choices=LEVELS)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-mjx-kinematics", action="store_true",
                        help="leave out MJX's own kinematics (seconds a call to compile and run)")
    args = parser.parse_args(argv)
    batch = args.batch
    print(f"JAX backend: {jax.default_backend()}; batch {batch}, {args.difficulty}")
    cpu = gym.make("auv_envs/AcousticTracking-v2", obs_mode="state").unwrapped
    plant = RigPlantMJX(cpu.physics)
    tile = lambda values: jnp.tile(jnp.asarray(values, jnp.float32), (batch, 1))  # noqa: E731
    carrier, arm = tile([150.0, 150.0, -12.0, 0.3]), tile(NOMINAL_POSTURE)
    data = jax.jit(jax.vmap(lambda c, a: plant.place(c, a, plant.model)))(carrier, arm)
    rows = []
    if not args.skip_mjx_kinematics:
        kinematics = jax.jit(jax.vmap(lambda d: smooth.kinematics(plant.model, d)))
        rows.append(("MJX smooth.kinematics", best_ms(kinematics, (data,), args.repeats)))
    rows.append(("ChainKinematics", best_ms(jax.jit(jax.vmap(plant.kinematics)), (data,),
                                            args.repeats)))
    period = jax.jit(jax.vmap(lambda *args: plant.period(*args, plant.model)))
    references = (carrier, tile([0.2, 0.0, 0.0, 0.0]), arm, tile([0.2, 0.1, 0.0]))
    rows.append(("rig period (two MJX steps, fluid)",
                 best_ms(lambda d: period(d, *references)[1], (data,), args.repeats)))
    estimate = tile([150.0, 150.0, -15.0])
    for mode in ("state", "measurements"):
        env = FunctionalEnv("auv_envs/AcousticTracking-v2", obs_mode=mode,
                            difficulty=args.difficulty)
        states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch))
        step = jax.jit(env.step_batch)
        states = step(states, estimate)  # a stepped state: the types every later step has
        rows.append((f"env step, {mode}", best_ms(lambda s, step=step: step(s, estimate).obs,
                                                  (states,), args.repeats)))
    draws = step_draws(env, states)  # env: the measurements one
    numbers = sum(math.prod(shape) for _, shape in draws)
    rows.append((f"its random draws alone ({numbers:,} numbers an env)", best_ms(
        jax.jit(jax.vmap(lambda key: make_draws(draws, key))),
        (jax.random.split(jax.random.key(1), batch),), args.repeats)))
    fixes = DetectionFixesMJX(env)
    held = jax.vmap(lambda _: fixes.start())(jnp.arange(batch))
    observe_all = jax.jit(jax.vmap(lambda h, o: observe(fixes.params, h, o, jnp)))
    rows.append(("detection fixes of the observation", best_ms(
        lambda h, o: observe_all(h, o)[1]["fix"], (held, states.obs), args.repeats)))
    fixed = jax.jit(jax.vmap(fixes.reset))(jax.random.split(jax.random.key(0), batch))
    step = jax.jit(fixes.step_batch)
    fixed = step(fixed, estimate)
    rows.append(("env step, measurements with the detection fixes", best_ms(
        lambda s: step(s, estimate).obs["fix"], (fixed,), args.repeats)))
    print("\n| piece | ms a call | env-steps/s |")
    print("|---|---|---|")
    for name, ms in rows:
        print(f"| {name} | {ms:.2f} | {batch / ms * 1e3:,.0f} |")


if __name__ == "__main__":
    main()
