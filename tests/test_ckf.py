"""The cubature Kalman filter and [LTAT]'s motion model (baselines/lars/estimation/ckf.py)."""

import datetime
import math

import numpy as np
import pytest

from baselines.lars.estimation.ckf import (
    CubatureKalmanFilter,
    HeaveSurgeModel,
    covariance_root,
    cubature_points,
    fit_heave,
    position_measurement,
    white_acceleration_noise,
)


def kf_step(transition, f, h, q, r, x, p, z):
    """One textbook Kalman filter step (predict, then update with ``z``).

    ``transition`` maps the mean (``f @ x``, or an affine ``f @ x + b``); the
    covariance is predicted with ``f`` either way.
    """
    x, p = transition(x), f @ p @ f.T + q
    s = h @ p @ h.T + r
    k = p @ h.T @ np.linalg.inv(s)
    return x + k @ (z - h @ x), p - k @ s @ k.T


def kalman_reference(f, h, q, r, x, p, zs):
    """The textbook Kalman filter over measurements ``zs``: (mean, covariance) after each."""
    out = []
    for z in zs:
        x, p = kf_step(lambda v: f @ v, f, h, q, r, x, p, z)
        out.append((x.copy(), p.copy()))
    return out


def test_cubature_points_match_mean_and_covariance():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T + 0.1 * np.eye(6)
    mean = rng.normal(size=6)
    pts = cubature_points(mean, cov)
    assert pts.shape == (12, 6)
    np.testing.assert_allclose(pts.mean(axis=0), mean, atol=1e-12)
    dev = pts - mean
    np.testing.assert_allclose(dev.T @ dev / 12, cov, atol=1e-12)


def test_equals_kalman_filter_on_linear_gaussian_model():
    rng = np.random.default_rng(1)
    model = HeaveSurgeModel(dt=0.04, omega=0.9, z_mean=-0.05)
    q = white_acceleration_noise(0.04, (0.05, 0.02, 0.1))
    h = np.hstack((np.eye(3), np.zeros((3, 3))))
    x0 = np.array([0.1, 2.0, -0.1, 0.05, 0.0, 0.1])
    p0 = np.diag([0.01, 0.01, 0.01, 0.04, 0.04, 0.04])
    ckf = CubatureKalmanFilter(model, position_measurement, q, np.eye(3))
    ckf.initialise(x0, p0)
    zs, rs = rng.normal(size=(60, 3)) * 0.02 + x0[:3], []
    for _ in zs:
        a = rng.normal(size=(3, 3)) * 0.01
        rs.append(a @ a.T + 1e-4 * np.eye(3))
    x, p = x0.copy(), p0.copy()
    for z, r in zip(zs, rs, strict=True):
        ckf.predict()
        assert ckf.update(z, r)
        x, p = kf_step(model, model.matrix, h, q, r, x, p, z)
        np.testing.assert_allclose(ckf.mean, x, atol=1e-9, rtol=0)
        np.testing.assert_allclose(ckf.covariance, p, atol=1e-9, rtol=0)


def test_equals_kalman_filter_random_linear_model():
    rng = np.random.default_rng(2)
    n, m = 4, 2
    f = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    h = rng.normal(size=(m, n))
    a = rng.normal(size=(n, n))
    q = 0.01 * a @ a.T
    r = 0.05 * np.eye(m)
    x0, p0 = rng.normal(size=n), np.eye(n)
    zs = rng.normal(size=(40, m))
    ckf = CubatureKalmanFilter(lambda s: s @ f.T, lambda s: s @ h.T, q, r)
    ckf.initialise(x0, p0)
    for z, (x, p) in zip(zs, kalman_reference(f, h, q, r, x0, p0, zs), strict=True):
        ckf.predict()
        ckf.update(z)
        np.testing.assert_allclose(ckf.mean, x, atol=1e-9, rtol=0)
        np.testing.assert_allclose(ckf.covariance, p, atol=1e-9, rtol=0)


