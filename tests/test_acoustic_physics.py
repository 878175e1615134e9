"""The acoustic environment's added physics (sound-speed error, propagation delay,
travel-time wander), the static point's Cramer-Rao bound, each against an independent
derivation, and the leaderboard's bound row (the bound itself: ``test_acoustic_bound.py``)."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from auv_envs.core.acoustics import AcousticConfig
from auv_envs.tasks.acoustic.env import HARD_ACOUSTICS, PAPER_ACOUSTICS
from auv_envs.tasks.acoustic.transition import STATIC_POINTS

ENV_ID = "auv_envs/AcousticTracking-v2"
#: No noise, no misses, no clutter, no ghosts: measurements are the geometry.
EXACT = AcousticConfig(noise_scale=0.0, clock_offset_std=0.0, clutter_rate=0.0,
                       ideal_detection=True, multipath=False, max_detections=1)


def test_sound_speed_error_scales_every_tdoa(array_of):
    array = array_of(EXACT)
    point = np.array(STATIC_POINTS[3])
    true_speed = 1507.5
    m = array.measure(np.random.default_rng(0), point, np.zeros(8), sound_speed=true_speed, xp=np)
    ranges = np.linalg.norm(point - array.positions, axis=1)
    np.testing.assert_allclose(m.tdoa[0, 0], (ranges[1:] - ranges[0]) / true_speed, rtol=1e-12)
    nominal = array.noise_free(point, np)[0]
    np.testing.assert_allclose(m.tdoa[0, 0], nominal * 1500.0 / true_speed, rtol=1e-12)
    with pytest.raises(ValueError, match="sound_speed"):
        array.measure(np.random.default_rng(0), point, np.zeros(8), sound_speed=-1.0, xp=np)


def test_sound_speed_draws_follow_the_configured_spread(array_of):
    array = array_of(dataclasses.replace(EXACT, sound_speed_error_std=3.0))
    rng = np.random.default_rng(1)
    speeds = np.array([array.draw_sound_speed(rng, np) for _ in range(4000)])
    assert abs(speeds.mean() - 1500.0) < 0.2
    assert speeds.std() == pytest.approx(3.0, rel=0.05)
    off = array_of(EXACT)
    state = rng.bit_generator.state
    assert off.draw_sound_speed(rng, np) == 1500.0
    assert rng.bit_generator.state == state  # no draw when the error is off


def test_env_reports_and_uses_the_episode_sound_speed():
    config = dataclasses.replace(EXACT, sound_speed_error_std=5.0)
    env = gym.make(ENV_ID, acoustic=config, trajectory="static", static_point=2)
    try:
        obs, info = env.reset(seed=4)
        c_true = info["sound_speed"]
        assert c_true != 1500.0
        array = env.unwrapped.calibration.array
        exact = array.noise_free(info["true_position"], np)[0] * 1500.0 / c_true
        np.testing.assert_allclose(obs["tdoa"][0, 0], exact, rtol=1e-9)
    finally:
        env.close()


def _retarded(start, velocity, t, node, c):
    """Where a source moving as start + velocity t was when the sound heard at ``t``
    left it: solve |p(t - tau) - node| = c tau (a quadratic in tau)."""
    d = start + velocity * t - node
    a = velocity @ velocity - c * c
    b = -2.0 * (d @ velocity)
    tau = (-b - math.sqrt(b * b - 4 * a * (d @ d))) / (2 * a)
    return start + velocity * (t - tau)


def test_emission_positions_match_the_retarded_time(array_of):
    array = array_of(EXACT)
    dt, n = 0.01, 120
    start, velocity = np.array([120.0, 140.0, -12.0]), np.array([1.5, -0.8, 0.1])
    track = start + velocity * (dt * np.arange(n))[:, None]
    count = 50
    emitted = array.emission_positions(track, count, dt, xp=np)
    for j in (0, 25, 49):
        t = dt * (n - count + j)
        for i in (0, 3, 7):
            expected = _retarded(start, velocity, t, array.positions[i], 1500.0)
            np.testing.assert_allclose(emitted[j, i], expected, atol=1e-6)
    # Angles see each node's own emission position, every TDOA node 1's.
    m = array.measure(np.random.default_rng(0), emitted, np.zeros(8), xp=np)
    tdoa, azimuth, elevation = array.noise_free(emitted[:, 0], np)
    np.testing.assert_allclose(m.tdoa[:, 0, 0], tdoa, atol=1e-12)
    for i in range(8):
        own = array.noise_free(emitted[:, i], np)
        np.testing.assert_allclose(m.azimuth[:, 0, 0, i], own[1][:, i], atol=1e-12)
        np.testing.assert_allclose(m.elevation[:, 0, 0, i], own[2][:, i], atol=1e-12)


def test_a_source_at_rest_is_heard_where_it_is(array_of):
    array = array_of(EXACT)
    track = np.broadcast_to(np.array(STATIC_POINTS[0]), (80, 3))
    np.testing.assert_allclose(array.emission_positions(track, 50, 0.01, xp=np),
                               np.broadcast_to(track[0], (50, 8, 3)), atol=1e-12)


def test_travel_time_wander_is_the_documented_gauss_markov_process(array_of):
    config = dataclasses.replace(EXACT, fluctuation_intensity=1e-3, fluctuation_length=10.0,
                                 fluctuation_time=0.5)
    array = array_of(config)
    rng = np.random.default_rng(3)
    unit = array.draw_wander(rng, 20000, xp=np)
    assert unit.std() == pytest.approx(1.0, rel=0.05)
    lag = np.mean([np.corrcoef(unit[:-1, i], unit[1:, i])[0, 1] for i in range(8)])
    assert lag == pytest.approx(math.exp(-0.01 / 0.5), abs=0.01)
    # Continuing a block keeps the correlation across the boundary.
    first = array.draw_wander(np.random.default_rng(5), 50, xp=np)
    nxt = array.draw_wander(np.random.default_rng(6), 50, first[-1], xp=np)
    a = math.exp(-0.01 / 0.5)
    shock = (nxt[0] - a * first[-1]) / math.sqrt(1 - a * a)
    assert np.all(np.abs(shock) < 5)
    # The arrival-time spread at a node is mu sqrt(L R) / c.
    point = np.array(STATIC_POINTS[2])
    m = array.measure(rng, np.broadcast_to(point, (len(unit), 3)), np.zeros(8), wander=unit, xp=np)
    exact = array.noise_free(point, np)[0]
    ranges = np.linalg.norm(point - array.positions, axis=1)
    sigma = 1e-3 * np.sqrt(10.0 * ranges) / 1500.0
    expected = np.hypot(sigma[1:], sigma[0])
    np.testing.assert_allclose((m.tdoa[:, 0, 0] - exact).std(axis=0), expected, rtol=0.08)
    assert array_of(EXACT).draw_wander(rng, 10, xp=np) is None


def test_crb_is_reached_by_the_weighted_least_squares_fix(array_of):
    """At high SNR the maximum-likelihood fix is efficient: its RMSE equals the bound."""
    config = dataclasses.replace(AcousticConfig(), clock_offset_std=0.0, clutter_rate=0.0,
                                 ideal_detection=True, multipath=False, max_detections=1)
    array = array_of(config)
    point = np.array(STATIC_POINTS[1])
    bound = array.position_crb(point)
    model = array.model(point)
    n, trials = 8, 400
    m = array.measure(np.random.default_rng(9), np.broadcast_to(point, (trials, 3)), np.zeros(n),
                      xp=np)
    # Gauss-Newton weighted least squares over all bands of one period, written here from
    # the model's documented covariances (independent of position_crb's code).
    weights = []
    for q in range(config.n_bands):
        arrival = model["arrival_std"][q]
        cov = np.zeros((3 * n - 1, 3 * n - 1))
        cov[: n - 1, : n - 1] = np.diag(arrival[1:] ** 2) + arrival[0] ** 2
        cov[n - 1 : 2 * n - 1, n - 1 : 2 * n - 1] = np.diag(model["azimuth_std"][q] ** 2)
        cov[2 * n - 1 :, 2 * n - 1 :] = np.diag(model["elevation_std"][q] ** 2)
        weights.append(np.linalg.inv(cov))
    errors = []
    for k in range(trials):
        z = [np.concatenate([m.tdoa[k, q, 0], m.azimuth[k, q, 0], m.elevation[k, q, 0]])
             for q in range(config.n_bands)]
        x = point + 0.05
        for _ in range(4):
            h0 = np.concatenate(array.noise_free(x, np))
            jac = np.stack([(np.concatenate(array.noise_free(x + e, np)) - h0) / 1e-4
                            for e in 1e-4 * np.eye(3)], axis=1)
            normal, rhs = np.zeros((3, 3)), np.zeros(3)
            for q in range(config.n_bands):
                residual = z[q] - h0
                residual[n - 1 : 2 * n - 1] = np.angle(np.exp(1j * residual[n - 1 : 2 * n - 1]))
                normal += jac.T @ weights[q] @ jac
                rhs += jac.T @ weights[q] @ residual
            x = x + np.linalg.solve(normal, rhs)
        errors.append(x - point)
    rmse = math.sqrt(np.mean(np.sum(np.square(errors), axis=1)))
    assert rmse == pytest.approx(bound, rel=0.12)


def test_crb_grows_with_the_level_and_rejects_bad_input(array_of):
    point = STATIC_POINTS[4]
    bounds = [array_of(c).position_crb(point) for c in
              (AcousticConfig(), PAPER_ACOUSTICS, HARD_ACOUSTICS)]
    assert bounds[0] < bounds[1] < bounds[2]
    array = array_of(AcousticConfig())
    assert array.position_crb(point, periods=100) == pytest.approx(bounds[0] / 10.0, rel=1e-9)
    with pytest.raises(ValueError):
        array.position_crb((np.nan, 1.0, 2.0))
    with pytest.raises(ValueError):
        array.position_crb(point, periods=0)


def test_paper_level_turns_the_added_physics_on():
    env = gym.make(ENV_ID, difficulty="paper")
    try:
        config = env.unwrapped.calibration.config
        assert config == PAPER_ACOUSTICS
        assert config.propagation_delay and config.fluctuation_intensity > 0
        assert config.sound_speed_error_std > 0 and config.flow_noise_level is not None
        _, info = env.reset(seed=0)
        assert info["sound_speed"] != 1500.0
    finally:
        env.close()
    mine = AcousticConfig(clutter_rate=5.0)
    env = gym.make(ENV_ID, difficulty="hard", acoustic=mine)
    try:
        assert env.unwrapped.calibration.config is mine
    finally:
        env.close()


def test_leaderboard_shows_the_bound_beside_the_trackers_unranked():
    from baselines import leaderboard
    from baselines.evaluation import BOUND_AGENT, BOUND_LABEL, bound_rows
    from baselines.stats import bootstrap_interval

    def row(agent, rmse, scenario, kwargs, seeds):
        stat = {"mean": rmse, "std": 0.0, "n": 5, "ci": [rmse * 0.9, rmse * 1.1]}
        return {"env_id": ENV_ID, "obs_mode": "measurements", "scenario": scenario,
                "agent": agent, "episodes": 5, "failed": 0, "status": "ok", "seeds": seeds,
                "errors": [], "failure_reasons": {}, "env_kwargs": kwargs, "group": None,
                "metrics": {"success": {"mean": 1.0, "std": 0.0, "n": 5, "ci": [0.5, 1.0]},
                            "rmse": stat}}

    paper = {"difficulty": "paper", "time_limit": 3.0}
    hard = {"difficulty": "hard", "time_limit": 3.0}
    summary = [row("a", 0.05, "paper", paper, [913010]),
               row("b", 0.30, "paper", paper, [913011]),
               row("a", 0.50, "hard", hard, [913010, 913011])]
    bounds = bound_rows(summary)
    assert [(b["agent"], b["scenario"], b["label"]) for b in bounds] == [
        (BOUND_AGENT, "paper", BOUND_LABEL), (BOUND_AGENT, "hard", BOUND_LABEL)]
    for bound in bounds:  # one bound per episode of the scenario's seeds, with its interval
        assert bound["seeds"] == [913010, 913011] and bound["episodes"] == 2
        env = gym.make(ENV_ID, **bound["env_kwargs"])
        values = []
        for seed in bound["seeds"]:
            env.reset(seed=seed)
            values.append(env.unwrapped.trajectory_bound())
        env.close()
        stat = bound["metrics"]["rmse"]
        assert stat["mean"] == pytest.approx(np.mean(values), rel=1e-12)
        assert stat["ci"] == pytest.approx(list(bootstrap_interval(values)), rel=1e-12)
    assert bounds[0]["metrics"]["rmse"]["mean"] < bounds[1]["metrics"]["rmse"]["mean"]
    rows = leaderboard.by_env(summary + bounds)[ENV_ID]
    labels = dict(zip([(r["agent"], r["scenario"]) for r in rows],
                      leaderboard.rank_labels(rows), strict=True))
    assert labels[(BOUND_AGENT, "paper")] == "bound"
    assert labels[("a", "paper")] == "1" and labels[("b", "paper")] == "2"
    assert labels[("a", "hard")] == "1"
    # Beside the trackers, sorted by its RMSE (below every tracker's), with its label.
    assert [r["agent"] for r in rows if r["scenario"] == "paper"] == [BOUND_AGENT, "a", "b"]
    assert f"`{BOUND_AGENT}`: {BOUND_LABEL}" in leaderboard.markdown(summary + bounds)


def test_band_fading_is_a_gauss_markov_fade_of_each_bands_snr(array_of):
    config = dataclasses.replace(AcousticConfig(), fading_std=5.6, fading_time=0.5,
                                 timing_floor=0.0, clock_offset_std=0.0, clutter_rate=0.0,
                                 ideal_detection=True, multipath=False, max_detections=1)
    array = array_of(config)
    fades = array.draw_fading(np.random.default_rng(2), 20000, xp=np)
    assert fades.shape == (20000, 10, 8)
    assert fades.std() == pytest.approx(5.6, rel=0.05)
    lag = np.corrcoef(fades[:-1, 3, 5], fades[1:, 3, 5])[0, 1]
    assert lag == pytest.approx(math.exp(-0.01 / 0.5), abs=0.01)
    assert abs(np.corrcoef(fades[:, 0, 0], fades[:, 1, 0])[0, 1]) < 0.1  # bands independent
    # A fade of +20 dB on one band cuts its delay noise tenfold (sigma ~ 1 / sqrt(snr)).
    point = np.array(STATIC_POINTS[0])
    n = 4000
    fade = np.zeros((n, 10, 8))
    fade[:, 2] = 20.0
    m = array.measure(np.random.default_rng(4), np.broadcast_to(point, (n, 3)), np.zeros(8),
                      fading=fade, xp=np)
    exact = array.noise_free(point, np)[0]
    spread = (m.tdoa[:, :, 0] - exact).std(axis=0)  # (Q, N-1)
    model = array.model(point)  # the unfaded noise of bands 1 and 2
    expected = 0.1 * model["tdoa_std"][2] / model["tdoa_std"][1]
    np.testing.assert_allclose(spread[2] / spread[1], expected, rtol=0.1)
    assert array_of(dataclasses.replace(config, fading_std=0.0)).draw_fading(
        np.random.default_rng(0), 5, xp=np) is None

