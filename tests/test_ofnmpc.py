"""[OFNMPC] OFNMPC: target conditions inside the NLP, offset-free closed loop, solver
fallback, and a short seeded docking episode of the registered agent."""

from __future__ import annotations

import math

import numpy as np
import pytest

from baselines import registry
from baselines.docking.agents import OFNMPCAgent
from baselines.docking.control.ofnmpc import OffsetFreeNMPC, OFNMPCConfig
from baselines.docking.estimation.observers import DockingEKF
from baselines.evaluation import run_episode
from baselines.registry import make_agent
from tests.conftest import DOCKING_IDS, make_env
from tests.test_agents import assert_docked


@pytest.fixture(scope="module")
def calibration():
    env = make_env(DOCKING_IDS[0], "features")
    yield env.unwrapped.calibration
    env.close()


@pytest.fixture(scope="module")
def controller(calibration):
    return OffsetFreeNMPC(calibration)


def test_target_conditions_hold_inside_the_solution(controller, calibration):
    """x_s is the docking pose at rest and u_s balances d and the restoring force."""
    controller.reset()
    d = np.array([5.0, -4.0, 3.0, 1.5])
    result = controller.solve(np.array([-6.0, 0.3, -0.2, 0.05, 0.2, 0.0, 0.0, 0.0]), d)
    assert result.success
    chi, _ = controller.last_plan()
    us = chi[0, 8:12]
    target = np.concatenate([calibration.target_position, [0.0], np.zeros(4)])
    # Holding the docking pose at rest is an equilibrium of the nominal model: the
    # whole derivative vanishes there, the pose rows included.
    derivative = calibration.nominal_model.derivatives(target, us, d, ops=math)
    np.testing.assert_allclose(derivative, 0.0, atol=1e-6)
    # Net buoyancy B - W (N, up): holding depth takes -(B - W) - d_Z of heave thrust.
    buoyancy = calibration.nominal_params.net_buoyancy
    np.testing.assert_allclose(us, -d - np.array([0.0, 0.0, buoyancy, 0.0]), atol=1e-5)
    # The carried target is the same at every stage.
    np.testing.assert_allclose(chi[:, 8:], np.broadcast_to(chi[0, 8:], chi[:, 8:].shape),
                               atol=1e-9)


def test_offset_free_on_nominal_model_with_constant_unmodelled_force(calibration):
    """Plant = nominal model + constant force; pixels from the visual model. The closed
    loop settles on the docking point with zero offset and the EKF's disturbance
    estimate converges to the force ([OFNMPC] §3.2)."""
    force = np.array([12.0, -15.0, 10.0, 4.0])
    model = calibration.nominal_model
    observer = DockingEKF(calibration)
    controller = OffsetFreeNMPC(calibration)
    visual = observer.visual
    x = np.array([-3.5, 0.4, 0.3, 0.1, 0.0, 0.0, 0.0, 0.0])
    tau = np.zeros(4)
    for _ in range(220):
        h, _ = visual.evaluate(x, np.zeros(2))
        obs = {"pixels": h[: 2 * visual.n_lights].reshape(-1, 2),
               "visible": np.ones(visual.n_lights), "velocity": x[4:8],
               "attitude": np.array([0.0, 0.0, x[3]])}
        estimate = observer.step(obs, tau)
        result = controller.solve(estimate.state, estimate.disturbance)
        assert result.success
        tau = result.tau
        x = model.step(x, tau, calibration.control_period, d=force, ops=np)
    np.testing.assert_allclose(x[:3], calibration.target_position, atol=1e-4)
    assert abs(x[3]) < 1e-6
    np.testing.assert_allclose(x[4:], 0.0, atol=1e-4)
    np.testing.assert_allclose(estimate.disturbance, force, atol=1e-4)
    assert controller.failures == 0


