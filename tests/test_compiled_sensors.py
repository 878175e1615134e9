"""The docking tasks' compiled sensors (``sensors="compiled"``). The navigation sensors
(:class:`~auv_envs.tasks.docking.navigation.CompiledNavigation`): the readings equal to the
bit and the draws the same as :class:`~auv_envs.tasks.docking.navigation.Navigation`'s,
the USBL fix (:meth:`USBL.solve`) equal to :meth:`USBL.fix` at round-off, every level's
sensors. The lights' detection through the water
(:class:`~auv_envs.tasks.docking.optics.CompiledLampDetection`) against NumPy's, every
water. Episodes with either, and the scalar operations compiled against Python's."""

from __future__ import annotations

import copy
import dataclasses
import math
import operator
import pickle
from types import SimpleNamespace

import casadi
import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the ids)
from auv_envs.core import frames
from auv_envs.core.ops import FLOATS, Backend, casadi_ops
from auv_envs.tasks.docking import transition
from auv_envs.tasks.docking.config import EASY_NAVIGATION, HARD_NAVIGATION, PAPER_NAVIGATION
from auv_envs.tasks.docking.navigation import (
    DVL,
    USBL,
    USBL_ACOUSTICS,
    CompiledNavigation,
    Navigation,
    NavigationSensors,
    NavState,
)
from auv_envs.tasks.docking.optics import CompiledLampDetection, LampOutages, WaterOptics
from auv_envs.tasks.docking.plant import compiled_sensors

#: Every level's suite, and one with DVL dropouts, a coarse depth and USBL outliers.
SUITES = {
    "easy": EASY_NAVIGATION, "paper": PAPER_NAVIGATION, "hard": HARD_NAVIGATION,
    "rough": dataclasses.replace(
        HARD_NAVIGATION, dvl=DVL(dropout=0.3, min_altitude=1.0),
        usbl=dataclasses.replace(HARD_NAVIGATION.usbl, outlier_rate=0.2, shadowing=0.5)),
}
SEABED_Z = -5.0


def random_truth(rng: np.random.Generator) -> dict:
    """A vehicle anywhere from the station to a mission's start, at any attitude."""
    x, y = rng.uniform(-300.0, 300.0, 2)
    return {"velocity": tuple(rng.normal(0.0, 0.4, 6).tolist()),
            "seabed_clearance": float(rng.uniform(-0.2, 60.0)),
            "euler": tuple(rng.uniform(-math.pi, math.pi, 3).tolist()),
            "position": (float(x), float(y), float(rng.uniform(SEABED_Z, 45.0)))}


def same(a, b) -> bool:
    """Equal to the bit (as float64), element by element."""
    return np.array_equal(np.asarray(a, dtype=float).view(np.int64),
                          np.asarray(b, dtype=float).view(np.int64))


@pytest.mark.parametrize("level", sorted(SUITES))
def test_readings_and_schedule_are_the_same_numbers_and_the_fix_the_same_at_round_off(level):
    """Episodes of random truths (bottom lock lost and found, pings and late fixes): every
    field of the sensors' state equal to the bit but the fix in flight, its arrival time
    and the delivered fix, equal at round-off; the same draws, as many; the same
    observation, at the step's time and after it."""
    suite = SUITES[level]
    reference = Navigation(suite, SEABED_Z, 0.1)
    compiled = CompiledNavigation(suite, SEABED_Z, 0.1)
    rng = np.random.default_rng(20261208)
    fixes = 0
    for episode in range(12):
        drawn, replayed = (np.random.default_rng(episode) for _ in range(2))
        truth = random_truth(rng)
        expected, got = reference.start(truth, drawn, FLOATS), compiled.start(truth, replayed,
                                                                             FLOATS)
        for step in range(1, 26):
            time = step * 0.1
            truth = random_truth(rng)
            expected = reference.advance(expected, truth, time, drawn, FLOATS)
            got = compiled.advance(got, truth, time, replayed, FLOATS)
            named = CompiledNavigation.unpack(got)
            for field in NavState._fields:
                a, b = getattr(expected, field), getattr(named, field)
                if field in ("pending", "fix", "pending_due"):  # the fix, and its travel time
                    scale = max(1.0, float(np.linalg.norm(a)))
                    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9 * scale)
                else:
                    assert type(a) is type(b) and same(a, b), (level, episode, step, field)
            assert drawn.random() == replayed.random()  # the same draws, as many
            # At the step's time (the call's own observation) and later (made from the state)
            for when in (time, time + 0.05):
                seen, read = (reference.observation(expected, when, FLOATS),
                              compiled.observation(got, when, FLOATS))
                for key in seen:
                    assert (seen[key].dtype == read[key].dtype
                            and seen[key].shape == read[key].shape)
                    if key == "usbl":
                        np.testing.assert_allclose(read[key], seen[key], rtol=1e-6, atol=1e-5)
                    else:
                        assert np.array_equal(read[key], seen[key]), key
            fixes += bool(expected.fix_valid)
    assert fixes > 100  # fixes delivered and observed


