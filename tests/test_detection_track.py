"""The acoustic learners' track (baselines/rl/detection_fixes.py, ``detection_track``): a
Kalman track over the detection fixes, one definition on NumPy and JAX.

Checks the track against an independently written constant-velocity Kalman filter (whole
6-state matrices) on fixes whose truth is known, its gate and its restart, JAX float32
against NumPy float64 over a ``hard`` episode, and the wrapper's observation.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from baselines.rl.config import ConfigError
from baselines.rl.detection_fixes import (
    DEVIATION_KEYS,
    TRACK_ACCEL_STD,
    TRACK_GATE,
    TRACK_KEYS,
    TRACK_MAX_MISSES,
    TRACK_VARIANCE_FLOOR,
    DetectionTrack,
    Held,
    Motion,
    Track,
    observe_track,
    track_step,
)

ACOUSTIC = "auv_envs/AcousticTracking-v2"
DT = 0.1


class ReferenceFilter:
    """The constant-velocity Kalman filter written from its equations: state (x, y, z,
    vx, vy, vz), F = [[I, dt I], [0, I]], Q the white-acceleration covariance, H = [I 0]."""

    def __init__(self, dt: float, accel_std: float):
        eye, zero = np.eye(3), np.zeros((3, 3))
        self.F = np.block([[eye, dt * eye], [zero, eye]])
        q = accel_std ** 2
        self.Q = q * np.block([[dt ** 4 / 4 * eye, dt ** 3 / 2 * eye],
                               [dt ** 3 / 2 * eye, dt ** 2 * eye]])
        self.H = np.hstack([eye, zero])
        self.x = self.P = None

    def start(self, z, r):
        self.x = np.concatenate([z, np.zeros(3)])
        self.P = np.diag(np.concatenate([r, np.ones(3)]))

    def predict(self):
        self.x = self.F @ self.x
        self.P = self.F @ self.P @ self.F.T + self.Q

    def distance(self, z, r):
        nu = z - self.H @ self.x
        return float(nu @ np.linalg.solve(self.H @ self.P @ self.H.T + np.diag(r), nu))

    def update(self, z, r):
        S = self.H @ self.P @ self.H.T + np.diag(r)
        K = self.P @ self.H.T @ np.linalg.inv(S)
        self.x = self.x + K @ (z - self.H @ self.x)
        self.P = (np.eye(6) - K @ self.H) @ self.P


def _fixes(z, r, valid, slots: int = 3):
    """One band of ``slots`` fixes, the first ``z`` (variances ``r``) valid or not, the
    others clutter that is not valid."""
    position = np.full((1, slots, 3), 50.0)
    variance = np.ones((1, slots, 3))
    position[0, 0], variance[0, 0] = z, r
    ok = np.zeros((1, slots), bool)
    ok[0, 0] = valid
    return position, variance, ok


def test_the_track_is_a_constant_velocity_kalman_filter_with_a_gate_and_a_restart():
    rng = np.random.default_rng(4)
    reference = ReferenceFilter(DT, TRACK_ACCEL_STD)
    track = Track.start()
    truth = np.array([10.0, -5.0, -20.0])
    velocity = np.array([0.5, 0.2, -0.1])
    misses, events = 0, {"gated": 0, "outlier": 0, "restart": 0}
    for step in range(200):
        truth = truth + DT * velocity
        r = np.array([0.01, 0.02, 0.04])
        z = truth + rng.normal(0.0, np.sqrt(r))
        valid = not 120 <= step < 120 + TRACK_MAX_MISSES + 5  # a long dropout
        if step in (40, 41, 90):
            z = z + np.array([8.0, 0.0, 0.0])  # outliers, outside the gate
        track = track_step(Motion.of(DT), track, *_fixes(z, r, valid))
        floored = r + TRACK_VARIANCE_FLOOR
        if reference.x is None:
            reference.start(z, floored)
            continue
        reference.predict()
        if valid and misses >= TRACK_MAX_MISSES:
            reference.start(z, floored)
            misses = 0
            events["restart"] += 1
        elif valid and reference.distance(z, floored) <= TRACK_GATE:
            reference.update(z, floored)
            misses = 0
            events["gated"] += 1
        else:
            misses += 1
            events["outlier"] += valid
        assert int(track.misses) == misses
        np.testing.assert_allclose(track.position, reference.x[:3], atol=1e-4)
        np.testing.assert_allclose(track.velocity, reference.x[3:], atol=1e-4)
        np.testing.assert_allclose(track.pp, np.diag(reference.P)[:3], rtol=1e-4)
        np.testing.assert_allclose(track.pv, np.diag(reference.P, 3), rtol=1e-4, atol=1e-9)
        np.testing.assert_allclose(track.vv, np.diag(reference.P)[3:], rtol=1e-4)
    assert events == {"gated": 170, "outlier": 3, "restart": 1}
    assert np.linalg.norm(track.position - truth) < 0.2


def test_the_track_starts_at_the_fix_nearest_the_median():
    position = np.array([[[1.0, 0.0, 0.0], [1.2, 0.1, 0.0], [40.0, 40.0, 0.0]],
                         [[0.9, 0.0, 0.1], [0.0, 0.0, 0.0], [-30.0, 5.0, 0.0]]])
    valid = np.array([[True, True, True], [True, False, True]])
    track = track_step(Motion.of(DT), Track.start(), position, np.full((2, 3, 3), 0.01), valid)
    assert bool(track.started) and int(track.misses) == 0
    np.testing.assert_allclose(track.position, [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(track.velocity, 0.0)
    nothing = track_step(Motion.of(DT), Track.start(), position, np.ones((2, 3, 3)),
                         np.zeros((2, 3), bool))
    assert not bool(nothing.started)


def _observations(seed: int, steps: int):
    env = gym.make(ACOUSTIC, obs_mode="measurements", difficulty="hard")
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(np.array([150.0, 150.0, -15.0], np.float32))
        out.append(obs)
    return out


def test_the_track_on_jax_follows_the_numpy_track():
    """Float32 against float64 over a hard episode: the same decisions (started, misses,
    validity), the track within 5 cm (3.4 cm on this episode), the deviations alike. With
    the clock correction the TDOA rows (in m^2) weigh more and the float32 fixes depart
    further from the float64 ones than without it (4.6 mm): on this episode up to 11 cm for
    a fix that fits badly, 1.3 cm at the 90th percentile."""
    import jax
    import jax.numpy as jnp

    wrapper = DetectionTrack(gym.make(ACOUSTIC, obs_mode="measurements", difficulty="hard"))
    params = wrapper.params
    step = jax.jit(lambda carry, obs: observe_track(params, carry, obs, jnp))
    cpu, traced = wrapper.start(), (Held.start(params, jnp), Track.start(jnp),
                                    params.clock.start(jnp))
    worst, deviations = 0.0, []
    for obs in _observations(7, 300):
        cpu, seen = observe_track(params, cpu, obs)
        traced, seen_jax = step(traced, {k: jnp.asarray(v) for k, v in obs.items()})
        assert wrapper.observation_space.contains(seen)
        assert bool(traced[1].started) == bool(cpu[1].started)
        assert int(traced[1].misses) == int(cpu[1].misses)
        worst = max(worst, float(np.max(np.abs(np.asarray(traced[1].position)
                                               - cpu[1].position))))
        for key in ("fix_valid", "held_fix_valid", "track_fix_valid"):
            np.testing.assert_array_equal(seen[key], np.asarray(seen_jax[key]))
        for key, valid in zip(DEVIATION_KEYS, ("fix_valid", "held_fix_valid",
                                               "track_fix_valid"), strict=True):
            mask = seen[valid] > 0
            deviations += list(np.abs(seen[key][mask] - np.asarray(seen_jax[key])[mask]))
    assert bool(cpu[1].started) and worst < 0.05, worst
    assert np.median(deviations) < 0.01 and np.max(deviations) < 0.5


def test_the_wrapper_adds_the_track_and_forgets_it_at_reset():
    wrapper = DetectionTrack(gym.make(ACOUSTIC, obs_mode="measurements", difficulty="paper"))
    obs, _ = wrapper.reset(seed=3)
    assert set(TRACK_KEYS) | set(DEVIATION_KEYS) <= set(obs)
    assert wrapper.observation_space.contains(obs)
    # the first fixes start the track; no token has a deviation before it existed
    assert not obs["fix_deviation"].any() and obs["track_fix_deviation"][0] == 0.0
    for _ in range(30):
        obs, *_ = wrapper.step(np.array([150.0, 150.0, -15.0], np.float32))
    assert obs["track_fix_valid"][0] == 1
    assert obs["fix_deviation"][obs["fix_valid"] > 0].min() < np.log1p(TRACK_GATE)
    obs, _ = wrapper.reset(seed=4)
    assert int(wrapper.state[1].misses) == 0 and not obs["fix_deviation"].any()


def test_the_track_front_end_is_acoustic_only_and_not_beside_the_fixes():
    from baselines.rl.config import resolve_config

    with pytest.raises(ConfigError, match="obs_mode='measurements'"):
        DetectionTrack(gym.make(ACOUSTIC, obs_mode="state"))
    with pytest.raises(ConfigError, match="set detection_fixes: false with it"):
        resolve_config("cppo", ACOUSTIC, 0, {"detection_track": True})
    with pytest.raises(ConfigError, match="measurements front ends"):
        resolve_config("cppo", "auv_envs/DockingStation-v2", 0, {"detection_track": True})


@pytest.mark.parametrize("difficulty", ["paper", "hard"])
def test_the_pure_clock_step_is_the_estimators_update(difficulty):
    """ClockOffsetEstimator.step (fixed shapes; NumPy and JAX) folds in what update does."""
    import jax
    import jax.numpy as jnp

    from baselines.acoustic.perception.positioning import (
        ClockOffsetEstimator,
        LeastSquaresPositioner,
    )

    env = gym.make(ACOUSTIC, obs_mode="measurements", difficulty=difficulty)
    calibration = env.unwrapped.calibration
    estimator, fused = ClockOffsetEstimator(calibration), LeastSquaresPositioner(calibration,
                                                                                 "fused")
    state, traced = estimator.start(), estimator.start(jnp)
    step = jax.jit(lambda s, *a: estimator.step(s, *a, xp=jnp))
    obs, _ = env.reset(seed=11)
    for _ in range(150):
        measured = tuple(obs[k] for k in ("tdoa", "azimuth", "elevation"))
        valid = fused.solve(*measured, obs["mask"], estimator.clock,
                            obs.get("node_mask")).valid
        estimator.update(*measured, valid, obs.get("node_mask"))
        state = estimator.step(state, *measured, valid, obs.get("node_mask"))
        np.testing.assert_allclose(state.offset, estimator.offset, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(state.precision, estimator._precision, rtol=1e-9)
        traced = step(traced, *(jnp.asarray(m, jnp.float32) for m in measured), valid,
                      obs.get("node_mask"))
        obs, *_ = env.step(np.array([150.0, 150.0, -15.0], np.float32))
    assert estimator.samples > 0
    np.testing.assert_allclose(np.asarray(traced.offset), estimator.offset,
                               atol=0.02 * float(np.max(estimator.std)))
    np.testing.assert_allclose(np.asarray(traced.precision), estimator._precision, rtol=1e-3)


@pytest.mark.parametrize("difficulty", ["paper", "hard"])
def test_the_track_follows_ls_kf(difficulty):
    """On the same episode the track stays within decimetres of ``ls-kf``'s estimate (the
    same filter, gate and clock calibration; the track takes the fixes' covariances by
    their diagonals): median 3.4 cm at paper and 6.8 cm at hard on this seed."""
    from baselines.acoustic.agents import LSKalmanAgent

    env = gym.make(ACOUSTIC, obs_mode="measurements", difficulty=difficulty, time_limit=10.0)
    wrapper = DetectionTrack(gym.make(ACOUSTIC, obs_mode="measurements",
                                      difficulty=difficulty))
    agent = LSKalmanAgent(env.unwrapped)
    obs, info = env.reset(seed=31)
    agent.reset()
    wrapper.clear()
    gaps, done = [], False
    while not done:
        wrapper.state, _ = wrapper.advance(wrapper.state, obs)
        action = agent.act(obs, info)
        track = wrapper.state[1]
        if track.started:
            gaps.append(float(np.linalg.norm(track.position - action)))
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    assert len(gaps) > 900
    assert np.median(gaps) < 0.1 and np.percentile(gaps, 99) < 0.3, np.percentile(
        gaps, [50, 99])
