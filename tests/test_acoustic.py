"""The acoustic tracking environment: measurement model, noise statistics, scene."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest

from auv_envs import metrics
from auv_envs.core.acoustics import (
    GMPHD_FLOW_NOISE_LEVEL,
    ORIGIN_BOTTOM,
    ORIGIN_CLUTTER,
    ORIGIN_SURFACE,
    ORIGIN_TARGET,
    AcousticConfig,
    ambient_noise_level,
    flow_noise_level,
    thorp_absorption,
)
from auv_envs.tasks.acoustic import transition

ENV_ID = "auv_envs/AcousticTracking-v2"


def make(**kwargs) -> gym.Env:
    return gym.make(ENV_ID, **kwargs)


def geometric(position, hydrophones, c):
    """Independent reference: TDOA vs node 1, azimuth, [GMPHD]'s elevation angle."""
    d = np.asarray(position) - hydrophones
    ranges = np.sqrt((d**2).sum(axis=1))
    tdoa = (ranges[1:] - ranges[0]) / c
    azimuth = np.array([math.atan2(v[1], v[0]) for v in d])
    elevation = np.array([math.atan2(math.hypot(v[0], v[1]), v[2]) for v in d])
    return tdoa, azimuth, elevation


def documented_model(config, hydrophones, position, current_speed=0.0):
    """The noise model exactly as documented in auv_envs.core.acoustics, coded independently.

    Returns per band (Q, ...): TDOA std (N-1), azimuth std (N), elevation std (N), P_D.
    """
    tdoa_std, az_std, el_std, pd = [], [], [], []
    b, fs = config.bandwidth, config.sample_rate
    for f in config.band_centres:
        fk = f / 1000.0
        thorp = 0.11 * fk**2 / (1 + fk**2) + 44 * fk**2 / (4100 + fk**2) + 2.75e-4 * fk**2 + 0.003
        wind, thermal = 50 - 18 * math.log10(fk), -15 + 20 * math.log10(fk)
        power = 10 ** (wind / 10) + 10 ** (thermal / 10)
        if config.flow_noise_level is not None and current_speed > 0:
            # Ross: 60 log10(U / 1 m/s) - 20 log10(f / 1 kHz) on the reference level.
            flow = (config.flow_noise_level + 60 * math.log10(current_speed)
                    - 20 * math.log10(fk))
            power += 10 ** (flow / 10)
        noise = 10 * math.log10(power) + 10 * math.log10(b)
        snrs, t_std, a_std, e_std = [], [], [], []
        for h in hydrophones:
            d = np.asarray(position) - h
            r = math.sqrt(d @ d)
            snr = (config.source_level - (20 * math.log10(max(r, 1.0)) + thorp * r / 1000)
                   - noise + 10 * math.log10(b / fs))
            lin = 10 ** (snr / 10)
            beta = b / math.sqrt(12)
            t_std.append(config.noise_scale * math.hypot(
                config.timing_floor, 1 / (2 * math.pi * beta * math.sqrt(2 * lin))))
            theta = config.noise_scale * math.hypot(
                config.angle_floor,
                (config.sound_speed / f) / (2 * math.pi * config.aperture * math.sqrt(2 * lin)))
            polar = math.atan2(math.hypot(d[0], d[1]), d[2])
            a_std.append(theta / max(math.sin(polar), 0.05))
            e_std.append(theta)
            snrs.append(snr)
        tdoa_std.append([math.hypot(t, t_std[0]) for t in t_std[1:]])
        az_std.append(a_std)
        el_std.append(e_std)
        pd.append(1 / (1 + math.exp(-(np.mean(snrs) - config.snr50) / config.snr_slope)))
    return np.array(tdoa_std), np.array(az_std), np.array(el_std), np.array(pd)


def detections(obs, info, origin):
    """Per band, the detection with the given origin code (or None)."""
    out = []
    for q in range(obs["mask"].shape[0]):
        slots = np.flatnonzero(info["detection_origin"][q] == origin)
        assert len(slots) <= 1
        if len(slots):
            k = slots[0]
            assert obs["mask"][q, k] == 1
            out.append((obs["tdoa"][q, k], obs["azimuth"][q, k], obs["elevation"][q, k]))
        else:
            out.append(None)
    return out


