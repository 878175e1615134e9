"""The batched JAX docking environment against the MuJoCo CPU environment.

The same start state and action sequence must give positions within 1 cm and
light pixels within 1 px over 20 s (float32 against float64), and a fixed
policy's success or failure must agree on at least 95 of 100 seeds. The
Gymnasium face (``gym.make_vec``) must speak NumPy, reset finished episodes
on the step that ends them and refuse bad input.
"""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import auv_envs  # noqa: E402,F401
from auv_envs.batched.functional import FunctionalEnv  # noqa: E402
from auv_envs.core.ops import FLOATS  # noqa: E402
from auv_envs.core.vehicle import PlantPerturbation  # noqa: E402
from auv_envs.tasks.docking.env import DockingDisturbances  # noqa: E402
from auv_envs.tasks.docking.rules import failure_reason  # noqa: E402
from scripts.batched_equivalence import (  # noqa: E402
    LAYOUTS,
    line_of_sight_policy,
    outcome_agreement,
    trajectory_errors,
)


@pytest.mark.parametrize("env_id", LAYOUTS)
def test_same_start_and_actions_stay_within_1cm_and_1px_over_20s(env_id):
    errors = trajectory_errors(env_id, (3, 11, 29), steps=200)
    assert errors["steps"] == 200 and errors["ended_early"] == 0  # 20 s of approach
    assert errors["worst_position_m"] < 0.01
    assert errors["worst_pixel_px"] < 1.0
    assert errors["visibility_mismatch_steps"] == 0
    assert errors["pixels_compared"] > 200  # the lights were in view for most of it


def test_a_fixed_policy_docks_or_fails_alike_on_95_of_100_seeds():
    outcomes = outcome_agreement("auv_envs/DockingStation-v2", range(700, 800))
    # A sharp test: the policy neither always docks nor always fails.
    assert 10 <= outcomes["cpu_successes"] <= 90
    assert outcomes["success_agreement"] >= 95


def test_perturbed_vehicle_and_thruster_lag_follow_the_cpu_plant():
    """The ``paper`` plant's deterministic parts: the same vehicle draws and actions."""
    disturbances = DockingDisturbances(
        plant=PlantPerturbation(mass=0.1, damping=0.3, net_buoyancy=5.0),
        thruster_time_constant=0.5)
    env_id = "auv_envs/DockingStation-v2"
    cpu = gym.make(env_id, obs_mode="state", disturbances=disturbances).unwrapped
    batched = FunctionalEnv(env_id, obs_mode="state", disturbances=disturbances,
                         auto_reset=False)
    reset_to = jax.jit(batched.reset_to)
    step = jax.jit(batched.step)
    worst = 0.0
    for seed in (4, 18):
        obs, info = cpu.reset(seed=seed)
        draws = info["plant"]
        assert draws["mass_scale"] != 1.0
        start = (cpu.physics.data.qpos.copy(), cpu.physics.data.qvel.copy())
        state = reset_to(*start, jax.random.PRNGKey(seed), plant_draws=draws)
        for _ in range(200):
            action = line_of_sight_policy(obs)[0]
            obs, _, terminated, truncated, info = cpu.step(action)
            state = step(state, jnp.asarray(action))
            assert not (terminated or truncated)
            np.testing.assert_allclose(np.asarray(state.episode.thrust), info["thrust"],
                                       rtol=1e-4, atol=1e-3)
            worst = max(worst, float(np.abs(np.asarray(state.plant["qpos"][:3])
                                            - info["true_position"]).max()))
    assert worst < 0.01
    # The check can fail: with a vehicle of its own drawing the batch leaves the CPU path.
    state = reset_to(*start, jax.random.PRNGKey(0))
    assert float(state.episode.plant[0]) != pytest.approx(draws["mass_scale"])
    obs = cpu.reset(seed=18)[0]
    for _ in range(200):
        action = line_of_sight_policy(obs)[0]
        obs, _, _, _, info = cpu.step(action)
        state = step(state, jnp.asarray(action))
    assert np.abs(np.asarray(state.plant["qpos"][:3]) - info["true_position"]).max() > 0.01