def test_the_noise_free_fix_is_exact_at_any_range():
    usbl = USBL(acoustics=dataclasses.replace(USBL_ACOUSTICS, sound_speed_error_std=0.0)
                .noise_free())
    array = usbl.array(50.0, SEABED_Z)
    transponder = (0.5, 0.0, 1.0)
    rng = np.random.default_rng(5)
    for distance in (3.0, 40.0, 160.0, 400.0):
        euler = tuple(rng.uniform(-0.5, 0.5, 3).tolist())
        position = (transponder[0] - distance, 2.0, 8.0)
        vector, valid = usbl.solve(array, position, euler, transponder,
                                   USBL_ACOUSTICS.sound_speed, rng, FLOATS)
        rows = np.array(frames.rotation_rows_from_euler(*euler, math))
        truth = (np.array(transponder) - np.array(position)) @ rows
        assert valid
        np.testing.assert_allclose(vector, truth, rtol=0, atol=1e-9 * distance)


def test_an_episode_with_compiled_sensors_is_the_same_but_for_the_fix_at_round_off():
    envs = [gym.make("auv_envs/DockingStation-v2", obs_mode="nav_features", sensors=code,
                     difficulty="hard") for code in ("numpy", "compiled")]
    assert isinstance(envs[1].unwrapped.params.navigation, CompiledNavigation)
    assert type(envs[0].unwrapped.params.navigation) is Navigation
    for env in envs:
        env.reset(seed=8)
    actions = np.random.default_rng(8).uniform(-1.0, 1.0, (120, 4)).astype(np.float32)
    fixed = 0
    for action in actions:
        steps = [env.step(action) for env in envs]
        (a, reward, done, cut, _), (b, reward_c, done_c, cut_c, _) = steps
        assert (reward, done, cut) == (reward_c, done_c, cut_c)
        for key in a:
            if key == "usbl":
                np.testing.assert_allclose(b[key], a[key], rtol=1e-6, atol=1e-5)
            else:
                assert np.array_equal(a[key], b[key]), key
        fixed += int(a["usbl_valid"][0])
        if done or cut:
            break
    assert fixed > 10


def test_copied_compiled_sensors_draw_into_their_own_calls():
    """Pickled or deep-copied, the compiled sensors are built again: their draws go into
    the copy's own calls' inputs, and the copy reads as the original."""
    suite = HARD_NAVIGATION
    navigation = CompiledNavigation(suite, SEABED_Z, 0.1)
    clear = WaterOptics.jerlov("I")
    params = gym.make("auv_envs/LampArrayDocking-v2", obs_mode="features", sensors="compiled",
                      optics=clear).unwrapped.params
    rng = np.random.default_rng(4)
    truth = random_truth(rng)
    state = navigation.start(truth, np.random.default_rng(1), FLOATS)
    for twin in (pickle.loads(pickle.dumps(navigation)), copy.deepcopy(navigation)):
        assert np.array_equal(twin.advance(state, truth, 0.1, np.random.default_rng(5), FLOATS),
                              navigation.advance(state, truth, 0.1, np.random.default_rng(5),
                                                 FLOATS))
    lamps = params.lamp_detection
    shell = gym.make("auv_envs/LampArrayDocking-v2", obs_mode="features", optics=clear)
    shell.reset(seed=3)
    truth = shell.unwrapped.truth_now()
    out = np.zeros(len(params.light_positions), bool)
    expected = lamps(truth, out, np.random.default_rng(6))
    assert expected["visible"].sum() > 0 and lamps.reads
    for twin in (pickle.loads(pickle.dumps(lamps)), copy.deepcopy(lamps)):
        got = twin(truth, out, np.random.default_rng(6))
        assert got.keys() == expected.keys()
        assert all(np.array_equal(got[key], expected[key]) for key in expected)


def test_the_occlusions_step_as_numpys():
    """The lamps' occluders (:meth:`CompiledLampDetection.occlusions`) against
    :meth:`LampOutages.occlusions_drawn` from random occlusions, in waters where lamps are
    hidden and cleared often: the same occlusions, the same draws."""
    busy = WaterOptics.jerlov("III", occlusion_rate=2.0, occlusion_duration=0.3)
    params = compiled_sensors(gym.make("auv_envs/DockingMission-v0", obs_mode="features",
                                       optics=busy).unwrapped.params)
    rng = np.random.default_rng(21)
    changed = 0
    for trial in range(200):
        occluded = rng.random(params.n_lights) < 0.5
        drawn, replayed = np.random.default_rng(trial), np.random.default_rng(trial)
        expected = LampOutages.occlusions_drawn(occluded, busy, params.dt, drawn, np)
        got = params.lamp_detection.occlusions(occluded, replayed)
        assert got.dtype == bool and np.array_equal(got, expected), trial
        assert drawn.random() == replayed.random()
        changed += int((got != occluded).sum())
    assert changed > 100  # lamps hidden and cleared: both branches compared