def _range_product_sensor():
    """A nonlinear Stone Soup sensor without angles (range and a scaled x*y product).

    Angles are avoided on purpose: Stone Soup averages bearings as circular
    quantities, a different (equally valid) definition of the mean.
    """
    from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement
    from stonesoup.types.array import StateVector, StateVectors

    class RangeProduct(NonLinearGaussianMeasurement):
        @property
        def ndim_meas(self):
            return 2

        def function(self, state, noise=False, **kwargs):
            vec = np.asarray(state.state_vector, dtype=float)
            x, y = vec[self.mapping[0], :], vec[self.mapping[1], :]
            out = np.vstack((np.hypot(x, y), x * y / 50.0))
            return StateVector(out) if out.shape[1] == 1 else StateVectors(out)

    return RangeProduct(ndim_state=5, mapping=(0, 2), noise_covar=np.diag([0.3**2, 0.5**2]))


def test_agrees_with_stone_soup_cubature_filter_on_nonlinear_model():
    from stonesoup.models.transition.nonlinear import ConstantTurn
    from stonesoup.predictor.kalman import CubatureKalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState, State
    from stonesoup.updater.kalman import CubatureKalmanUpdater

    dt = datetime.timedelta(seconds=0.5)
    transition = ConstantTurn(linear_noise_coeffs=np.array([0.1, 0.1]), turn_noise_coeff=0.01)
    sensor = _range_product_sensor()

    def f(points):
        return np.array([transition.function(State(p[:, None]), time_interval=dt).ravel()
                         for p in points])

    def h(points):
        return np.array([np.asarray(sensor.function(State(p[:, None])), float).ravel()
                         for p in points])

    # state (x, vx, y, vy, turn rate); the turn makes f nonlinear, h is nonlinear too
    x0 = np.array([50.0, 1.0, 30.0, 2.0, 0.1])
    p0 = np.diag([4.0, 0.5, 4.0, 0.5, 0.01])
    q = transition.covar(time_interval=dt)
    ckf = CubatureKalmanFilter(f, h, q, sensor.covar())
    ckf.initialise(x0, p0)

    start = datetime.datetime(2024, 1, 1)
    prior = GaussianState(x0[:, None], p0, timestamp=start)
    predictor = CubatureKalmanPredictor(transition)
    updater = CubatureKalmanUpdater(sensor)
    truth = x0.copy()
    rng = np.random.default_rng(3)
    for k in range(1, 16):
        truth = f(truth[None])[0]
        z = h(truth[None])[0] + rng.normal(size=2) * (0.3, 0.5)
        when = start + k * dt
        pred = predictor.predict(prior, timestamp=when)
        det = Detection(z[:, None], timestamp=when, measurement_model=sensor)
        prior = updater.update(SingleHypothesis(pred, det))
        ckf.predict()
        ckf.update(z)
        np.testing.assert_allclose(ckf.mean, np.asarray(prior.state_vector, float).ravel(),
                                   rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ckf.covariance, np.asarray(prior.covar, float),
                                   rtol=1e-7, atol=1e-9)
    # the filter moved well away from its prior: the comparison is not vacuous
    assert np.linalg.norm(ckf.mean[[0, 2]] - x0[[0, 2]]) > 5.0


def test_gate_rejects_outlier_and_keeps_estimate():
    model = HeaveSurgeModel(dt=0.04, omega=1.0)
    ckf = CubatureKalmanFilter(model, position_measurement,
                               white_acceleration_noise(0.04, 0.05), 1e-4 * np.eye(3))
    ckf.initialise(np.zeros(6), 1e-4 * np.eye(6))
    ckf.predict()
    mean, cov = ckf.mean.copy(), ckf.covariance.copy()
    assert not ckf.update(np.array([1.0, 0.0, 0.0]), gate=16.0)
    assert ckf.last_nis > 16.0
    np.testing.assert_array_equal(ckf.mean, mean)
    np.testing.assert_array_equal(ckf.covariance, cov)
    assert ckf.update(np.array([0.005, 0.0, 0.0]), gate=16.0)


