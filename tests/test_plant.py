"""The staged integrator: MuJoCo's step with a force at every stage, and no global state.

:class:`auv_envs.core.plant.StagedIntegrator` must give, bit for bit, what
MuJoCo's own ``mj_step`` gives with the same force in the process-global
``mjcb_passive`` callback (the oracle, installed here only for the comparison),
and the envs built on it must step in threads beside other MuJoCo code
(Gymnasium's own envs, a user's ``mj_step``, model compilation) without either
side noticing.
"""

from __future__ import annotations

import threading

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the environments)
from auv_envs.core.plant import StagedIntegrator
from tests.conftest import DOCKING_IDS

STEPS = 40

#: A chain of hinged links over a floor, a free ball that lands on it: contacts,
#: several bodies, joint damping, sensors and energy (which mj_step computes).
CHAIN_XML = """
<mujoco>
  <option timestep="0.004" integrator="{integrator}">
    <flag energy="enable"/>
  </option>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <body pos="0 0 0.6">
      <joint name="a" type="hinge" axis="0 1 0" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
      <body pos="0.3 0 0">
        <joint name="b" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
      </body>
    </body>
    <body pos="0.1 0.05 0.3">
      <freejoint/>
      <geom type="sphere" size="0.05"/>
    </body>
  </worldbody>
  <sensor><jointpos joint="a"/><jointvel joint="b"/></sensor>
</mujoco>
"""


def _drag(model, data):
    """A state-dependent force: quadratic drag on every dof, a pull on the ball."""
    data.qfrc_passive[:] -= 0.3 * data.qvel * np.abs(data.qvel)
    data.qfrc_passive[2:5] += 0.2 * np.sin(data.qpos[:3])


def _trajectory(model, data, stepper, steps: int) -> np.ndarray:
    rows = []
    for _ in range(steps):
        stepper()
        rows.append(np.concatenate([data.qpos, data.qvel, data.qacc_warmstart,
                                    data.sensordata, data.energy, [data.time]]))
    return np.array(rows)


def _with_callback(model, force, steps: int) -> np.ndarray:
    """The oracle: MuJoCo's mj_step with ``force`` as the global passive callback."""
    data = mujoco.MjData(model)
    mujoco.set_mjcb_passive(force)
    try:
        return _trajectory(model, data, lambda: mujoco.mj_step(model, data), steps)
    finally:
        mujoco.set_mjcb_passive(None)


def _staged(model, force, steps: int) -> np.ndarray:
    data = mujoco.MjData(model)
    return _trajectory(model, data, StagedIntegrator(model, data, force).step, steps)


@pytest.mark.parametrize("integrator", ["RK4", "Euler"])
def test_equals_mujoco_step_with_the_force_as_callback_bit_for_bit(integrator):
    model = mujoco.MjModel.from_xml_string(CHAIN_XML.format(integrator=integrator))
    want = _with_callback(model, _drag, 300)
    got = _staged(model, _drag, 300)
    np.testing.assert_array_equal(got, want)
    # The run has contacts (the ball and the chain reach the floor) and moves.
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = got[-1, : model.nq], got[-1, model.nq : model.nq + model.nv]
    mujoco.mj_forward(model, data)
    assert data.ncon > 0
    assert np.ptp(got[:, 0]) > 0.1


@pytest.mark.parametrize("integrator", ["RK4", "Euler"])
def test_with_no_force_it_is_mujoco_step(integrator):
    model = mujoco.MjModel.from_xml_string(CHAIN_XML.format(integrator=integrator))
    data = mujoco.MjData(model)
    want = _trajectory(model, data, lambda: mujoco.mj_step(model, data), 200)
    np.testing.assert_array_equal(_staged(model, lambda m, d: None, 200), want)


