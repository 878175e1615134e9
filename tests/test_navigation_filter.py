"""The mission's navigation filter against a Kalman filter (Stone Soup's) on a
linear-Gaussian case, its late-fix update, its gate, and the hand-over logic."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.docking.estimation.navigation_filter import USBL_GATE, NavigationFilter

TRANSPONDER = np.array([0.5, 0.0, 1.0])
SURFACE = 50.0


def _stone_soup_kalman(steps, velocities, depths, fixes, filt: NavigationFilter):
    """The same estimation problem through Stone Soup's KalmanPredictor/KalmanUpdater:
    state p (3), x_k = x_{k-1} + dt v_k + w (Q as the filter's at zero attitude), depth
    z = s - p_z and a fix y = t - p (zero attitude) as linear measurements."""
    from stonesoup.models.control.linear import LinearControlModel
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState, State
    from stonesoup.updater.kalman import KalmanUpdater

    params = filt.params
    dt = params.dt
    q = dt**2 * params.dvl_var * np.eye(3) + params.random_walk * np.eye(3)
    transition = _Identity(q)
    control = LinearControlModel(control_matrix=dt * np.eye(3),
                                 control_noise=np.zeros((3, 3)))
    predictor = KalmanPredictor(transition, control_model=control)
    state = GaussianState(StateVector(np.zeros(3)),
                          CovarianceMatrix(np.eye(3) * params.initial_var))
    out = []
    for k in range(steps):
        state = predictor.predict(state, control_input=State(StateVector(velocities[k])))
        # Depth: d - s = -p_z, a linear measurement of p.
        depth_model = LinearGaussian(3, [2], np.array([[params.depth_var]]))
        hyp = SingleHypothesis(state, Detection(StateVector([SURFACE - depths[k]]),
                                                measurement_model=depth_model))
        state = KalmanUpdater(depth_model).update(hyp)
        if fixes[k] is not None:
            fix, variance = fixes[k]
            usbl_model = LinearGaussian(3, [0, 1, 2], variance * np.eye(3))
            hyp = SingleHypothesis(state, Detection(StateVector(TRANSPONDER - fix),
                                                    measurement_model=usbl_model))
            state = KalmanUpdater(usbl_model).update(hyp)
        out.append((np.asarray(state.state_vector, dtype=float).ravel(),
                    np.asarray(state.covar, dtype=float)))
    return out


class _Identity:
    """A linear transition model x_k = x_{k-1} + w for Stone Soup (its protocol)."""

    def __init__(self, q):
        from stonesoup.models.transition.linear import LinearGaussianTransitionModel

        class Model(LinearGaussianTransitionModel):
            @property
            def ndim_state(self):
                return 3

            def matrix(self, **kwargs):
                return np.eye(3)

            def covar(self, **kwargs):
                return q

        self.model = Model()

    def __getattr__(self, name):
        return getattr(self.model, name)


def _observation(velocity, depth, fix=None, age=0.0):
    return {"attitude": np.zeros(3), "rates": np.zeros(3),
            "dvl_velocity": np.asarray(velocity, np.float64), "dvl_valid": np.array([1]),
            "depth": np.array([depth]), "usbl": np.zeros(3) if fix is None else fix,
            "usbl_age": np.array([age]), "usbl_valid": np.array([int(fix is not None)])}


def test_equals_a_kalman_filter_on_a_linear_gaussian_case():
    """Level attitude, fixes without latency: the error-state filter is a Kalman filter on
    the position; it matches Stone Soup's to round-off, step by step."""
    pytest.importorskip("stonesoup")
    rng = np.random.default_rng(3)
    filt = NavigationFilter(TRANSPONDER, SURFACE, 0.1, usbl_std=(0.3, 0.0), initial_std=100.0)
    steps = 60
    truth = np.array([-40.0, 5.0, 2.0])
    velocities, depths, fixes = [], [], []
    for k in range(steps):
        v = np.array([0.8, -0.1, 0.02]) + 0.02 * rng.standard_normal(3)
        truth = truth + 0.1 * v
        velocities.append(v)
        depths.append(SURFACE - truth[2] + 0.014 * rng.standard_normal())
        fix = None
        if k % 10 == 9:
            fix = (TRANSPONDER - truth + 0.3 * rng.standard_normal(3), 0.3**2)
        fixes.append(fix)
    reference = _stone_soup_kalman(steps, velocities, depths, fixes, filt)
    for k in range(steps):
        obs = _observation(velocities[k], depths[k], None if fixes[k] is None else fixes[k][0])
        estimate = filt.step(obs)
        np.testing.assert_allclose(estimate, reference[k][0], rtol=0, atol=1e-9)
        # Round-off of two update formulas after a 1e4 m^2 prior: 1e-16 of it.
        np.testing.assert_allclose(filt.P, reference[k][1], rtol=1e-9, atol=1e-11)
    assert filt.fixes == 6 and filt.rejected == 0


def test_late_fix_updates_through_the_state_at_its_ping():
    """A fix measured one step ago (``usbl_age`` 0.1 s) is compared with the estimate then:
    the vehicle has moved on 0.1 m since, and the estimate now is where it is. The same fix
    taken as current leaves the estimate 0.1 m behind."""
    velocity = np.array([1.0, 0.0, 0.0])
    start = np.array([-30.0, 2.0, 0.0])
    first = start + 0.1 * velocity  # the vehicle after the first step, when the fix was made
    fix = TRANSPONDER - first
    estimates = {}
    for age in (0.1, 0.0):
        filt = NavigationFilter(TRANSPONDER, SURFACE, 0.1, usbl_std=(0.01, 0.0))
        filt.step(_observation(velocity, SURFACE))
        estimates[age] = filt.step(_observation(velocity, SURFACE, fix, age=age))
        assert filt.fixes == 1
    np.testing.assert_allclose(estimates[0.1], first + 0.1 * velocity, atol=0.01)
    np.testing.assert_allclose(estimates[0.0], first, atol=0.01)


def test_gate_rejects_a_far_fix_once_the_filter_is_sure():
    filt = NavigationFilter(TRANSPONDER, SURFACE, 0.1, usbl_std=(0.2, 0.0))
    true = np.array([-20.0, 0.0, 0.0])
    for k in range(30):
        fix = TRANSPONDER - true if k % 10 == 0 else None
        filt.step(_observation(np.zeros(3), SURFACE, fix))
    assert filt.fixes == 3
    wrong = TRANSPONDER - (true + np.array([0.0, 0.0, -8.0]))  # a bottom-mirror fix
    filt.step(_observation(np.zeros(3), SURFACE, wrong))
    assert filt.rejected == 1
    assert np.linalg.norm(filt.p - true) < 0.2
    assert USBL_GATE == pytest.approx(16.27, abs=0.01)
    from scipy import stats
    assert stats.chi2.ppf(0.999, 3) == pytest.approx(USBL_GATE, abs=0.01)


class _Env:
    """What :class:`MissionAgent` reads of an env."""

    def __init__(self):
        import gymnasium as gym

        env = gym.make("auv_envs/DockingMission-v0", obs_mode="nav_features").unwrapped
        self.obs_mode = env.obs_mode
        self.calibration, self.navigation, self.rules = env.calibration, env.navigation, \
            env.rules


def _nav_features(visible: int, n: int = 6):
    obs = _observation(np.zeros(3), SURFACE, None)
    obs["visible"] = np.array([1] * visible + [0] * (n - visible), np.int8)
    obs["pixels"] = np.zeros((n, 2), np.float32)
    return obs


def test_handover_with_hysteresis_on_scripted_cases():
    """To the lights after 5 steps with enough of them; a flicker does not hand back; 50
    steps without them do, and a new hand-over starts a fresh OFNMPC agent."""
    from baselines.docking.agents import MissionAgent

    agent = MissionAgent(_Env())
    agent.reset(0)
    for _ in range(4):
        agent.act(_nav_features(6), {})
    assert agent.terminal is None
    agent.act(_nav_features(6), {})
    first = agent.terminal
    assert first is not None and agent.handovers == 1
    for _ in range(10):  # a flicker: lights lost for 10 steps
        agent.act(_nav_features(1), {})
    assert agent.terminal is first
    for _ in range(40):
        agent.act(_nav_features(0), {})
    assert agent.terminal is None  # 50 steps without the lights: back to homing
    for _ in range(5):
        agent.act(_nav_features(4), {})
    assert agent.terminal is not None and agent.terminal is not first
    assert agent.handovers == 2
    with pytest.raises(ValueError, match="nav_features"):
        import gymnasium as gym

        MissionAgent(gym.make("auv_envs/DockingMission-v0", obs_mode="nav").unwrapped)
    assert agent.position_estimate() is None  # no USBL fix yet: placed nowhere