@pytest.mark.parametrize(("env_id", "level"), [
    ("auv_envs/DockingStation-v2", "paper"), ("auv_envs/LampArrayDocking-v2", "paper"),
    ("auv_envs/DockingStation-v2", "hard")])
def test_the_levels_water_and_current_have_the_cpu_envs_statistics(env_id, level):
    """Random draws differ between the two generators; their effects must not.

    The share of the lamps in view that the camera detects (the water's
    detection model, failed lamps, occluders) over 40 CPU episodes of 6 s and
    400 batched ones; and the Gauss–Markov current's mean speed after 6 s in
    the batch against 4000 draws of the CPU env's process.
    """
    episodes, batch, steps = 40, 400, 60
    action = np.array([0.3, 0.0, 0.0, 0.0], np.float32)
    cpu = gym.make(env_id, obs_mode="features", difficulty=level).unwrapped
    detected = in_view = 0
    for seed in range(900, 900 + episodes):
        cpu.reset(seed=seed)
        for _ in range(steps):
            obs, _, terminated, truncated, info = cpu.step(action)
            detected += int(obs["visible"].sum())
            in_view += info["lights_visible"]
            if terminated or truncated:
                break
    batched = FunctionalEnv(env_id, obs_mode="features", difficulty=level, auto_reset=False)
    state = jax.jit(jax.vmap(batched.reset))(jax.random.split(jax.random.PRNGKey(9), batch))
    step = jax.jit(jax.vmap(batched.step))
    alive = np.ones(batch, dtype=bool)
    batch_detected = batch_in_view = 0
    for _ in range(steps):
        state = step(state, jnp.tile(action, (batch, 1)))
        batch_detected += int((np.asarray(state.obs["visible"]).sum(1) * alive).sum())
        batch_in_view += int((np.asarray(state.metrics["lights_visible"]) * alive).sum())
        alive &= ~np.asarray(state.done)
    share, batch_share = detected / in_view, batch_detected / batch_in_view
    assert in_view > 5000
    assert abs(share - batch_share) < 0.04, (share, batch_share)
    # The current: the CPU env's process (its own generator), 6 s after its start.
    current = cpu.calibration.disturbances.current
    rng = np.random.default_rng(0)
    speeds = []
    for _ in range(4000):
        speed, direction = current.start(0.0, 1.0, rng, FLOATS)
        for _ in range(steps):
            speed, direction = current.advance(speed, direction, 0.0, 1.0, cpu.dt, rng, FLOATS)
        speeds.append(speed)
    batch_speeds = np.asarray(state.episode.current_polar)[:, 0]
    np.testing.assert_allclose(np.hypot(*np.asarray(state.episode.current)[:, :2].T),
                               batch_speeds, rtol=1e-5, atol=1e-6)
    assert np.mean(speeds) > 0.05  # the current varies at this level
    assert abs(np.mean(batch_speeds) - np.mean(speeds)) < 0.15 * np.mean(speeds)