def test_docking_plant_equals_the_callback_plant_through_contact():
    """The env's hull wrench through the staged integrator against MuJoCo's RK4 with
    the wrench as the callback (the plant ``-v1`` shipped with): same bits, also
    while the hull lies on the seabed."""
    env = gym.make(DOCKING_IDS[0], obs_mode="state", scenario="current")
    try:
        unwrapped = env.unwrapped
        env.reset(seed=9301)
        physics, hull = unwrapped.physics, unwrapped.hull
        start = (physics.data.qpos.copy(), physics.data.qvel.copy())
        tau = (0.0, 0.0, -unwrapped.vehicle.thrust_limits[2], 0.0, 0.0, 3.0)
        runs, contacts = [], []
        for stepper in ("callback", "staged"):
            physics.data.qpos[:], physics.data.qvel[:] = start
            physics.data.qacc_warmstart[:] = 0.0
            physics.data.time = 0.0
            mujoco.mj_forward(physics.model, physics.data)
            hull.command(tau, (0.2, -0.1, 0.0))
            model, data = physics.model, physics.data
            step = (unwrapped.integrator.step if stepper == "staged"
                    else lambda model=model, data=data: mujoco.mj_step(model, data))
            if stepper == "callback":
                mujoco.set_mjcb_passive(hull.passive_force)
            try:
                rows = []
                for _ in range(300):
                    step()
                    contacts.append(data.ncon)
                    rows.append(np.concatenate([data.qpos, data.qvel, data.qacc_warmstart]))
            finally:
                mujoco.set_mjcb_passive(None)
            runs.append(np.array(rows))
    finally:
        env.close()
    np.testing.assert_array_equal(runs[1], runs[0])
    assert max(contacts) > 0


def test_refuses_what_it_does_not_integrate():
    model = mujoco.MjModel.from_xml_string(CHAIN_XML.format(integrator="implicitfast"))
    data = mujoco.MjData(model)
    with pytest.raises(ValueError, match="Euler or RK4"):
        StagedIntegrator(model, data, _drag).step()
    activated = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><joint name='j'/><geom size='0.1'/></body></worldbody>"
        "<actuator><general joint='j' dyntype='filter' dynprm='0.1'/></actuator></mujoco>")
    with pytest.raises(ValueError, match="activations"):
        StagedIntegrator(activated, mujoco.MjData(activated), _drag)


def test_an_exception_in_the_force_reaches_the_caller_and_leaves_nothing_behind():
    model = mujoco.MjModel.from_xml_string(CHAIN_XML.format(integrator="RK4"))
    data = mujoco.MjData(model)

    def broken(model, data):
        raise ZeroDivisionError("boom")

    with pytest.raises(ZeroDivisionError):
        StagedIntegrator(model, data, broken).step()
    assert mujoco.get_mjcb_passive() is None
    StagedIntegrator(model, data, _drag).step()  # the data steps on with a working force


# ---------------------------------------------------------------- envs side by side


def _actions(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (STEPS, 4)).astype(np.float32)


def _rollout(env, seed: int, actions) -> np.ndarray:
    _, info = env.reset(seed=seed)
    rows = []
    for action in actions:
        _, _, terminated, truncated, info = env.step(action)
        rows.append(np.concatenate([info["true_position"], info["true_velocity"]]))
        if terminated or truncated:
            break
    return np.array(rows)


def _alone(env_id: str, scenario: str, seed: int) -> np.ndarray:
    env = gym.make(env_id, obs_mode="state", scenario=scenario)
    try:
        return _rollout(env, seed, _actions(seed))
    finally:
        env.close()


def test_interleaved_envs_each_get_their_own_force():
    """Two envs (different layouts and currents) stepped alternately equal each alone."""
    specs = [(DOCKING_IDS[0], "current", 5), (DOCKING_IDS[1], "mismatch", 6)]
    expected = [_alone(*spec) for spec in specs]
    envs = [gym.make(env_id, obs_mode="state", scenario=s) for env_id, s, _ in specs]
    try:
        rows = [[], []]
        for env, (_, _, seed) in zip(envs, specs, strict=True):
            env.reset(seed=seed)
        for k in range(STEPS):
            for i, (env, (_, _, seed)) in enumerate(zip(envs, specs, strict=True)):
                if len(rows[i]) < len(expected[i]):
                    _, _, _, _, info = env.step(_actions(seed)[k])
                    rows[i].append(np.concatenate([info["true_position"],
                                                   info["true_velocity"]]))
    finally:
        for env in envs:
            env.close()
    for got, want in zip(rows, expected, strict=True):
        np.testing.assert_array_equal(np.array(got), want)


def test_sync_vector_env_matches_single_envs():
    seeds = [11, 12, 13]
    vec = gym.vector.SyncVectorEnv(
        [lambda: gym.make(DOCKING_IDS[0], obs_mode="state", scenario="current")] * 3
    )
    try:
        vec.reset(seed=seeds)
        actions = np.stack([_actions(s)[:10] for s in seeds], axis=1)
        for action in actions:
            _, _, _, _, infos = vec.step(action)
        positions = infos["true_position"]
    finally:
        vec.close()
    for i, seed in enumerate(seeds):
        np.testing.assert_array_equal(positions[i], _alone(DOCKING_IDS[0], "current", seed)[9, :3])


