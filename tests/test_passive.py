"""The passive-force dispatcher: one global MuJoCo callback, many models.

Several docking envs in one process (a ``SyncVectorEnv``, threads) must each
get their own hull force, and no other MuJoCo model may see it.
"""

from __future__ import annotations

import threading

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the environments)
from auv_envs.core import passive
from tests.conftest import DOCKING_IDS

STEPS = 40


def _actions(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (STEPS, 4)).astype(np.float32)


def _rollout(env, seed: int, actions) -> np.ndarray:
    _, info = env.reset(seed=seed)
    rows = []
    for action in actions:
        _, _, terminated, truncated, info = env.step(action)
        rows.append(np.concatenate([info["true_position"], info["true_velocity"]]))
        if terminated or truncated:
            break
    return np.array(rows)


def _alone(env_id: str, scenario: str, seed: int) -> np.ndarray:
    env = gym.make(env_id, obs_mode="state", scenario=scenario)
    try:
        return _rollout(env, seed, _actions(seed))
    finally:
        env.close()


def test_interleaved_envs_each_get_their_own_force():
    """Two envs (different layouts and currents) stepped alternately equal each alone."""
    specs = [(DOCKING_IDS[0], "current", 5), (DOCKING_IDS[1], "mismatch", 6)]
    expected = [_alone(*spec) for spec in specs]
    envs = [gym.make(env_id, obs_mode="state", scenario=s) for env_id, s, _ in specs]
    try:
        rows = [[], []]
        for env, (_, _, seed) in zip(envs, specs, strict=True):
            env.reset(seed=seed)
        for k in range(STEPS):
            for i, (env, (_, _, seed)) in enumerate(zip(envs, specs, strict=True)):
                if len(rows[i]) < len(expected[i]):
                    _, _, _, _, info = env.step(_actions(seed)[k])
                    rows[i].append(np.concatenate([info["true_position"],
                                                   info["true_velocity"]]))
    finally:
        for env in envs:
            env.close()
    for got, want in zip(rows, expected, strict=True):
        np.testing.assert_array_equal(np.array(got), want)


def test_sync_vector_env_matches_single_envs():
    seeds = [11, 12, 13]
    vec = gym.vector.SyncVectorEnv(
        [lambda: gym.make(DOCKING_IDS[0], obs_mode="state", scenario="current")] * 3
    )
    try:
        vec.reset(seed=seeds)
        actions = np.stack([_actions(s)[:10] for s in seeds], axis=1)
        for action in actions:
            _, _, _, _, infos = vec.step(action)
        positions = infos["true_position"]
    finally:
        vec.close()
    for i, seed in enumerate(seeds):
        np.testing.assert_array_equal(positions[i], _alone(DOCKING_IDS[0], "current", seed)[9, :3])


def test_envs_stepping_in_threads_match_sequential_runs():
    specs = [(DOCKING_IDS[0], "current", 21), (DOCKING_IDS[1], "current", 22),
             (DOCKING_IDS[0], "mismatch", 23)]
    expected = [_alone(*spec) for spec in specs]
    results: list = [None] * len(specs)

    def work(i, env_id, scenario, seed):
        results[i] = _alone(env_id, scenario, seed)

    threads = [threading.Thread(target=work, args=(i, *spec)) for i, spec in enumerate(specs)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for got, want in zip(results, expected, strict=True):
        np.testing.assert_array_equal(got, want)


def test_models_compile_in_one_thread_while_another_steps():
    """MuJoCo's compiler evaluates passive forces on internal data with no
    Python object: without the shared lock it fails while a docking env steps."""
    stop = threading.Event()
    errors: list = []

    def stepping():
        env = gym.make(DOCKING_IDS[0], obs_mode="state")
        try:
            env.reset(seed=0)
            while not stop.is_set():
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                if terminated or truncated:
                    env.reset()
        except Exception as exc:  # reported below, not lost in the thread
            errors.append(exc)
        finally:
            env.close()

    thread = threading.Thread(target=stepping)
    thread.start()
    try:
        for env_id in (*DOCKING_IDS, "auv_envs/AcousticTracking-v0") * 3:
            gym.make(env_id, obs_mode="state").close()
    finally:
        stop.set()
        thread.join()
    assert not errors, errors


def test_no_callback_left_installed_for_other_models():
    env = gym.make(DOCKING_IDS[0], obs_mode="state")
    try:
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()
    assert mujoco.get_mjcb_passive() is None


def test_a_foreign_passive_callback_is_refused_clearly():
    env = gym.make(DOCKING_IDS[0], obs_mode="state")
    env.reset(seed=0)
    try:
        mujoco.set_mjcb_passive(lambda model, data: None)
        with pytest.raises(RuntimeError, match="another mjcb_passive callback"):
            env.step(env.action_space.sample())
    finally:
        mujoco.set_mjcb_passive(None)
        env.close()


def test_an_exception_in_the_force_unregisters_it():
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody></mujoco>"
    )
    data = mujoco.MjData(model)

    def broken(model, data):
        raise ZeroDivisionError("boom")

    with pytest.raises(Exception):  # noqa: B017  (MuJoCo re-raises as its own error)
        passive.step(model, data, broken)
    assert mujoco.get_mjcb_passive() is None
    # The data can be stepped again with a working force.
    passive.step(model, data, lambda m, d: None)
