"""``auv_envs/DockingMission-v0``: the start, the rules a long approach needs,
the phase metrics, the privileged reference, the batched twin."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.core.ops import FLOATS
from auv_envs.tasks.docking import transition
from auv_envs.tasks.docking.rules import FAILURE_REASONS

ID = "auv_envs/DockingMission-v0"


def test_starts_far_at_any_bearing_height_and_heading():
    env = gym.make(ID, obs_mode="state")
    seabed = env.unwrapped.rules.seabed_z
    starts = []
    for seed in range(300):
        obs, _ = env.reset(seed=seed)
        starts.append((*obs[:3], math.atan2(obs[6], obs[5])))
    x, y, z, yaw = np.array(starts).T
    horizontal = np.hypot(x, y)
    assert horizontal.min() >= 100.0 and horizontal.max() <= 300.0
    assert np.all(z - seabed >= 3.0 - 1e-6) and np.all(z - seabed <= 30.0 + 1e-6)
    bearings = np.arctan2(y, x)
    assert np.histogram(bearings, bins=4, range=(-np.pi, np.pi))[0].min() > 50  # all round
    assert np.histogram(yaw, bins=4, range=(-np.pi, np.pi))[0].min() > 50
    assert (x > 0).mean() > 0.3  # many start behind the station


def _truth(x, y, z, distance=None):
    return {"longitudinal": x, "seabed_clearance": 5.0, "position": (x, y, z),
            "distance": math.hypot(x, y, z) if distance is None else distance}


def test_rules_of_the_long_approach():
    rules = gym.make(ID).unwrapped.rules
    assert rules.out_of_bounds == 500.0 and rules.behind_radius == 3.0
    codes = {}
    for name, truth in {"far_behind": _truth(150.0, 20.0, 0.0),
                        "near_behind": _truth(1.0, 0.5, 0.0),
                        "out": _truth(-501.0, 0.0, 0.0),
                        "surfaced": _truth(-100.0, 0.0, rules.surface_z)}.items():
        flags = rules.failures(truth, False, 0.0, FLOATS)
        codes[name] = rules.failure_index(flags, FLOATS)
    assert codes["far_behind"] == 0
    assert FAILURE_REASONS[codes["near_behind"] - 1] == "behind_entrance"
    assert FAILURE_REASONS[codes["out"] - 1] == "out_of_bounds"
    assert FAILURE_REASONS[codes["surfaced"] - 1] == "surfaced"
    # The docking ids keep their four failures and their 30 m bounds.
    docking = gym.make("auv_envs/DockingStation-v2").unwrapped.rules
    assert len(docking.failures(_truth(150.0, 20.0, 0.0), False, 0.0, FLOATS)) == 4
    assert docking.failure_index(
        docking.failures(_truth(150.0, 20.0, 0.0), False, 0.0, FLOATS), FLOATS) == 1


def test_lights_lost_timeout_is_refused():
    with pytest.raises(TypeError, match="lights-lost"):
        gym.make(ID, lights_lost_timeout=5.0)


def test_phase_record_on_a_scripted_path():
    """Path length accumulates; the hand-over is the first step with the lights in view
    within the hand-over range, recorded once."""
    params = gym.make(ID).unwrapped.params
    handover = params.mission.handover_range
    record = transition.MissionRecord(x=-100.0, y=0.0, z=0.0, path_length=0.0,
                                      handed_over=False, handover_time=math.nan,
                                      homing_path_length=math.nan, handover_range=math.nan,
                                      handover_cross_track=math.nan)
    lights = params.rules.min_visible
    path = [(-60.0, 0.0, 0.0, lights), (-20.0, 3.0, 4.0, lights - 1),
            (-(handover - 1.0), 3.0, 4.0, lights), (-5.0, 0.0, 0.0, lights)]
    for k, (x, y, z, seen) in enumerate(path, start=1):
        truth = {"position": (x, y, z), "n_visible": seen, "distance": math.hypot(x, y, z),
                 "lateral": y, "vertical": z}
        record = transition.track_mission(params, record, k, truth, FLOATS)
    points = [(-100.0, 0.0, 0.0), *((x, y, z) for x, y, z, _ in path)]
    assert record.path_length == pytest.approx(
        sum(math.dist(a, b) for a, b in zip(points, points[1:], strict=False)))
    assert record.handed_over
    assert record.handover_time == pytest.approx(3 * params.dt)  # the third step
    assert record.handover_range == pytest.approx(math.hypot(handover - 1.0, 3.0, 4.0))
    assert record.handover_cross_track == pytest.approx(5.0)



def test_surfacing_ends_the_episode():
    env = gym.make(ID, obs_mode="state")
    env.reset(seed=4)
    for _ in range(3000):
        _, _, terminated, truncated, info = env.step(np.array([0, 0, 1, 0], np.float32))
        if terminated or truncated:
            break
    assert terminated and info["episode_metrics"]["failure_reason"] == "surfaced"


@pytest.mark.parametrize(("difficulty", "layout"), [("easy", "six_lights"),
                                                    ("hard", "lamp_array")])
def test_privileged_reference_homes_hands_over_and_docks(difficulty, layout):
    from baselines.docking.agents import HomingPDAgent

    env = gym.make(ID, obs_mode="state", difficulty=difficulty, layout=layout)
    agent = HomingPDAgent(env.unwrapped)
    docked = 0
    for seed in (2, 3):
        obs, info = env.reset(seed=seed)
        agent.reset(seed)
        while True:
            obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
            if terminated or truncated:
                break
        metrics = info["episode_metrics"]
        docked += metrics["success"]
        assert metrics["homing_time"] is not None and metrics["homing_time"] > 0
        assert metrics["homing_path_length"] <= metrics["path_length"]
        assert metrics["handover_range"] <= env.unwrapped.params.mission.handover_range
        assert metrics["path_length"] >= 100.0 - 30.0  # it came from >= 100 m
    assert docked == 2


def test_handover_range_follows_the_water():
    ranges = [gym.make(ID, difficulty=level).unwrapped.params.mission.handover_range
              for level in ("easy", "paper", "hard")]
    assert ranges[0] > ranges[1] > ranges[2] > 5.0
    optics = gym.make(ID, difficulty="paper").unwrapped.calibration.optics
    assert float(optics.detection_probability(ranges[1], np)) == pytest.approx(0.5, abs=1e-3)


def test_nav_modes_and_pickling():
    import pickle

    env = gym.make(ID, obs_mode="nav_features", difficulty="paper")
    obs, _ = env.reset(seed=5)
    for _ in range(30):
        obs, *_ = env.step(env.action_space.sample())
    assert obs in env.observation_space
    assert obs["usbl_valid"][0] == 1
    # The fix points at the station, a hundred metres and more away.
    assert np.linalg.norm(obs["usbl"]) > 60.0
    clone = pickle.loads(pickle.dumps(env))
    action = np.array([0.2, 0.0, -0.1, 0.05], np.float32)
    a, b = env.step(action), clone.step(action)
    np.testing.assert_array_equal(a[0]["usbl"], b[0]["usbl"])
    assert a[1] == b[1]


def test_batched_twin_draws_the_same_start_distribution():
    """The batched twin through ``auv_envs.batched.load`` in ``nav_features``: the same start
    distribution, finite flat observations (34 floats: 6 lights' pixels and visibility, the
    16 navigation readings) through a few steps."""
    jax = pytest.importorskip("jax")

    import auv_envs.batched

    env = auv_envs.batched.load("auv_envs/DockingMissionMJX-v0", obs_mode="nav_features",
                                difficulty="paper")
    assert env.observation_size == 34 and env.action_size == 4
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 64))
    qpos = np.asarray(states.data["plant"]["qpos"])
    horizontal = np.hypot(qpos[:, 0], qpos[:, 1])
    assert horizontal.min() >= 100.0 - 1e-3 and horizontal.max() <= 300.0 + 1e-3
    height = qpos[:, 2] - env.task.rules.seabed_z
    assert height.min() >= 3.0 - 1e-4 and height.max() <= 30.0 + 1e-4
    step = jax.jit(jax.vmap(env.step))
    action = jax.numpy.zeros((64, 4))
    for _ in range(12):  # past the first USBL fix's arrival
        states = step(states, action)
    obs = np.asarray(states.obs)
    assert obs.shape == (64, 34) and np.all(np.isfinite(obs))