@pytest.fixture(scope="module")
def noise_free_rollout():
    env = make(acoustic=AcousticConfig().noise_free(), time_limit=1.0)
    obs, info = env.reset(seed=3)
    steps = [(obs, info)]
    for _ in range(60):  # crosses a simulation block boundary
        obs, _, _, _, info = env.step(info["true_position"])
        steps.append((obs, info))
    cal = env.unwrapped.calibration
    env.close()
    return steps, cal


def test_noise_free_tdoa_and_doa_equal_the_geometry(noise_free_rollout):
    steps, cal = noise_free_rollout
    h, c = cal.hydrophone_positions, cal.sound_speed
    for obs, info in steps:
        tdoa, azimuth, elevation = geometric(info["true_position"], h, c)
        for found in detections(obs, info, ORIGIN_TARGET):
            assert found is not None  # ideal detection: every band hears the source
            np.testing.assert_allclose(found[0], tdoa, rtol=0, atol=1e-9)
            np.testing.assert_allclose(found[1], azimuth, rtol=0, atol=1e-12)
            np.testing.assert_allclose(found[2], elevation, rtol=0, atol=1e-12)


def test_multipath_ghosts_sit_at_the_mirror_images(noise_free_rollout):
    steps, cal = noise_free_rollout
    h, c, depth = cal.hydrophone_positions, cal.sound_speed, cal.tank_depth
    for obs, info in steps[::7]:
        x, y, z = info["true_position"]
        mirrors = {ORIGIN_SURFACE: (x, y, -z), ORIGIN_BOTTOM: (x, y, -2 * depth - z)}
        for origin, image in mirrors.items():
            tdoa, azimuth, elevation = geometric(image, h, c)
            for found in detections(obs, info, origin):
                assert found is not None
                np.testing.assert_allclose(found[0], tdoa, atol=1e-9)
                np.testing.assert_allclose(found[1], azimuth, atol=1e-12)
                np.testing.assert_allclose(found[2], elevation, atol=1e-12)
                # A surface ghost looks up at the mirror above the surface.
                if origin == ORIGIN_SURFACE:
                    assert np.all(found[2] < np.array(geometric((x, y, z), h, c)[2]) + 1e-12)


def test_noise_free_config_has_no_clutter(noise_free_rollout):
    steps, _ = noise_free_rollout
    for _obs, info in steps:
        assert not np.any(info["detection_origin"] == ORIGIN_CLUTTER)


def test_noise_statistics_match_the_documented_model():
    # Static source, P_D in mid-range (snr50 raised), clutter on: per band, the
    # empirical TDOA / azimuth / elevation spreads, detection rate and
    # false-alarm rate against the model of auv_envs.core.acoustics.
    # Small floors so that the SNR-dependent terms dominate the spreads.
    config = dataclasses.replace(AcousticConfig(), snr50=24.0, snr_slope=2.0, clutter_rate=0.7,
                                 timing_floor=5e-7, angle_floor=math.radians(0.01))
    env = make(acoustic=config, trajectory="static", static_point=4, disturbance="low",
               time_limit=60.0)
    obs, info = env.reset(seed=11)
    cal = env.unwrapped.calibration
    h, c = cal.hydrophone_positions, cal.sound_speed
    q_bands = config.n_bands
    residuals = {q: [] for q in range(q_bands)}
    hits = np.zeros(q_bands)
    clutter = np.zeros(q_bands)
    n = 0
    truncated = False
    while not truncated:
        tdoa, azimuth, elevation = geometric(info["true_position"], h, c)
        for q, found in enumerate(detections(obs, info, ORIGIN_TARGET)):
            if found is not None:
                hits[q] += 1
                d_az = (found[1] - azimuth + np.pi) % (2 * np.pi) - np.pi
                residuals[q].append(np.concatenate([found[0] - tdoa, d_az, found[2] - elevation]))
        clutter += (info["detection_origin"] == ORIGIN_CLUTTER).sum(axis=1)
        n += 1
        obs, _, _, truncated, info = env.step(info["true_position"])
    tdoa_std, az_std, el_std, pd = documented_model(config, h, info["true_position"])
    model = cal.array.model(info["true_position"])
    env.close()
    np.testing.assert_allclose(model["tdoa_std"], tdoa_std, rtol=1e-9)
    np.testing.assert_allclose(model["azimuth_std"], az_std, rtol=1e-9)
    np.testing.assert_allclose(model["elevation_std"], el_std, rtol=1e-9)
    np.testing.assert_allclose(model["detection_probability"], pd, rtol=1e-9)

    assert 0.05 < pd.min() and pd.max() < 0.99  # the check below is informative
    se = np.sqrt(pd * (1 - pd) / n)
    np.testing.assert_array_less(np.abs(hits / n - pd), 4.5 * se + 1e-3)
    # Poisson false alarms (none dropped at this rate: K = 8 slots).
    np.testing.assert_array_less(np.abs(clutter / n - 0.7), 4.5 * np.sqrt(0.7 / n))

    nodes = len(h)
    offsets = []
    for q in range(q_bands):
        r = np.array(residuals[q])
        m = len(r)
        expected = np.concatenate([tdoa_std[q], az_std[q], el_std[q]])
        ratio = r.std(axis=0) / expected
        # Std of a sample std is about sigma / sqrt(2 m); allow 5 of those per
        # component, and 5 of the pooled error for each quantity's mean ratio.
        assert np.all(np.abs(ratio - 1) < 5 / np.sqrt(2 * m)), (q, ratio)
        for part in (ratio[: nodes - 1], ratio[nodes - 1 : 2 * nodes - 1], ratio[2 * nodes - 1 :]):
            assert abs(part.mean() - 1) < 5 / np.sqrt(2 * m * len(part)), (q, part)
        offsets.append(r[:, : nodes - 1].mean(axis=0))
        assert np.all(np.abs(r[:, nodes - 1 :].mean(axis=0)) < 5 * expected[nodes - 1 :] /
                      np.sqrt(m))
    # Clock offsets: a per-node TDOA bias, the same in every band and not zero.
    offsets = np.array(offsets)
    spread = tdoa_std.max() / np.sqrt(min(len(residuals[q]) for q in residuals))
    assert np.all(np.abs(offsets - offsets.mean(axis=0)) < 6 * spread)
    assert np.abs(offsets.mean(axis=0)).max() > 10 * spread


