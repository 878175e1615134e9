"""The batched JAX docking environment against the MuJoCo CPU environment (issue 21, item 3).

The same start state and action sequence must give positions within 1 cm and
light pixels within 1 px over 20 s (float32 against float64), and a fixed
policy's success or failure must agree on at least 95 of 100 seeds. The
Gymnasium face (``gym.make_vec``) must speak NumPy, reset finished episodes
on the step that ends them and refuse bad input.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import auv_envs  # noqa: E402,F401
from auv_envs.batched.docking_env import DockingMJX, failure_reason  # noqa: E402
from auv_envs.core.vehicle import PlantPerturbation  # noqa: E402
from auv_envs.tasks.docking import DockingDisturbances  # noqa: E402

LAYOUTS = ("auv_envs/DockingStation-v1", "auv_envs/LampArrayDocking-v1")


def line_of_sight_policy(obs: np.ndarray) -> np.ndarray:
    """A fixed proportional-derivative controller on the ``state`` observation (a batch).

    Steers along a line of sight towards the docking axis, holds depth and
    slows near the entrance: it docks in most calm episodes and fails in
    many with a 0.3 m/s current, which makes its outcomes a sharp test.
    """
    obs = np.atleast_2d(obs)
    x, y, z = obs[:, 0], obs[:, 1], obs[:, 2]
    yaw = np.arctan2(obs[:, 6], obs[:, 5])
    u, v, w, r = obs[:, 7], obs[:, 8], obs[:, 9], obs[:, 12]
    ahead = -1.0 - x  # CG target about 1 m before the entrance plane
    heading = np.arctan2(-y, np.maximum(ahead, 0.0) + 6.0) * np.clip(ahead / 3.0, 0.0, 1.0)
    heading_error = (heading - yaw + np.pi) % (2 * np.pi) - np.pi
    surge = np.clip(0.1 * np.hypot(ahead, y), 0.15, 0.5)
    action = np.stack([0.8 * (surge - u), -0.6 * np.cos(yaw) * y - 1.0 * v,
                       -1.5 * z - 1.5 * w, 1.5 * heading_error - 1.0 * r], axis=1)
    return np.clip(action, -1.0, 1.0).astype(np.float32)


def _start(cpu, seed):
    """Reset the CPU env; return its first ``state`` observation, plant state and current."""
    obs, info = cpu.reset(seed=seed)
    data = cpu.physics.data
    current = info["current"]
    polar = np.array([np.hypot(current[0], current[1]), np.arctan2(current[1], current[0])])
    return obs, data.qpos.copy(), data.qvel.copy(), polar


@pytest.mark.parametrize("env_id", LAYOUTS)
def test_same_start_and_actions_stay_within_1cm_and_1px_over_20s(env_id):
    steps = 200  # 20 s
    state_env = gym.make(env_id, obs_mode="state").unwrapped
    features_env = gym.make(env_id, obs_mode="features").unwrapped
    batched = DockingMJX(env_id, obs_mode="features", auto_reset=False)
    step = jax.jit(jax.vmap(batched.step))
    seeds = (3, 11, 29)
    starts = [_start(state_env, seed) for seed in seeds]
    states = jax.jit(jax.vmap(batched.reset_to))(
        np.stack([s[1] for s in starts]), np.stack([s[2] for s in starts]),
        jax.random.split(jax.random.PRNGKey(0), len(seeds)), np.stack([s[3] for s in starts]))
    worst_position = worst_pixel = 0.0
    compared_pixels = 0
    # The CPU runs the seeds one after the other, the batch all at once.
    logs = []
    for seed in seeds:
        obs, *_ = _start(state_env, seed)
        features_env.reset(seed=seed)
        log = {"action": [], "position": [], "pixels": [], "visible": []}
        for _ in range(steps):
            action = line_of_sight_policy(obs)[0]
            obs, _, terminated, truncated, info = state_env.step(action)
            _, _, _, _, features_info = features_env.step(action)
            assert not (terminated or truncated), "the check needs 20 s of approach"
            log["action"].append(action)
            log["position"].append(info["true_position"])
            log["pixels"].append(features_info["true_pixels"])
            log["visible"].append(features_info["true_visible"])
        logs.append(log)
    for k in range(steps):
        actions = np.stack([log["action"][k] for log in logs])
        states = step(states, jnp.asarray(actions))
        positions = np.asarray(states.data["qpos"][:, :3])
        pixels = np.asarray(states.obs["pixels"])
        visible = np.asarray(states.obs["visible"]).astype(bool)
        for i, log in enumerate(logs):
            worst_position = max(worst_position,
                                 float(np.abs(positions[i] - log["position"][k]).max()))
            np.testing.assert_array_equal(visible[i], log["visible"][k])
            if visible[i].any():
                worst_pixel = max(worst_pixel, float(np.abs(
                    pixels[i][visible[i]] - log["pixels"][k][visible[i]]).max()))
                compared_pixels += int(visible[i].sum())
    assert worst_position < 0.01
    assert worst_pixel < 1.0
    assert compared_pixels > steps  # the lights were in view for most of the approach


def test_a_fixed_policy_docks_or_fails_alike_on_95_of_100_seeds():
    env_id = "auv_envs/DockingStation-v1"
    cpu = gym.make(env_id, obs_mode="state", scenario="current").unwrapped
    seeds = range(700, 800)
    starts, cpu_outcomes = [], []
    for seed in seeds:
        obs, qpos, qvel, current = _start(cpu, seed)
        starts.append((qpos, qvel, current))
        while True:
            obs, _, terminated, truncated, info = cpu.step(line_of_sight_policy(obs)[0])
            if terminated or truncated:
                break
        cpu_outcomes.append(info["episode_metrics"]["success"])
    batched = DockingMJX(env_id, obs_mode="state", scenario="current", auto_reset=False)
    states = jax.jit(jax.vmap(batched.reset_to))(
        np.stack([s[0] for s in starts]), np.stack([s[1] for s in starts]),
        jax.random.split(jax.random.PRNGKey(1), len(starts)), np.stack([s[2] for s in starts]))
    step = jax.jit(jax.vmap(batched.step))
    done = np.zeros(len(starts), dtype=bool)
    outcomes = np.zeros(len(starts), dtype=bool)
    while not done.all():
        states = step(states, jnp.asarray(line_of_sight_policy(np.asarray(states.obs))))
        ended = np.asarray(states.done) & ~done
        outcomes[ended] = np.asarray(states.info["success"])[ended]
        done |= ended
    cpu_outcomes = np.array(cpu_outcomes)
    # A sharp test: the policy neither always docks nor always fails.
    assert 10 <= cpu_outcomes.sum() <= 90
    assert (outcomes == cpu_outcomes).sum() >= 95


def test_perturbed_vehicle_and_thruster_lag_follow_the_cpu_plant():
    """The ``paper`` plant's deterministic parts: the same vehicle draws and actions."""
    disturbances = DockingDisturbances(
        plant=PlantPerturbation(mass=0.1, damping=0.3, net_buoyancy=5.0),
        thruster_time_constant=0.5)
    env_id = "auv_envs/DockingStation-v1"
    cpu = gym.make(env_id, obs_mode="state", disturbances=disturbances).unwrapped
    batched = DockingMJX(env_id, obs_mode="state", disturbances=disturbances,
                         auto_reset=False)
    reset_to = jax.jit(batched.reset_to)
    step = jax.jit(batched.step)
    worst = 0.0
    for seed in (4, 18):
        obs, info = cpu.reset(seed=seed)
        assert info["plant"]["mass_scale"] != 1.0
        state = reset_to(cpu.physics.data.qpos.copy(), cpu.physics.data.qvel.copy(),
                         jax.random.PRNGKey(seed), plant_draws=info["plant"])
        for _ in range(200):
            action = line_of_sight_policy(obs)[0]
            obs, _, terminated, truncated, info = cpu.step(action)
            state = step(state, jnp.asarray(action))
            assert not (terminated or truncated)
            np.testing.assert_allclose(np.asarray(state.info["thrust"]), info["thrust"],
                                       rtol=1e-4, atol=1e-3)
            worst = max(worst, float(np.abs(np.asarray(state.data["qpos"][:3])
                                            - info["true_position"]).max()))
    assert worst < 0.01
    # Without the episode's vehicle the plant is another one: the check can fail.
    state = reset_to(cpu.physics.data.qpos.copy(), cpu.physics.data.qvel.copy(),
                     jax.random.PRNGKey(0))
    assert float(state.info["plant"]["mass_scale"]) != pytest.approx(
        info["plant"]["mass_scale"] if "plant" in info else 0.0)


