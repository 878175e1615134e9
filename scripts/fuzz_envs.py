"""Fuzz every environment: random, out-of-range and extreme actions at every level.

    python scripts/fuzz_envs.py [--steps N] [--levels easy paper hard] [--first-seed S]
                                [--batched-steps N] [--no-batched]

For every registered id, every non-rendered obs mode and every level, episodes
are played with actions drawn from a mix (uniform in the box, far outside it,
huge finite values such as 1e300, exact bounds, zeros) until ``--steps`` steps;
every ``observation`` must lie in its space and every reward be finite, and no
step may raise. Each episode is also pickled mid-way and the copy stepped on
beside the original: their next observations must be equal. Bad actions (NaN,
inf, ``None``, complex, wrong shape) must raise ``ValueError`` and leave the
episode steppable. The batched envs (``pip install -e ".[jax]"``) get the same
action mix through ``gym.make_vec``, at the levels each builds.

Prints one line per (id, obs mode, level): steps, episodes, failures; exits 1
when any failed. Seeds default to 930000+ (clear of every seed range in
``baselines/seeds.py``).
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
import traceback

import gymnasium as gym
import numpy as np

import auv_envs

#: Rendered modes are left out (a frame a step; ``tests/test_rendering.py`` covers them).
RENDERED = ("image", "stereo")
BAD_ACTIONS = ("nan", "inf", None, "complex", "shape")


def fuzz_action(rng: np.random.Generator, space: gym.spaces.Box) -> np.ndarray:
    """One action of the mix: in the box, far outside, huge, the bounds, or zero."""
    kind = rng.integers(5)
    shape = space.shape
    if kind == 0:
        return rng.uniform(space.low, space.high)
    if kind == 1:
        return rng.uniform(-50.0, 50.0, shape)
    if kind == 2:
        return rng.choice([-1e300, 1e300, -1e30, 1e30], size=shape)
    if kind == 3:
        return np.where(rng.random(shape) < 0.5, space.low, space.high)
    return np.zeros(shape)


def bad_action(kind, space: gym.spaces.Box):
    shape = space.shape
    return {"nan": np.full(shape, np.nan), "inf": np.full(shape, -np.inf), None: None,
            "complex": np.full(shape, 1j), "shape": np.zeros(shape[0] + 1)}[kind]


def fuzz_env(env_id: str, obs_mode: str, level: str, steps: int, seed: int) -> dict:
    """Play ``steps`` steps of fuzzed episodes; counts and the first failures."""
    rng = np.random.default_rng(seed)
    env = gym.make(env_id, obs_mode=obs_mode, difficulty=level)
    space, act = env.observation_space, env.action_space
    done_steps = episodes = 0
    failures: list[str] = []
    while done_steps < steps and len(failures) < 5:
        episode_seed = int(seed + episodes)
        try:
            obs, _ = env.reset(seed=episode_seed)
            if not space.contains(obs):
                failures.append(f"seed {episode_seed}: reset observation outside its space")
            episodes += 1
            pickle_at = int(rng.integers(1, 50))
            for t in range(steps - done_steps):
                if t == pickle_at:
                    copy = pickle.loads(pickle.dumps(env))
                    action = fuzz_action(rng, act)
                    a, _, terminated, truncated, _ = env.step(action)
                    b = copy.step(action)[0]
                    copy.close()
                    same = (all(np.array_equal(a[k], b[k]) for k in a) if isinstance(a, dict)
                            else np.array_equal(a, b))
                    if not same:
                        failures.append(f"seed {episode_seed}: pickled copy diverged at {t}")
                    kind = BAD_ACTIONS[int(rng.integers(len(BAD_ACTIONS)))]
                    try:
                        env.step(bad_action(kind, act))
                        failures.append(f"seed {episode_seed}: bad action {kind} accepted")
                    except ValueError:
                        pass
                    done_steps += 1
                    if terminated or truncated:
                        break
                    continue
                obs, reward, terminated, truncated, _ = env.step(fuzz_action(rng, act))
                done_steps += 1
                if not space.contains(obs):
                    failures.append(f"seed {episode_seed} step {t}: observation outside "
                                    f"its space")
                if not np.isfinite(reward):
                    failures.append(f"seed {episode_seed} step {t}: reward {reward}")
                if terminated or truncated:
                    break
        except Exception as exc:  # a crash is what the fuzz looks for
            failures.append(f"seed {episode_seed}: {type(exc).__name__}: {exc} "
                            f"({traceback.extract_tb(exc.__traceback__)[-1].name})")
    env.close()
    return {"steps": done_steps, "episodes": episodes, "failures": failures}


def batched_levels(env_id: str) -> tuple[str, ...]:
    """The ``difficulty`` levels a batched id builds (its CPU env's: the batched env takes
    the CPU env's arguments)."""
    return tuple(auv_envs.task_class(auv_envs.family(env_id).env_id).difficulty_presets)


def fuzz_batched(env_id: str, obs_mode: str, level: str, steps: int, seed: int,
                 num_envs: int = 64) -> dict:
    """The action mix through ``gym.make_vec``: ``steps`` batch steps of ``num_envs``."""
    rng = np.random.default_rng(seed)
    envs = gym.make_vec(env_id, num_envs=num_envs, obs_mode=obs_mode, difficulty=level)
    space, act = envs.observation_space, envs.single_action_space
    failures: list[str] = []
    episodes = 0
    obs, _ = envs.reset(seed=seed)
    for t in range(steps):
        actions = np.stack([fuzz_action(rng, act) for _ in range(num_envs)])
        try:
            obs, reward, terminated, truncated, _ = envs.step(actions)
        except Exception as exc:
            failures.append(f"step {t}: {type(exc).__name__}: {exc}")
            break
        episodes += int(np.count_nonzero(terminated | truncated))
        if not space.contains(obs):
            failures.append(f"step {t}: observation outside its space")
        if not np.isfinite(reward).all():
            failures.append(f"step {t}: non-finite reward")
    for kind in BAD_ACTIONS:
        action = bad_action(kind, act)
        batch = None if action is None else np.broadcast_to(action, (num_envs, *action.shape))
        try:
            envs.step(batch)
            failures.append(f"bad action {kind} accepted")
        except ValueError:
            pass
    envs.close()
    return {"steps": steps * num_envs, "episodes": episodes, "failures": failures[:5]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=20_000,
                        help="steps per (id, obs mode, level) (default 20000)")
    parser.add_argument("--levels", nargs="+", default=["easy", "paper", "hard"])
    parser.add_argument("--first-seed", type=int, default=930_000)
    parser.add_argument("--batched-steps", type=int, default=200,
                        help="batch steps (of 64 envs) per batched (id, level) (default 200)")
    parser.add_argument("--no-batched", action="store_true")
    args = parser.parse_args(argv)
    total = {"steps": 0, "episodes": 0, "failures": 0}
    cases = [(env_id, mode, level, False) for env_id in auv_envs.ENVIRONMENTS
             for mode in auv_envs.task_class(env_id).obs_modes if mode not in RENDERED
             for level in args.levels]
    if not args.no_batched:
        cases += [(env_id, "measurements" if "Acoustic" in env_id else "features", level, True)
                  for env_id in auv_envs.BATCHED_ENVIRONMENTS
                  for level in args.levels if level in batched_levels(env_id)]
    for index, (env_id, mode, level, batched) in enumerate(cases):
        start = time.perf_counter()
        seed = args.first_seed + 1000 * index
        result = (fuzz_batched(env_id, mode, level, args.batched_steps, seed) if batched
                  else fuzz_env(env_id, mode, level, args.steps, seed))
        for key in ("steps", "episodes"):
            total[key] += result[key]
        total["failures"] += len(result["failures"])
        print(f"{env_id:34s} {mode:13s} {level:6s} steps {result['steps']:7d}  episodes "
              f"{result['episodes']:5d}  failures {len(result['failures'])}  "
              f"({time.perf_counter() - start:.0f} s)", flush=True)
        for failure in result["failures"]:
            print(f"    {failure}", flush=True)
    print(f"total: {total['steps']} steps, {total['episodes']} episodes, "
          f"{total['failures']} failures")
    return 1 if total["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