def test_band_physics_absorption_and_noise():
    f = np.array(AcousticConfig().band_centres)
    assert np.all(np.diff(thorp_absorption(f)) > 0)
    # Thorp at 10 kHz is about 1.2 dB/km, at 100 kHz about 35 dB/km.
    assert thorp_absorption(10_000.0) == pytest.approx(1.19, abs=0.05)
    assert thorp_absorption(100_000.0) == pytest.approx(34.7, abs=1.0)
    assert np.all(np.diff(ambient_noise_level([1e3, 1e4, 3e4])) < 0)  # wind noise falls
    env = make()
    array = env.unwrapped.calibration.array
    env.close()
    near, far = array.model((30.0, 30.0, -8.0)), array.model((280.0, 280.0, -10.0))
    drop = near["snr_db"].mean(axis=1) - far["snr_db"].mean(axis=1)
    assert np.all(np.diff(drop) > 0)  # high bands fade faster with range
    assert np.all(far["tdoa_std"] > near["tdoa_std"])


def test_hydrophone_geometry_is_well_conditioned_over_the_work_area():
    env = make()
    cal = env.unwrapped.calibration
    env.close()
    h = cal.hydrophone_positions
    low, high = np.array(cal.work_area[0]), np.array(cal.work_area[1])
    grid = np.stack(np.meshgrid(*[np.linspace(a, b, 9) for a, b in zip(low, high, strict=True)],
                                indexing="ij"), -1).reshape(-1, 3)
    worst = 0.0
    for p in grid:
        u = (p - h) / np.linalg.norm(p - h, axis=1)[:, None]
        jac = u[1:] - u[0]  # d(range difference) / dp
        worst = max(worst, math.sqrt(np.trace(np.linalg.inv(jac.T @ jac))))
    # TDOA GDOP (position error per unit range-difference error); 8.95 measured.
    assert worst < 10.0


def test_static_points_and_disturbance_levels():
    deviation = {}
    for level, (lo, hi) in transition.DISTURBANCES.items():
        env = make(obs_mode="state", trajectory="static", static_point=2, disturbance=level,
                   time_limit=10.0)
        _, info = env.reset(seed=1)
        devs, speeds = [], []
        truncated = False
        while not truncated:
            _, _, _, truncated, info = env.step(info["true_position"])
            devs.append(np.linalg.norm(info["true_position"] - transition.STATIC_POINTS[1]))
            speeds.append(np.linalg.norm(info["current"]))
        env.close()
        assert lo - 1e-9 <= min(speeds) and max(speeds) <= hi + 1e-9
        deviation[level] = np.mean(devs)
    assert deviation["low"] < 0.1
    assert deviation["low"] < deviation["medium"] < deviation["high"] < 0.5


