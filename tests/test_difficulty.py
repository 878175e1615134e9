"""Difficulty levels: ``easy`` is the release bit for bit; presets apply and can be overridden."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import auv_envs
from auv_envs.core import difficulty
from tests.fingerprints import SEEDS, cases, fingerprint, key, level_cases

RELEASE = json.loads((Path(__file__).parent / "data" / "release_fingerprints.json").read_text())
LEVELS = json.loads((Path(__file__).parent / "data" / "level_fingerprints.json").read_text())
LEVELLED = [case for case in cases()
            if hasattr(auv_envs.task_class(case[0]), "difficulty_presets")]


def _ids(case):
    env_id, mode, kwargs = case
    return "-".join([env_id.split("/")[1], mode, *map(str, kwargs.values())])


def _assert_release(rows, release):
    """Same steps, same numbers (to summation-order rounding: the sums are of many floats)."""
    assert len(rows) == len(release)
    np.testing.assert_allclose(np.array(rows), np.array(release), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("case", cases(), ids=_ids)
def test_default_is_the_release(case):
    env_id, mode, kwargs = case
    for seed in SEEDS:
        _assert_release(fingerprint(env_id, mode, seed, **kwargs),
                        RELEASE[key(env_id, mode, kwargs, seed)])


@pytest.mark.parametrize("case", LEVELLED, ids=_ids)
def test_easy_is_the_release(case):
    env_id, mode, kwargs = case
    seed = SEEDS[0]
    _assert_release(fingerprint(env_id, mode, seed, difficulty="easy", **kwargs),
                    RELEASE[key(env_id, mode, kwargs, seed)])


@pytest.mark.parametrize("case", level_cases(), ids=_ids)
def test_levels_are_unchanged(case):
    """``paper`` and ``hard`` episodes as recorded (``tests/data/level_fingerprints.json``):
    a refactor of a family's transition must leave them as they were."""
    env_id, mode, kwargs = case
    _assert_release(fingerprint(env_id, mode, SEEDS[0], **kwargs),
                    LEVELS[key(env_id, mode, kwargs, SEEDS[0])])


@pytest.mark.parametrize("env_id", sorted({case[0] for case in LEVELLED}))
def test_presets_apply_and_keywords_override(env_id):
    cls = auv_envs.task_class(env_id)
    presets = cls.difficulty_presets
    difficulty.check_presets(presets)
    for level in ("paper", "hard"):
        assert presets[level], f"{level} sets no parameter"
        env = gym.make(env_id, difficulty=level)
        try:
            assert env.unwrapped.difficulty == level
            # Pickling rebuilds the env from its recorded arguments: the level is one of them.
            assert pickle.loads(pickle.dumps(env.unwrapped)).difficulty == level
        finally:
            env.close()
    assert presets["paper"] != presets["hard"]


@pytest.mark.parametrize("env_id", sorted({case[0] for case in LEVELLED}))
@pytest.mark.parametrize("level", ["paper", "hard"])
def test_an_env_pickles_before_its_first_reset(env_id, level):
    """A level's episode state (e.g. the failed lamps of ``optics``) is drawn at reset:
    before it there is none to restore."""
    env = gym.make(env_id, difficulty=level).unwrapped
    try:
        copy = pickle.loads(pickle.dumps(env))
        obs, _ = copy.reset(seed=5)
        np.testing.assert_equal(obs, env.reset(seed=5)[0])
        copy.close()
    finally:
        env.close()


def test_resolve():
    presets = {"easy": {}, "paper": {"a": 1}, "hard": {"a": 2}}
    assert difficulty.resolve(presets, "easy", {"a": None, "b": 3}) == {"a": None, "b": 3}
    assert difficulty.resolve(presets, "paper", {"a": None, "b": 3}) == {"a": 1, "b": 3}
    assert difficulty.resolve(presets, "hard", {"a": 7, "b": None}) == {"a": 7, "b": None}
    with pytest.raises(ValueError, match="difficulty"):
        difficulty.resolve(presets, "extreme", {"a": None})
    with pytest.raises(ValueError, match="lacks"):
        difficulty.resolve(presets, "paper", {"b": None})
    with pytest.raises(ValueError):
        difficulty.check_presets({"easy": {"a": 1}, "paper": {}, "hard": {}})
    with pytest.raises(ValueError):
        difficulty.check_presets({"paper": {}, "hard": {}})


def test_bad_level_is_a_clear_error():
    env_id = LEVELLED[0][0]
    with pytest.raises(ValueError, match="difficulty"):
        gym.make(env_id, difficulty="Paper")


#: The first seed's release and level records of the superseded ids
#: (``auv_envs.PREVIOUS_VERSIONS``): ``-v1`` docking, ``AcousticTracking-v0`` and ``-v1``.
RECORDS = {**RELEASE, **LEVELS}
SUPERSEDED_CASES = sorted(k for k in RECORDS if k.split("|")[0] in auv_envs.PREVIOUS_VERSIONS
                          and k.endswith(f"|{SEEDS[0]}"))


@pytest.mark.parametrize("case", SUPERSEDED_CASES,
                         ids=lambda k: "-".join([*k.split("|")[:2], k.split("|")[2][:40]]))
def test_superseded_ids_keep_their_behaviour(case):
    """A superseded id is built with the keywords that give its old behaviour and still
    makes its recorded episodes: ``-v1`` docking (``plant="mujoco"``, MuJoCo's staged
    plant throughout) exactly, ``-v2``'s compiled plant the same to round-off
    (``test_default_is_the_release``, whose ``-v2`` records are ``-v1``'s);
    ``AcousticTracking-v0`` (``integrator="implicitfast"``, ``noise_draws="all"``) to
    round-off: the measurement noise's deviations have been computed with ``exp`` and
    ``sqrt`` instead of a power and ``hypot`` since v1 (8.9e-16 in the observations);
    ``AcousticTracking-v1`` (``planner="tabulated"``) likewise (identical to the byte
    when v2 came)."""
    env_id, mode, kwargs, seed = case.split("|")
    env = gym.make(env_id)
    for name, value in auv_envs.PREVIOUS_VERSIONS[env_id][1].items():
        assert env.unwrapped._init_kwargs[name] == value
    env.close()
    rows = fingerprint(env_id, mode, int(seed), **json.loads(kwargs))
    if "Docking" in env_id:
        assert rows == RECORDS[case]
    else:
        _assert_release(rows, RECORDS[case])
