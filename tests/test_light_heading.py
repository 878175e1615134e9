"""The lights' heading filter (baselines/docking/estimation/light_heading.py) and the mission
front end that turns the navigation filter with it (baselines/rl/nav_filter.py): its
projection against the environment's camera (auv_envs.core.camera, written separately),
its Jacobian against finite differences, the deviation it learns from lamps seen along an
approach and in the environment, and the same estimates in JAX (float32) as in NumPy."""

import math

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import auv_envs  # noqa: F401 (registers the ids)
from auv_envs.core.camera import points_in_camera, project
from auv_envs.core.frames import rotation_from_euler
from baselines.docking.estimation import light_heading as lh
from baselines.docking.estimation import navigation_filter as nav
from baselines.rl import nav_filter as nf

MISSION = "auv_envs/DockingMission-v0"


@pytest.fixture(scope="module")
def hard():
    env = gym.make(MISSION, obs_mode="nav_features", difficulty="hard")
    base = env.unwrapped
    return env, lh.HeadingParams.of(base.calibration, base.navigation), base.calibration


def _pixels(cal, position, euler):
    """The lamps' pixels from the environment's camera functions, and which are in front."""
    R_b = rotation_from_euler(*euler, np)
    ext = cal.extrinsics
    camera = np.asarray(position) + R_b @ np.asarray(ext.position)
    q = points_in_camera(cal.light_positions, camera, R_b @ ext.rotation_matrix)
    return project(cal.intrinsics, q)


def test_the_projection_is_the_cameras_and_its_jacobian_its_derivative(hard):
    _, params, cal = hard
    lights = np.asarray(params.lights)
    position, euler = np.array([-5.0, 0.4, -0.3]), np.array([0.03, -0.02, 0.2])
    expected, _ = _pixels(cal, position, euler)
    # x = (p, b, e_roll, e_pitch, e_yaw): the attitude read is the true one plus the errors
    x = np.array([*position, 0.1, 0.01, -0.02, 0.03])
    read = euler + np.array([0.01, -0.02, 0.1 + 0.03])
    pixels, jacobian, _ = lh._measurement(params, lights, x, read, np)
    np.testing.assert_allclose(pixels, expected, atol=1e-9)
    numeric = np.zeros_like(jacobian)
    for j in range(7):
        d = np.zeros(7)
        d[j] = 1e-6
        numeric[:, :, j] = (lh._measurement(params, lights, x + d, read, np)[0]
                            - lh._measurement(params, lights, x - d, read, np)[0]) / 2e-6
    np.testing.assert_allclose(jacobian, numeric, atol=1e-5 * np.abs(jacobian).max())


def _approach(params, cal, deviation: float, steps: int = 120):
    """Noise-free observations of a vehicle gliding in from 3 m before the entrance at
    0.25 m/s, its heading swaying by 3 deg, its AHRS heading ``deviation`` off. (The
    lamps, 2.55 m inside the station on a 0.45 m ring, show the station's yaw by their
    perspective alone, which grows with the inverse square of their range.)"""
    obs = []
    position = np.array([-4.0, 0.3, 0.1])
    for k in range(steps):
        euler = np.array([0.0, 0.0, 0.05 * math.sin(0.1 * k)])
        velocity = np.array([0.25, 0.0, 0.0])
        position = position + rotation_from_euler(*euler, np) @ velocity * params.motion.dt
        pixels, in_front = _pixels(cal, position, euler)
        shown = in_front & (pixels[:, 0] > 0) & (pixels[:, 0] < cal.intrinsics.width) \
            & (pixels[:, 1] > 0) & (pixels[:, 1] < cal.intrinsics.height)
        obs.append({"attitude": euler + np.array([0.0, 0.0, deviation]),
                    "dvl_velocity": velocity, "dvl_valid": np.array([1]),
                    "pixels": np.where(shown[:, None], pixels, 0.0),
                    "visible": shown.astype(np.int8)})
    return obs, position


@pytest.mark.parametrize("deviation", [-0.14, 0.1])
def test_the_deviation_is_learnt_from_the_lamps_along_an_approach(hard, deviation):
    _, params, cal = hard
    state = lh.HeadingState.start(params)
    observations, position = _approach(params, cal, deviation)
    for obs in observations:
        state = lh.step(params, state, obs)
    assert int(state.updates) == len(observations) and int(state.rejected) == 0
    assert abs(float(state.deviation) - deviation) < math.radians(1.0)
    assert math.sqrt(state.covariance[3, 3]) < 0.3 * math.sqrt(params.deviation_var)
    np.testing.assert_allclose(state.position, position, atol=0.1)
    corrected = lh.corrected_attitude(state, observations[-1]["attitude"])
    assert abs(corrected[2] - (observations[-1]["attitude"][2] - deviation)) < math.radians(1.0)