@pytest.mark.parametrize("point", range(1, 6))
def test_static_trajectory_holds_each_paper_point(point):
    env = make(obs_mode="state", trajectory="static", static_point=point, disturbance="low",
               time_limit=2.0)
    _, info = env.reset(seed=0)
    env.close()
    assert np.linalg.norm(info["true_position"] - transition.STATIC_POINTS[point - 1]) < 0.1


def test_routes_mix_straight_segments_curves_and_pauses():
    dt = 0.01
    for seed in range(20):
        reference, velocity = transition.plan_route(np.random.default_rng(seed), 6001, dt)
        speed = np.hypot(velocity[:, 0], velocity[:, 1])
        assert np.all(reference[:, :2] >= transition.ROUTE_XY[0])
        assert np.all(reference[:, :2] <= transition.ROUTE_XY[1])
        assert np.all((reference[:, 2] >= transition.ROUTE_Z[0]) &
                      (reference[:, 2] <= transition.ROUTE_Z[1]))
        # Positions integrate the velocities (no jumps) away from the limits.
        step = np.linalg.norm(np.diff(reference[:, :3], axis=0), axis=1)
        assert step.max() <= transition.CARRIER_SPEED[1] * dt * 1.5
        kinds = {"pause": speed == 0, "curve": (speed > 0) & (velocity[:, 3] != 0),
                 "straight": (speed > 0) & (velocity[:, 3] == 0)}
        for name, where in kinds.items():
            assert where.mean() > 0.02, (seed, name)


def test_oracle_and_biased_estimates_score_as_expected():
    env = make(obs_mode="state", time_limit=2.0)
    _, info = env.reset(seed=5)
    offset = np.array([0.3, 0.0, 0.4])  # 0.5 m error
    truncated = False
    while not truncated:
        _, reward, _, truncated, info = env.step(info["true_position"] + offset)
        assert info["estimate_error"] == pytest.approx(0.5, abs=1e-5)
        assert reward == pytest.approx(-0.5 / 5.0, abs=1e-5)
    m = info["episode_metrics"]
    env.close()
    assert m["steps"] == 200
    assert m["rmse"] == pytest.approx(0.5, abs=1e-5)
    assert m["max_error"] == pytest.approx(0.5, abs=1e-5)
    assert m["error_bias"] == pytest.approx(0.5, abs=1e-5)  # a constant offset is all bias
    assert m["tfc"] == 0 and m["success"] is False
    assert m["mean_ospa"] == pytest.approx(metrics.ospa([[0.0, 0.0, 0.0]], [offset], 5.0, 1.0),
                                           abs=1e-5)


def test_lost_and_reacquired_track_counts_one_fragmentation():
    env = make(obs_mode="state", time_limit=1.0)
    _, info = env.reset(seed=2)
    truncated = False
    k = 0
    while not truncated:
        lost = 30 <= k < 50
        _, _, _, truncated, info = env.step(info["true_position"] + (3.0 if lost else 0.0))
        assert info["tracked"] is (not lost)
        k += 1
    env.close()
    assert info["episode_metrics"]["tfc"] == 1


def test_measurement_observations_hide_which_detection_is_the_source():
    env = make(time_limit=5.0)
    obs, info = env.reset(seed=0)
    slots = []
    for _ in range(200):
        for q in range(obs["mask"].shape[0]):
            slots.extend(np.flatnonzero(info["detection_origin"][q] == ORIGIN_TARGET))
        obs, _, _, _, info = env.step(info["true_position"])
    env.close()
    counts = np.bincount(slots, minlength=4)
    assert np.count_nonzero(counts) >= 3  # the source appears in several slots