def test_make_vec_speaks_numpy_and_resets_finished_episodes():
    envs = gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs=4, obs_mode="features",
                        max_episode_steps=30)
    assert isinstance(envs, gym.vector.VectorEnv)
    # Compiled programs go to a persistent cache (a later process loads them) on a GPU or
    # TPU; on the CPU, whose loader can crash on a large program, none is set.
    cache = envs.unwrapped.compilation_cache
    if jax.default_backend() == "cpu":
        assert cache is None and not jax.config.jax_compilation_cache_dir
    else:
        assert cache.is_dir() and str(cache) == jax.config.jax_compilation_cache_dir
    obs, info = envs.reset(seed=5)
    assert envs.observation_space.contains(obs)
    again, _ = envs.reset(seed=5)
    for key in obs:
        np.testing.assert_array_equal(obs[key], again[key])
    ended = 0
    for _ in range(30):
        obs, reward, terminated, truncated, info = envs.step(np.zeros((4, 4), np.float32))
        assert envs.observation_space.contains(obs)
        assert reward.shape == terminated.shape == truncated.shape == (4,)
        assert reward.dtype == np.float32 and terminated.dtype == bool
        assert set(info) >= {"distance_to_entrance", "lights_visible", "reward_progress"}
        if terminated.any() or truncated.any():
            done = terminated | truncated
            np.testing.assert_array_equal(info["_final_obs"], done)
            np.testing.assert_array_equal(info["_episode_metrics"], done)
            metrics = info["episode_metrics"]
            assert set(metrics["failure_reason"][truncated]) <= {"time_limit"}
            np.testing.assert_array_equal(metrics["steps"][truncated], 30)
            ended += int(done.sum())
    assert ended == 4  # every episode truncated at 30 steps (drifting, far from failing)
    assert obs["visible"].dtype == np.int8
    # The CPU envs' action rule (tests/test_trust_numbers.py): the same refusals ...
    with pytest.raises(ValueError, match="finite"):
        envs.step(np.full((4, 4), np.nan, np.float32))
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.zeros((3, 4), np.float32))
    for bad, message in ((None, "None"), (np.full((4, 4), 1j), "complex"),
                         (np.ones((4, 4), bool), "booleans"), (np.full((4, 4), np.inf), "finite")):
        with pytest.raises(ValueError, match=message):
            envs.step(bad)
    # ... and a huge finite action clipped as a small one (float32 would make it inf).
    stepped = []
    for value in (1e300, 2.0):
        envs.reset(seed=5)
        stepped.append(envs.step(np.full((4, 4), value))[0])
    for key in stepped[0]:
        np.testing.assert_array_equal(stepped[0][key], stepped[1][key])


def test_refuses_what_it_does_not_build():
    with pytest.raises(ValueError, match="difficulty"):
        FunctionalEnv("auv_envs/DockingStation-v2", difficulty="extreme")
    with pytest.raises(ValueError, match="obs_mode"):
        FunctionalEnv("auv_envs/DockingStation-v2", obs_mode="image")
    with pytest.raises(ValueError, match="superseded"):
        FunctionalEnv("auv_envs/DockingStation-v0")
    with pytest.raises(TypeError):
        FunctionalEnv("auv_envs/DockingStation-v2", no_such_argument=1)
    assert failure_reason(0, True) == "" and failure_reason(0, False) == "time_limit"
    assert failure_reason(2, False) == "seabed"


def test_importing_the_batched_package_prints_nothing():
    """MJX's "Failed to import warp" notes (an optional backend these envs do not use)
    are not passed on to the user."""
    out = subprocess.run([sys.executable, "-c", "import auv_envs.batched.vector"],
                         capture_output=True, text=True, check=True)
    assert out.stdout == ""


def test_step_batch_is_vmap_of_step_with_fewer_resets():
    """FunctionalEnv.step_batch (the auto-reset once for the batch, only on a step where an
    episode ended) gives the states jax.vmap(step) gives, resets included."""
    env = FunctionalEnv("auv_envs/DockingStation-v2", obs_mode="features", time_limit=0.5)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(8), 3))
    by_env, by_batch = jax.jit(jax.vmap(env.step)), jax.jit(env.step_batch)
    actions = jnp.asarray(np.random.default_rng(1).uniform(-1, 1, (12, 3, 4)), jnp.float32)
    # Environment 0 two steps ahead, so on some steps one episode ends and the others not.
    ahead = by_env(by_env(states, actions[0]), actions[1])
    a = b = jax.tree_util.tree_map(lambda x, y: x.at[0].set(y[0]), states, ahead)
    ended = 0
    for k in range(12):
        a, b = by_env(a, actions[k]), by_batch(b, actions[k])
        ended += int(np.asarray(a.done).sum())
        for left, right in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b),
                               strict=True):
            np.testing.assert_array_equal(np.asarray(left), np.asarray(right))
    assert ended >= 6  # episodes of 5 steps: two restarts each