def _run_threads(jobs: dict) -> dict:
    """Run each ``name: callable`` in its own thread at once; their results, or raise
    the first error any of them met (none is lost in its thread)."""
    results, errors = {}, []
    barrier = threading.Barrier(len(jobs))

    def work(name, job):
        try:
            barrier.wait()
            results[name] = job()
        except BaseException as exc:  # re-raised below
            errors.append((name, exc))

    threads = [threading.Thread(target=work, args=item) for item in jobs.items()]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    if errors:
        name, exc = errors[0]
        raise AssertionError(f"thread {name!r} failed: {exc!r}") from exc
    return results


def _half_cheetah(steps: int = 400) -> np.ndarray:
    env = gym.make("HalfCheetah-v5")
    try:
        obs, _ = env.reset(seed=3)
        rng = np.random.default_rng(3)
        rows = [obs]
        for _ in range(steps):
            obs, *_ = env.step(rng.uniform(-1.0, 1.0, 6).astype(np.float32))
            rows.append(obs)
        return np.array(rows)
    finally:
        env.close()


def _users_own_mujoco(steps: int = 3000) -> np.ndarray:
    """A user's model, compiled over and over and stepped with ``mj_step``."""
    xml = CHAIN_XML.format(integrator="RK4")
    for _ in range(20):
        mujoco.MjModel.from_xml_string(xml)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    return _trajectory(model, data, lambda: mujoco.mj_step(model, data), steps)


def _our_env(env_id: str, seed: int, **kwargs) -> np.ndarray:
    env = gym.make(env_id, obs_mode="state", **kwargs)
    try:
        obs, _ = env.reset(seed=seed)
        rows = [np.asarray(obs, dtype=float)]
        env.action_space.seed(seed)
        for _ in range(60):
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            rows.append(np.asarray(obs, dtype=float))
            if terminated or truncated:
                obs, _ = env.reset()
        return np.array(rows)
    finally:
        env.close()


def test_other_mujoco_code_in_threads_is_untouched_and_so_are_our_envs():
    """Gymnasium's HalfCheetah, a user's own compile-and-mj_step and our three
    families, all at once in five threads: nothing fails and every trajectory is
    the one it has alone (``-v1`` used a global passive callback that made
    HalfCheetah fail here)."""
    jobs = {
        "half_cheetah": _half_cheetah,
        "user": _users_own_mujoco,
        "docking": lambda: _our_env(DOCKING_IDS[0], 71, scenario="current"),
        "lars": lambda: _our_env("auv_envs/LARSCapture-v0", 72),
        "acoustic": lambda: _our_env("auv_envs/AcousticTracking-v2", 73),
    }
    alone = {name: job() for name, job in jobs.items()}
    together = _run_threads(jobs)
    for name, want in alone.items():
        np.testing.assert_array_equal(together[name], want, err_msg=name)


def test_two_of_our_envs_in_two_threads_equal_serial_runs():
    specs = {"six": (DOCKING_IDS[0], "current", 21), "lamp": (DOCKING_IDS[1], "current", 22),
             "mismatch": (DOCKING_IDS[0], "mismatch", 23)}
    expected = {name: _alone(*spec) for name, spec in specs.items()}
    got = _run_threads({name: (lambda spec=spec: _alone(*spec)) for name, spec in specs.items()})
    for name, want in expected.items():
        np.testing.assert_array_equal(got[name], want, err_msg=name)


def test_a_camera_env_renders_from_whichever_thread_steps_it():
    """An ``image`` env stepped in turn by the main thread, a thread that then ends,
    and a new thread: the images are those of a run in one thread."""
    def make():
        return gym.make(DOCKING_IDS[0], obs_mode="image", image_size=(64, 48))

    actions = _actions(31)[:6]
    env = make()
    try:
        env.reset(seed=31)
        want = [env.step(a)[0]["image"] for a in actions]
    finally:
        env.close()

    env = make()
    try:
        env.reset(seed=31)
        got = []
        for k, action in enumerate(actions):
            if k % 3 == 0:
                got.append(env.step(action)[0]["image"])
            else:  # a fresh thread, which ends before the next step
                got.append(_run_threads({"step": lambda a=action: env.step(a)[0]["image"]})
                           ["step"])
    finally:
        env.close()
    for k, (image, reference) in enumerate(zip(got, want, strict=True)):
        np.testing.assert_array_equal(image, reference, err_msg=f"step {k}")
    assert any(image.std() > 0 for image in got)  # real frames, not blank buffers