def test_bad_acoustic_arguments():
    with pytest.raises(ValueError, match="static_point"):
        make(trajectory="static", static_point=6)
    with pytest.raises(ValueError, match="'low', 'medium', 'high'"):
        make(disturbance="storm")
    with pytest.raises(TypeError, match="AcousticConfig"):
        make(acoustic={"sound_speed": 1500})
    with pytest.raises(ValueError, match="sound_speed"):
        AcousticConfig(sound_speed=-1.0)
    with pytest.raises(ValueError, match="time_limit"):
        make(time_limit=float("nan"))
    env = make()
    with pytest.raises(ValueError, match="positions"):
        env.unwrapped.calibration.array.measure(np.random.default_rng(0), [[np.nan, 0, 0]],
                                                np.zeros(8), xp=np)
    env.close()


def test_tcfe_order_two_hand_worked():
    # Steps 0, 0, 1, 0, 0 -> second differences 0, 1, -1, 0: two in bin 0, two in bin 1.
    x = np.array([[0.0], [0.0], [0.0], [1.0], [1.0], [1.0]])
    assert metrics.tcfe(x, bin_width=1.0, order=2) == pytest.approx(math.log(2))
    # Constant acceleration: steps 0.5, 1.5, 2.5 span bins 0-2; second differences all 1.
    y = 0.5 * np.arange(4.0)[:, None] ** 2
    assert metrics.tcfe(y, bin_width=1.0) == pytest.approx(math.log(3))
    assert metrics.tcfe(y, bin_width=1.0, order=2) == 0.0
    with pytest.raises(ValueError, match="at least three"):
        metrics.tcfe(x[:2], order=2)
    with pytest.raises(ValueError, match="order"):
        metrics.tcfe(x, order=3)


def test_episode_tcfe_fluctuation_scores_the_estimate_not_the_motion():
    """The truth as the estimate scores 0 on ``tcfe_fluctuation``; 1 cm white jitter on it
    scores well above 0; ``tcfe`` is [GMPHD]'s first-difference reading of the same data."""
    rng = np.random.default_rng(0)
    scores, sent = {}, {}
    for name, jitter in (("truth", 0.0), ("jitter", 0.01)):
        env = make(obs_mode="state", time_limit=3.0, disturbance="high")
        _, info = env.reset(seed=1)
        truncated, actions = False, []
        while not truncated:
            actions.append((info["true_position"] + rng.normal(0.0, jitter, 3))
                           .astype(np.float32))
            _, _, _, truncated, info = env.step(actions[-1])
        scores[name], sent[name] = info["episode_metrics"], np.array(actions, np.float64)
        env.close()
    assert scores["truth"]["tcfe_fluctuation"] == 0.0
    assert scores["jitter"]["tcfe_fluctuation"] > 1.0
    for name, m in scores.items():
        assert m["tcfe"] == pytest.approx(metrics.tcfe(sent[name]))
        assert m["tcfe_fluctuation"] == pytest.approx(metrics.tcfe(sent[name], order=2))


# --------------------------------------------------------------------------- flow noise

FLOW = AcousticConfig(flow_noise_level=GMPHD_FLOW_NOISE_LEVEL)


def test_flow_noise_model_matches_the_documented_formula():
    env = make(acoustic=FLOW)
    cal = env.unwrapped.calibration
    env.close()
    h, p = cal.hydrophone_positions, np.array([150.0, 150.0, -15.0])
    for speed in (0.0, 0.1, 0.3, 0.5):
        model = cal.array.model(p, current_speed=speed)
        tdoa_std, az_std, el_std, pd = documented_model(FLOW, h, p, speed)
        np.testing.assert_allclose(model["tdoa_std"], tdoa_std, rtol=1e-9)
        np.testing.assert_allclose(model["azimuth_std"], az_std, rtol=1e-9)
        np.testing.assert_allclose(model["detection_probability"], pd, rtol=1e-9)
    # At rest the flow model is the calm one; the noise rise follows 60 log10 U
    # once the flow dominates (a doubling adds 18.06 dB) and hits low bands hardest.
    calm = make().unwrapped.calibration.array
    assert calm.model(p)["snr_db"] == pytest.approx(cal.array.model(p, 0.0)["snr_db"], abs=0)
    rise = cal.array.flow_noise_rise([0.0, 0.5, 4.0, 8.0], np)
    assert np.all(rise[0] == 0) and np.all(np.diff(rise[1]) < 0)
    np.testing.assert_allclose(rise[3] - rise[2], 60 * math.log10(2), atol=1e-3)
    flow = flow_noise_level(cal.band_centres, 0.5, GMPHD_FLOW_NOISE_LEVEL)
    np.testing.assert_allclose(
        rise[1], 10 * np.log10(1 + 10 ** ((flow - ambient_noise_level(cal.band_centres)) / 10)))
    # No flow-noise level: nothing rises whatever the current.
    assert np.all(calm.flow_noise_rise(0.5, np) == 0)


