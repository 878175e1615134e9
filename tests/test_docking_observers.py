"""[OFNMPC] observers: EKF = Kalman filter on a linear model, the visual model and its
Jacobian, and the MHE recovering the state from a noise-free sequence."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from baselines.docking.estimation.observers import (
    DockingEKF,
    DockingMHE,
    ExtendedKalmanFilter,
    MHEConfig,
    VisualObservationModel,
)
from tests.conftest import DOCKING_IDS, make_env


@pytest.fixture(scope="module", params=DOCKING_IDS)
def calibration(request):
    env = make_env(request.param, "features")
    yield env.unwrapped.calibration
    env.close()


def _kalman_filter(x, p, a, b, q, h, r, inputs, measurements):
    """Textbook Kalman filter (standard-form covariance update), the oracle."""
    means = []
    for u, z in zip(inputs, measurements, strict=True):
        x = a @ x + b @ u
        p = a @ p @ a.T + q
        s = h @ p @ h.T + r
        k = p @ h.T @ np.linalg.inv(s)
        x = x + k @ (z - h @ x)
        p = (np.eye(len(x)) - k @ h) @ p
        means.append((x.copy(), p.copy()))
    return means


def test_ekf_on_linear_gaussian_model_equals_kalman_filter():
    rng = np.random.default_rng(0)
    n, m, nz = 5, 2, 3
    a = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    b = rng.normal(size=(n, m))
    h = rng.normal(size=(nz, n))
    q = np.diag(rng.uniform(0.01, 0.1, n))
    r = np.diag(rng.uniform(0.1, 1.0, nz))
    xs, us = ca.SX.sym("x", n), ca.SX.sym("u", m)
    f = ca.DM(a) @ xs + ca.DM(b) @ us
    transition = ca.Function("f", [xs, us], [f, ca.jacobian(f, xs)])
    ekf = ExtendedKalmanFilter(transition, q)
    x0, p0 = rng.normal(size=n), np.eye(n)
    ekf.initialise(x0, p0)
    inputs = rng.normal(size=(30, m))
    measurements = rng.normal(size=(30, nz))
    oracle = _kalman_filter(x0, p0, a, b, q, h, r, inputs, measurements)
    for u, z, (x_ref, p_ref) in zip(inputs, measurements, oracle, strict=True):
        ekf.predict(u)
        ekf.update(z - h @ ekf.mean, h, r)
        np.testing.assert_allclose(ekf.mean, x_ref, rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(ekf.cov, p_ref, rtol=1e-10, atol=1e-12)


def test_visual_jacobian_matches_finite_differences(calibration):
    model = VisualObservationModel(calibration)
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = np.array([rng.uniform(-10, -2), rng.uniform(-1, 1), rng.uniform(-0.5, 0.5),
                      rng.uniform(-0.3, 0.3), *rng.normal(0, 0.3, 4)])
        attitude = rng.normal(0, 0.05, 2)
        _, jac = model.evaluate(x, attitude)
        numeric = np.zeros_like(jac)
        for i in range(len(x)):
            step = np.zeros(len(x))
            step[i] = 1e-6
            hi, _ = model.evaluate(x + step, attitude)
            lo, _ = model.evaluate(x - step, attitude)
            numeric[:, i] = (hi - lo) / 2e-6
        np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-5)


@pytest.mark.parametrize("env_id", DOCKING_IDS)
def test_visual_model_reproduces_the_env_camera(env_id):
    """The observers' projection is the env's projection (same pixels for the true pose)."""
    env = make_env(env_id, "features")
    try:
        model = VisualObservationModel(env.unwrapped.calibration)
        _, info = env.reset(seed=3)
        for _ in range(5):
            _, _, _, _, info = env.step(np.array([0.5, 0.2, -0.3, 0.3], dtype=np.float32))
        pos, euler, vel = info["true_position"], info["true_euler"], info["true_velocity"]
        x = np.concatenate([pos, [euler[2]], vel[[0, 1, 2, 5]]])
        h, _ = model.evaluate(x, euler[:2])
        visible = info["true_visible"]
        assert visible.sum() >= 3
        pixels = h[: 2 * model.n_lights].reshape(-1, 2)
        np.testing.assert_allclose(pixels[visible], info["true_pixels"][visible], atol=1e-6)
    finally:
        env.close()


def _features(model: VisualObservationModel, x, visible) -> dict:
    h, _ = model.evaluate(x, np.zeros(2))
    pixels = h[: 2 * model.n_lights].reshape(-1, 2)
    return {
        "pixels": np.where(visible[:, None], pixels, 0.0).astype(np.float32),
        "visible": visible.astype(np.int8),
        "velocity": np.asarray(x[4:8], dtype=np.float32),
        "attitude": np.array([0.0, 0.0, x[3]], dtype=np.float32),
    }


def _nominal_sequence(calibration, force, steps, seed=0):
    """States of the nominal model driven by known inputs plus a constant unmodelled force."""
    rng = np.random.default_rng(seed)
    model = calibration.nominal_model
    x = np.array([-6.0, 0.4, -0.2, 0.1, 0.3, 0.0, 0.0, 0.0])
    states, inputs = [x], []
    for _ in range(steps):
        tau = rng.uniform(-20.0, 20.0, 4)
        x = model.step(x, tau, calibration.control_period, d=force, ops=np)
        states.append(x)
        inputs.append(tau)
    return states, inputs


@pytest.mark.parametrize("observer", ["mhe", "ekf"])
def test_observer_recovers_state_and_force_from_noise_free_sequence(calibration, observer):
    """Noise-free data of the nominal model with an unmodelled constant force: the
    estimate converges to the true state and the disturbance to the force. One light
    is hidden half of the time (only visible pixels may enter the update)."""
    force = np.array([8.0, -6.0, 5.0, 2.0])
    states, inputs = _nominal_sequence(calibration, force, steps=60)
    if observer == "mhe":
        est = DockingMHE(calibration, MHEConfig(horizon=10))
    else:
        est = DockingEKF(calibration)
    visual = est.visual
    n = visual.n_lights
    tau_prev = np.zeros(4)
    for k, x in enumerate(states):
        visible = np.ones(n, dtype=bool)
        visible[k % n] = k % 2 == 0
        estimate = est.step(_features(visual, x, visible), tau_prev)
        tau_prev = inputs[k] if k < len(inputs) else tau_prev
    # The MHE fits the window exactly; the EKF's estimate of the random-walk
    # disturbance converges more slowly.
    state_tol, force_tol = (1e-5, 1e-3) if observer == "mhe" else (1e-4, 1e-2)
    np.testing.assert_allclose(estimate.state, states[-1], atol=state_tol)
    np.testing.assert_allclose(estimate.disturbance, force, atol=force_tol)
    if observer == "mhe":
        assert est.failures == 0


def test_observers_wait_until_two_lights_are_visible(calibration):
    ekf = DockingEKF(calibration)
    x = np.array([-6.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0, 0.0])
    one = np.zeros(ekf.visual.n_lights, dtype=bool)
    one[0] = True
    assert ekf.step(_features(ekf.visual, x, one), np.zeros(4)) is None
    assert not ekf.initialised
    every = np.ones(ekf.visual.n_lights, dtype=bool)
    estimate = ekf.step(_features(ekf.visual, x, every), np.zeros(4))
    np.testing.assert_allclose(estimate.state[:4], x[:4], atol=1e-4)


def test_malformed_features_are_rejected(calibration):
    ekf = DockingEKF(calibration)
    x = np.array([-6.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0, 0.0])
    obs = _features(ekf.visual, x, np.ones(ekf.visual.n_lights, dtype=bool))
    with pytest.raises(ValueError, match="pixels"):
        ekf.step({**obs, "pixels": obs["pixels"][:2]}, np.zeros(4))
    with pytest.raises(ValueError, match="non-finite"):
        ekf.step({**obs, "velocity": np.array([np.nan, 0, 0, 0])}, np.zeros(4))
    # A visible light with non-finite pixels is treated as not visible.
    broken = obs["pixels"].copy()
    broken[0] = np.nan
    estimate = ekf.step({**obs, "pixels": broken}, np.zeros(4))
    assert np.isfinite(estimate.state).all()
    np.testing.assert_allclose(estimate.state[:4], x[:4], atol=1e-4)


def test_a_pose_fit_running_off_along_the_bearing_is_skipped():
    """Two lights 16 px apart with centroid noise (``hard`` water, seed 620001, step 13):
    least squares ran the range off to 2e8 m, which then hung the NMPC's solver. The
    fit must put the lights in front of the camera within MAX_LIGHT_RANGE, or the
    observer waits; the next frame with a clean view initialises it."""
    env = make_env(DOCKING_IDS[0], "features")
    ekf = DockingEKF(env.unwrapped.calibration)
    env.close()
    pixels = np.zeros((6, 2), dtype=np.float32)
    pixels[4], pixels[5] = (460.2124, 273.4857), (451.6647, 287.0197)
    frame = {"pixels": pixels, "visible": np.array([0, 0, 0, 0, 1, 1], dtype=np.int8),
             "velocity": np.array([0.2127, -0.0081, 0.0457, 0.0221], dtype=np.float32),
             "attitude": np.array([0.00077, 0.00557, 0.24309], dtype=np.float32)}
    assert ekf.step(frame, np.zeros(4)) is None
    assert not ekf.initialised
    x = np.array([-10.0, 0.5, 0.2, 0.24, 0.2, 0.0, 0.0, 0.0])
    estimate = ekf.step(_features(ekf.visual, x, np.ones(6, dtype=bool)), np.zeros(4))
    np.testing.assert_allclose(estimate.state[:4], x[:4], atol=1e-3)