@pytest.mark.parametrize(("env_id", "level"), [
    ("auv_envs/DockingStation-v1", "paper"), ("auv_envs/LampArrayDocking-v1", "paper"),
    ("auv_envs/DockingStation-v1", "hard")])
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
    batched = DockingMJX(env_id, obs_mode="features", difficulty=level, auto_reset=False)
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
        speed, direction = current.start(0.0, 1.0, rng)
        for _ in range(steps):
            speed, direction = current.advance(speed, direction, 0.0, 1.0, cpu.dt, rng)
        speeds.append(speed)
    batch_speeds = np.asarray(state.info["current_polar"])[:, 0]
    np.testing.assert_allclose(np.hypot(*np.asarray(state.info["current"])[:, :2].T),
                               batch_speeds, rtol=1e-5, atol=1e-6)
    assert np.mean(speeds) > 0.05  # the current varies at this level
    assert abs(np.mean(batch_speeds) - np.mean(speeds)) < 0.15 * np.mean(speeds)


def test_make_vec_speaks_numpy_and_resets_finished_episodes():
    envs = gym.make_vec("auv_envs/DockingStationMJX-v1", num_envs=4, obs_mode="features",
                        max_episode_steps=30)
    assert isinstance(envs, gym.vector.VectorEnv)
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
    with pytest.raises(ValueError, match="finite"):
        envs.step(np.full((4, 4), np.nan, np.float32))
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.zeros((3, 4), np.float32))


def test_refuses_what_it_does_not_build():
    with pytest.raises(ValueError, match="difficulty"):
        DockingMJX("auv_envs/DockingStation-v1", difficulty="extreme")
    with pytest.raises(ValueError, match="obs_mode"):
        DockingMJX("auv_envs/DockingStation-v1", obs_mode="image")
    with pytest.raises(ValueError, match="rk4"):
        DockingMJX("auv_envs/DockingStation-v0")
    with pytest.raises(TypeError):
        DockingMJX("auv_envs/DockingStation-v1", no_such_argument=1)
    assert failure_reason(0, True) == "" and failure_reason(0, False) == "time_limit"
    assert failure_reason(2, False) == "seabed"
