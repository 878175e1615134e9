"""The LARS marker tracker (baselines/rl/marker_track.py): one definition, NumPy and JAX.

Checks that the CPU wrapper and the JAX functions give the same observation, that the
fix is ckf-pd's marker localiser's and finds the true marker and capture point without
pixel noise, and that the batched wrapper starts the tracker afresh with each episode.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from baselines.lars.perception.marker import MarkerLocaliser, marker_attitude
from baselines.rl.config import ConfigError
from baselines.rl.marker_track import (
    SIZE,
    SLICES,
    MarkerTrack,
    TrackParams,
    TrackState,
    fix,
    observe,
    track,
)

LARS = "auv_envs/LARSCapture-v0"
KWARGS = {"obs_mode": "features", "control": "position", "time_limit": 20.0}


def _servo(vector: np.ndarray) -> np.ndarray:
    """The untrained residual policy: hold + 0.3 x joint offset."""
    return np.clip(vector[SLICES["hold_target"]] + 0.3 * vector[SLICES["joint_offset"]], -1, 1)


def _episode(env: gym.Env, seed: int, steps: int):
    """The raw observations and infos of a servo-driven episode (at most ``steps``)."""
    tracker = MarkerTrack(env)
    obs, info = env.reset(seed=seed)
    tracker.reset()
    out = [(obs, info)]
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(_servo(tracker.observation(obs)))
        out.append((obs, info))
        if terminated or truncated:
            break
    return tracker.params, out


def test_the_tracker_on_jax_gives_the_cpu_observation():
    import jax
    import jax.numpy as jnp

    env = gym.make(LARS, difficulty="paper", **KWARGS)
    params, episode = _episode(env, seed=11, steps=80)

    @jax.jit
    def step(state, obs):
        state = track(params, state, obs, jnp)
        return state, observe(params, state, obs, jnp)

    cpu, traced = TrackState.start(), TrackState.start(jnp)
    worst, fixes = 0.0, 0
    for obs, _ in episode:
        cpu = track(params, cpu, obs)
        vector = observe(params, cpu, obs)
        traced, on_jax = step(traced, {key: jnp.asarray(value) for key, value in obs.items()})
        assert vector.shape == (SIZE,) and vector.dtype == np.float32
        worst = max(worst, float(np.max(np.abs(vector - np.asarray(on_jax)))))
        fixes = int(cpu.fixes)
    assert fixes > 3  # the track was running, not zeros on both sides
    assert worst < 5e-5, worst


def test_the_fix_is_the_marker_localisers_and_the_true_marker_without_noise():
    env = gym.make(LARS, difficulty="easy", pixel_noise_std=0.0, **KWARGS)
    params, episode = _episode(env, seed=3, steps=40)
    localiser = MarkerLocaliser(env.unwrapped.calibration, None, adapt=False)
    checked = offsets = 0
    tracker = TrackState.start()
    for obs, info in episode:
        tracker = track(params, tracker, obs)
        corners, valid = fix(params, obs["pixels"].astype(float), obs["visible"],
                             obs["joint_position"].astype(float))
        reference = localiser.locate(obs["pixels"], obs["visible"], obs["joint_position"])
        np.testing.assert_array_equal(valid, reference.valid)
        if not valid.all():
            continue
        checked += 1
        np.testing.assert_allclose(corners, reference.corners, atol=1e-9)
        np.testing.assert_allclose(corners, info["true_corners"], atol=5e-3)
        assert marker_attitude(corners, params.calibration.marker.depth_offset) == \
            pytest.approx(marker_attitude(reference.corners,
                                          params.calibration.marker.depth_offset), abs=1e-9)
        if int(tracker.fixes) == 1:  # the first fix starts the track where the marker says
            offset = observe(params, tracker, obs)[SLICES["offset"]]
            np.testing.assert_allclose(offset, info["capture_offset"], atol=0.01)
            offsets += 1
    assert checked >= 3 and offsets == 1  # the first fix's offset was compared


def test_the_batched_tracker_starts_afresh_with_each_episode():
    import jax
    import jax.numpy as jnp

    from auv_envs.batched.functional import FunctionalEnv
    from baselines.rl.marker_track import MarkerTrackMJX

    base = FunctionalEnv("auv_envs/LARSCapture-v0", difficulty="paper", **KWARGS)
    env = MarkerTrackMJX(base.use_unit_actions())
    assert env.observation_space.shape == (SIZE,) and env.max_episode_steps == 500
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(1), 8))
    assert states.obs.shape == (8, SIZE)
    step = jax.jit(env.step_batch)
    restarted = 0
    for _ in range(60):
        before = np.asarray(states.info["marker_track"].fixes)
        actions = jnp.clip(states.obs[:, :3] + 0.3 * states.obs[:, 18:21], -1.0, 1.0)
        states = step(states, actions)
        fixes = np.asarray(states.info["marker_track"].fixes)
        done = np.asarray(states.done)
        # a restarted episode's track holds at most its first fix; the others carry on
        assert np.all(fixes[done] <= 1)
        assert np.all(fixes[~done] >= before[~done])
        restarted += int(done.sum())
    assert restarted > 0  # the servo captures within a few seconds


def test_the_tracker_refuses_other_envs():
    with pytest.raises(ConfigError, match="obs_mode='features'"):
        MarkerTrack(gym.make(LARS, obs_mode="state"))
    with pytest.raises(ConfigError, match="obs_mode='features'"):
        TrackParams.of(gym.make("auv_envs/DockingStation-v2", obs_mode="features"))