def test_a_copied_env_steps_as_the_original():
    """Pickled or deep-copied (vector envs, checkpoints of a rollout), an env with compiled
    sensors steps as the original."""
    env = gym.make("auv_envs/LampArrayDocking-v2", obs_mode="nav_features", sensors="compiled",
                   difficulty="hard")
    env.reset(seed=2)
    for _ in range(5):
        env.step(np.full(4, 0.3, np.float32))
    copies = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    for k in range(40):
        action = np.full(4, 0.3 if k % 2 else -0.2, np.float32)
        expected = env.step(action)[0]
        for twin in copies:
            got = twin.step(action)[0]
            for key in expected:
                assert np.array_equal(got[key], expected[key]), (k, key)


def test_an_unknown_sensor_code_is_refused():
    with pytest.raises(ValueError, match="sensors"):
        gym.make("auv_envs/DockingStation-v2", obs_mode="nav", sensors="fast")


#: Values where Python's ``%`` and ``round`` take care: signs, exact multiples, halves.
TRICKY = [-7.5, -2.5, -0.5, -0.49999999999999994, -0.0, 0.0, 0.5, 1.5, 2.5, 3.5,
          2.0 * math.pi, -2.0 * math.pi, -1e-300, 48123.5, 48122.5, 1e16 + 2.0, -3.14159,
          math.pi, 123456.0005]


def test_casadi_mod_and_round_are_pythons_to_the_bit():
    ops = casadi_ops()
    x = casadi.SX.sym("x")
    compiled = casadi.Function("f", [x], [ops.mod(x, 2.0 * math.pi), ops.mod(x, 1.5),
                                          ops.round(x), ops.mod(x, -1.5)])
    extra = np.random.default_rng(3).uniform(-1e4, 1e4, 200).tolist()
    for value in TRICKY + extra:
        got = [float(v) for v in compiled(value)]
        expected = [operator.mod(value, 2.0 * math.pi), value % 1.5, FLOATS.round(value),
                    value % -1.5]
        for g, e in zip(got[:3], expected[:3], strict=True):
            assert g == e and math.copysign(1.0, g) == math.copysign(1.0, e), (value, g, e)
        # A negative divisor: the same number, a zero without its sign (ops' docstring).
        assert got[3] == expected[3], value


def test_a_suite_is_compiled_once():
    suite = NavigationSensors()
    first, second = (CompiledNavigation(suite, SEABED_Z, 0.1) for _ in range(2))
    assert first._call.function is second._call.function


#: The levels' waters and Jerlov's clearest and most turbid of each kind.
WATERS = ({"difficulty": "paper"}, {"difficulty": "hard"},
          {"optics": WaterOptics.jerlov("I")}, {"optics": WaterOptics.jerlov("III")},
          {"optics": WaterOptics.jerlov("1C")}, {"optics": WaterOptics.jerlov("5C")})


@pytest.mark.parametrize("env_id", ["auv_envs/LampArrayDocking-v2", "auv_envs/DockingStation-v2"])
def test_lamp_detection_is_numpys_through_every_water(env_id):
    """The lights along random approaches (the episodes' starts, then random thrust: most
    lamps in view) through several waters, with random failures and occlusions: the same
    detections and pixels as NumPy's (:func:`~auv_envs.tasks.docking.transition.observe`),
    the same DVL/INS readings to the bit, the same draws."""
    rng = np.random.default_rng(11)
    detected = missed = 0
    for water in WATERS:
        shell = gym.make(env_id, obs_mode="features", **water)
        params = shell.unwrapped.params
        assert params.optics is not None and params.lamp_detection is None
        compiled = compiled_sensors(params)
        assert isinstance(compiled.lamp_detection, CompiledLampDetection)
        for trial in range(30):
            shell.reset(seed=trial)
            for _ in range(int(rng.integers(0, 40))):
                shell.step(rng.uniform(-0.6, 0.6, 4).astype(np.float32))
            truth = shell.unwrapped.truth_now()
            state = SimpleNamespace(out=rng.random(len(params.light_positions)) < 0.2)
            seed = int(rng.integers(2**31))
            drawn, replayed = np.random.default_rng(seed), np.random.default_rng(seed)
            expected = transition.observe(params, state, truth, Backend(FLOATS, drawn, None))
            got = transition.observe(compiled, state, truth, Backend(FLOATS, replayed, None))
            assert drawn.random() == replayed.random()
            assert np.array_equal(expected["visible"], got["visible"]), (water, trial)
            np.testing.assert_allclose(got["pixels"], expected["pixels"], rtol=0, atol=1e-3)
            assert got["pixels"].dtype == expected["pixels"].dtype
            assert got["visible"].dtype == expected["visible"].dtype
            assert list(got) == list(expected)  # the readings too, made in the same call
            for key in ("velocity", "attitude"):
                assert np.array_equal(got[key], expected[key]) and got[key].dtype == np.float32
            detected += int(expected["visible"].sum())
            missed += int(truth["visible"].sum() - expected["visible"].sum())
    assert detected > 50 and missed > 50  # lamps seen and lamps the water (or an outage) hid