def test_without_a_deviation_in_the_level_the_estimate_stays_zero():
    env = gym.make(MISSION, obs_mode="nav_features", difficulty="paper")
    base = env.unwrapped
    params = lh.HeadingParams.of(base.calibration, base.navigation)
    assert params.deviation_var == 0.0
    state = lh.HeadingState.start(params)
    for obs in _approach(params, base.calibration, 0.1, steps=30)[0]:
        state = lh.step(params, state, obs)
    assert float(state.deviation) == 0.0 and int(state.updates) == 30


def test_a_turned_filter_is_the_same_filter_turned_about_the_centre():
    params = nav.FilterParams((0.5, 0.0, 1.0), 50.0, 0.1)
    state = nav.FilterState.start(params)
    rng = np.random.default_rng(0)
    for _ in range(5):
        state = nav.step(params, state, {
            "attitude": rng.normal(0, 0.1, 3), "dvl_velocity": rng.normal(0, 1, 3),
            "dvl_valid": np.array([1]), "depth": np.array([49.0]), "usbl_valid": np.array([0]),
            "usbl_age": np.array([0.0]), "usbl": np.zeros(3)})
    centre = np.array([0.5, 0.0, 1.0])
    moved = nav.turned(state, 0.3, centre)
    Rz = rotation_from_euler(0.0, 0.0, 0.3, np)
    np.testing.assert_allclose(moved.position - centre, Rz @ (state.position - centre))
    np.testing.assert_allclose(moved.covariance, Rz @ state.covariance @ Rz.T)
    np.testing.assert_allclose(moved.past_rotation[2], Rz @ state.past_rotation[2])
    back = nav.turned(moved, -0.3, centre)
    for got, want in zip(back, state, strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)


def test_the_front_end_learns_the_deviation_in_an_episode_and_jax_agrees(hard):
    """The shipped mission student at hard: the deviation the lights' filter ends with is
    within three of its standard deviations of the episode's, which has shrunk; the front
    end in JAX (float32, jit) keeps the same estimates over the frames with lamps."""
    from baselines.registry import make_agent

    env, params, _ = hard
    agent = make_agent("cppo-mission-nav-filter-s0", env.unwrapped)
    obs, info = env.reset(seed=856000)
    agent.reset(856000)
    truth = float(env.unwrapped._episode.state.nav.heading_bias)
    front = nf.params_of(env)
    carry = nf.start(front)
    observations = []
    while True:
        obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
        carry, _ = nf.advance(front, carry, obs)
        observations.append(obs)
        if terminated or truncated:
            break
    heading = carry.heading
    sigma = math.sqrt(heading.covariance[3, 3])
    assert abs(float(heading.deviation) - truth) < 3 * sigma
    assert sigma < 0.25 * math.sqrt(params.deviation_var)
    assert int(heading.rejected) < 0.05 * int(heading.updates)
    # JAX from shortly before the first lamps, NumPy afresh from the same frame
    first = next(i for i, o in enumerate(observations) if o["visible"].sum() >= 3) - 5
    step32 = jax.jit(lambda c, o: nf.advance(front, c, o, jnp)[0])
    carry64, carry32 = nf.start(front), nf.start(front, jnp)
    for obs in observations[first:]:
        carry64, _ = nf.advance(front, carry64, obs)
        carry32 = step32(carry32, {k: jnp.asarray(v) for k, v in obs.items()})
        assert abs(float(carry32.heading.deviation) - float(carry64.heading.deviation)) \
            < math.radians(0.2)
    assert int(carry32.heading.updates) == int(carry64.heading.updates)
    np.testing.assert_allclose(np.asarray(carry32.heading.position), carry64.heading.position,
                               atol=0.02)


def test_the_batched_front_end_runs_the_heading_filter_at_hard():
    """The compiled PPO's env at hard: the heading filter's carry rides with the
    navigation filter's, restarts with the episode, and the observation stays finite."""
    from baselines.rl import compiled

    env = compiled.make_env(MISSION, "nav_features", {"difficulty": "hard",
                                                      "time_limit": 1.0}, nav_filter=True)
    states = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(1), 2))
    step = jax.jit(env.step_batch)
    for _ in range(12):  # 1 s at 0.1 s: one restart
        states = step(states, jnp.zeros((2, 4)))
    carry = states.info["nav_filter"]
    assert isinstance(carry, nf.Carry)
    assert (np.asarray(carry.nav.length) < 5).all()
    assert np.isfinite(np.asarray(carry.heading.covariance)).all()
    assert all(np.isfinite(np.asarray(v)).all() for v in states.obs.values())