def test_solver_failure_applies_the_shifted_previous_plan(calibration):
    """A disturbance beyond the thrust limits makes the target conditions infeasible:
    the failure is counted and the previous plan, shifted by the elapsed time, runs."""
    ctrl = OffsetFreeNMPC(calibration, OFNMPCConfig(max_iter=40))
    x = np.array([-6.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    first = ctrl.solve(x, np.zeros(4))
    assert first.success and not first.fallback
    plan = ctrl.last_plan()[1].copy()
    outcomes = [ctrl.solve(x, np.array([0.0, 0.0, 500.0, 0.0])) for _ in range(4)]
    assert all(r.fallback and not r.success for r in outcomes)
    assert ctrl.failures == 4
    period, interval = calibration.control_period, ctrl.config.shooting_interval
    for k, r in enumerate(outcomes, start=1):
        np.testing.assert_allclose(r.tau, plan[int(k * period / interval + 1e-9)])
    recovered = ctrl.solve(x, np.zeros(4))
    assert recovered.success


def test_non_finite_estimate_raises(controller):
    with pytest.raises(ValueError, match="non-finite"):
        controller.solve(np.full(8, np.nan), np.zeros(4))
    with pytest.raises(ValueError, match="state"):
        controller.solve(np.zeros(3), np.zeros(4))


def test_agents_are_registered_for_both_docking_envs():
    for name in ("ofnmpc-ekf", "ofnmpc-mhe"):
        spec = registry.agent_spec(name)
        assert spec.obs_mode == "features"
        assert all(spec.applies_to(e) for e in DOCKING_IDS)


def test_agent_rejects_unknown_observer_and_state_observations():
    env = make_env(DOCKING_IDS[0], "state")
    try:
        with pytest.raises(ValueError, match="features"):
            make_agent("ofnmpc-ekf", env)
    finally:
        env.close()
    env = make_env(DOCKING_IDS[0], "features")
    try:
        with pytest.raises(ValueError, match="observer"):
            OFNMPCAgent(env.unwrapped, observer="ukf")
    finally:
        env.close()


def test_ofnmpc_ekf_docks_in_mismatch_scenario():
    """A short seeded episode; the agent never sees ``info`` (it gets an empty dict)."""
    env_id = DOCKING_IDS[0]
    env = make_env(env_id, "features", scenario="mismatch", time_limit=40.0)
    try:
        agent = make_agent("ofnmpc-ekf", env)

        class _NoInfo:
            """The agent behind a wall that hides ``info``."""

            def __getattr__(self, name):
                return getattr(agent, name)

            def act(self, observation, info):
                return agent.act(observation, {})

        row = run_episode(env, _NoInfo(), 100_000, env_id, "ofnmpc-ekf")
    finally:
        env.close()
    assert_docked(row, env.unwrapped.calibration.tolerances)
    assert row.metrics["agent_solver_failures"] == 0
    assert row.metrics["agent_solves"] == row.length
    assert row.metrics["estimate_error_max"] < 0.5  # position_estimate() vs truth
    assert {f"agent_disturbance_{a}" for a in "XYZN"} <= set(row.metrics)


def test_compiled_solver_gives_the_same_plan(calibration, tmp_path, monkeypatch):
    """C code generation changes the speed, not the iterates (short horizon: fast build)."""
    monkeypatch.setenv("AUV_ENVS_CACHE", str(tmp_path))
    config = OFNMPCConfig(horizon=2, compile=True, compile_flags=("-O0",))
    compiled = OffsetFreeNMPC(calibration, config)
    assert compiled.compiled
    assert len(list((tmp_path / "casadi").glob("*/ofnmpc_*.so"))) == 1
    reference = OffsetFreeNMPC(calibration, OFNMPCConfig(horizon=2))
    x, d = np.array([-4.0, 0.3, -0.2, 0.05, 0.2, 0.0, 0.0, 0.0]), np.array([3.0, -2, 1, 0.5])
    for _ in range(3):
        a, b = compiled.solve(x, d), reference.solve(x, d)
        assert a.success and b.success
        np.testing.assert_allclose(a.tau, b.tau, rtol=1e-9, atol=1e-9)
        x = calibration.nominal_model.step(x, a.tau, calibration.control_period, d=d, ops=np)
    # A second controller finds the cached library instead of compiling again.
    assert OffsetFreeNMPC(calibration, config).compiled


def test_without_a_compiler_the_solver_warns_and_runs_uncompiled(calibration, tmp_path,
                                                                  monkeypatch):
    import baselines.docking.control.ofnmpc as module

    monkeypatch.setenv("AUV_ENVS_CACHE", str(tmp_path))
    monkeypatch.setattr(module.shutil, "which", lambda name: None)
    with pytest.warns(RuntimeWarning, match="no C compiler"):
        ctrl = OffsetFreeNMPC(calibration, OFNMPCConfig(horizon=2, compile=True))
    assert not ctrl.compiled
    assert ctrl.solve(np.array([-4.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]), np.zeros(4)).success


def test_processes_needing_the_same_library_compile_it_once(tmp_path, monkeypatch):
    """The build is locked: of two simultaneous requests one compiles, the other waits and
    loads the result (a tiny NLP keeps the build short)."""
    import threading

    import casadi as ca

    import baselines.docking.control.ofnmpc as module

    monkeypatch.setenv("AUV_ENVS_CACHE", str(tmp_path))
    builds, build = [], module._build_library

    def counting_build(*args):
        builds.append(args[0])
        build(*args)

    monkeypatch.setattr(module, "_build_library", counting_build)
    x = ca.SX.sym("x", 2)
    options = {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}}
    solver = ca.nlpsol("tiny", "ipopt", {"x": x, "f": ca.sumsqr(x - ca.DM([1.0, -2.0]))},
                       options)
    results = [None, None]

    def request(i):
        results[i] = module.compiled_nlpsol("tiny", "ipopt", solver, options, ("-O0",))

    threads = [threading.Thread(target=request, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert builds == ["tiny"]
    for compiled in results:
        np.testing.assert_allclose(np.ravel(compiled(x0=[0.0, 0.0])["x"]), [1.0, -2.0],
                                   atol=1e-6)


def test_default_controller_is_compiled_where_a_compiler_exists(controller):
    import shutil

    assert controller.config.compile
    assert controller.compiled == (shutil.which("cc") is not None
                                   or shutil.which("gcc") is not None)


def test_an_estimate_beyond_max_distance_takes_the_fallback_without_solving(calibration):
    """FATROP does not return on a position near 1e8 m (a diverged pose fit once sent
    one): such an estimate is a counted failure that applies the stored plan."""
    ctrl = OffsetFreeNMPC(calibration, OFNMPCConfig(max_distance=100.0))
    x = np.array([-6.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert ctrl.solve(x, np.zeros(4)).success
    plan = ctrl.last_plan()[1].copy()
    far = x.copy()
    far[:3] = (-2.4e8, -3.0e6, 1.8e7)
    result = ctrl.solve(far, np.zeros(4))
    assert result.fallback and not result.success and result.iterations == -1
    assert "max_distance" in result.status and ctrl.failures == 1
    period, interval = calibration.control_period, ctrl.config.shooting_interval
    np.testing.assert_allclose(result.tau, plan[int(period / interval + 1e-9)])