def test_flow_noise_statistics_in_measure():
    # Many periods at one position and a strong current: detection rate and TDOA
    # spread per band against the documented model at that speed.
    env = make(acoustic=dataclasses.replace(FLOW, clock_offset_std=0.0, multipath=False,
                                            clutter_rate=0.0))
    array = env.unwrapped.calibration.array
    env.close()
    p, speed, n = np.array([200.0, 120.0, -12.0]), 0.4, 3000
    m = array.measure(np.random.default_rng(5), np.tile(p, (n, 1)), np.zeros(8), speed, xp=np)
    model = array.model(p, speed)
    pd = model["detection_probability"]
    assert 0.05 < pd.min() and pd.max() < 0.999  # informative
    hits = m.mask.sum(axis=-1)  # (n, Q): the source is the only possible detection
    np.testing.assert_array_less(np.abs(hits.mean(axis=0) - pd),
                                 4.5 * np.sqrt(pd * (1 - pd) / n) + 1e-3)
    truth = geometric(p, array.positions, array.config.sound_speed)[0]
    for q in range(array.config.n_bands):
        found = m.tdoa[:, q][m.mask[:, q].astype(bool)]
        ratio = (found - truth).std(axis=0) / model["tdoa_std"][q]
        assert np.all(np.abs(ratio - 1) < 5 / np.sqrt(2 * len(found))), (q, ratio)


def test_flow_noise_needs_the_current_and_checks_it():
    env = make(acoustic=FLOW)
    array = env.unwrapped.calibration.array
    env.close()
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="current_speed"):
        array.measure(rng, [100.0, 100.0, -10.0], np.zeros(8), xp=np)
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="current_speed"):
            array.measure(rng, [100.0, 100.0, -10.0], np.zeros(8), bad, xp=np)
    for bad in (float("inf"), True, "94"):
        with pytest.raises(ValueError, match="flow_noise_level"):
            AcousticConfig(flow_noise_level=bad)
    # Without flow noise the current is ignored: the same draws either way.
    calm = make().unwrapped.calibration.array
    a = calm.measure(np.random.default_rng(1), [100.0, 100.0, -10.0], np.zeros(8), xp=np)
    b = calm.measure(np.random.default_rng(1), [100.0, 100.0, -10.0], np.zeros(8), 0.5, xp=np)
    assert all(np.array_equal(getattr(a, f.name), getattr(b, f.name))
               for f in dataclasses.fields(a))


def test_env_flow_noise_follows_the_episode_current():
    # The env measures with the current of each sample period: over a high-current
    # episode the source detections per band match the model's P_D summed over the
    # steps at the logged current speeds; the physics (state observation) is the
    # calm episode's, bit for bit.
    kwargs = dict(disturbance="high", time_limit=8.0)
    env = make(obs_mode="measurements", acoustic=FLOW, **kwargs)
    state_env = make(obs_mode="state", acoustic=FLOW, **kwargs)
    calm_env = make(obs_mode="state", **kwargs)
    obs, info = env.reset(seed=7)
    states = [state_env.reset(seed=7)[0]]
    calm_states = [calm_env.reset(seed=7)[0]]
    array = env.unwrapped.calibration.array
    hits, expected, variance = 0.0, 0.0, 0.0
    truncated = False
    while not truncated:
        speed = float(np.linalg.norm(info["current"]))
        pd = array.model(info["true_position"], speed)["detection_probability"]
        hits += (info["detection_origin"] == ORIGIN_TARGET).sum(axis=1)
        expected += pd
        variance += pd * (1 - pd)
        action = info["true_position"]
        obs, _, _, truncated, info = env.step(action)
        states.append(state_env.step(action)[0])
        calm_states.append(calm_env.step(action)[0])
    for e in (env, state_env, calm_env):
        e.close()
    assert np.array_equal(np.array(states), np.array(calm_states))
    assert expected.min() < 0.8 * len(states)  # the flow noise costs detections here
    np.testing.assert_array_less(np.abs(hits - expected), 4.5 * np.sqrt(variance) + 1)