def test_bad_input_raises():
    q = white_acceleration_noise(0.04, 0.05)
    ckf = CubatureKalmanFilter(HeaveSurgeModel(0.04, 1.0), position_measurement, q, np.eye(3))
    with pytest.raises(RuntimeError, match="initialise"):
        ckf.predict()
    with pytest.raises(ValueError, match="mean"):
        ckf.initialise(np.zeros(5), np.eye(6))
    with pytest.raises(ValueError, match="non-finite"):
        ckf.initialise(np.full(6, np.nan), np.eye(6))
    ckf.initialise(np.zeros(6), np.eye(6))
    with pytest.raises(ValueError, match="non-finite"):
        ckf.update(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="noise"):
        ckf.update(np.zeros(3), np.eye(2))
    with pytest.raises(ValueError, match="square"):
        CubatureKalmanFilter(HeaveSurgeModel(0.04, 1.0), position_measurement, np.eye(6)[:3],
                             np.eye(3))
    with pytest.raises(ValueError, match="omega"):
        HeaveSurgeModel(0.04, 0.0)
    with pytest.raises(ValueError, match="discretisation"):
        HeaveSurgeModel(0.04, 1.0, discretisation="rk4")


def test_covariance_root_falls_back_on_semidefinite():
    p = np.diag([1.0, 0.0, 2.0])
    p[1, 1] = -1e-18  # round-off below zero
    s = covariance_root(p)
    np.testing.assert_allclose(s @ s.T, np.diag([1.0, 0.0, 2.0]), atol=1e-12)
    with pytest.raises(ValueError, match="non-finite"):
        covariance_root(np.full((2, 2), np.inf))


def test_exact_model_follows_the_sinusoid():
    omega, amp, zbar, dt = 0.8, 0.2, -0.05, 0.04
    model = HeaveSurgeModel(dt, omega, zbar)
    state = np.array([0.0, 2.0, zbar, 0.1, 0.0, amp * omega])  # z = zbar + A sin(w t)
    for k in range(1, 200):
        state = model(state)
        t = k * dt
        np.testing.assert_allclose(state, [0.1 * t, 2.0, zbar + amp * math.sin(omega * t), 0.1,
                                           0.0, amp * omega * math.cos(omega * t)], atol=1e-12)
    p, v, a = model.kinematics(state, 1.3)
    t = 199 * dt + 1.3
    np.testing.assert_allclose(p, [0.1 * t, 2.0, zbar + amp * math.sin(omega * t)], atol=1e-12)
    np.testing.assert_allclose(v[2], amp * omega * math.cos(omega * t), atol=1e-12)
    np.testing.assert_allclose(a[2], -amp * omega**2 * math.sin(omega * t), atol=1e-12)


def test_euler_form_is_first_order_of_exact():
    exact = HeaveSurgeModel(0.04, 1.1, 0.3)
    euler = HeaveSurgeModel(0.04, 1.1, 0.3, discretisation="euler")
    state = np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.2])
    gap = np.abs(exact(state) - euler(state)).max()
    assert 0 < gap < (1.1 * 0.04) ** 2


def test_fit_heave_recovers_frequency_and_level():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 6.0, 0.04)
    z = -0.05 + 0.2 * np.sin(0.9 * t + 1.0) + rng.normal(0.0, 0.01, t.size)
    fit = fit_heave(t, z)
    assert abs(fit.omega - 0.9) < 0.02
    assert abs(fit.mean + 0.05) < 0.01
    assert abs(fit.amplitude - 0.2) < 0.01
    assert fit.rms < 0.012
    with pytest.raises(ValueError, match=">= 4"):
        fit_heave(t[:3], z[:3])
    with pytest.raises(ValueError, match="finite"):
        fit_heave(t, np.where(t > 1, np.nan, z))
