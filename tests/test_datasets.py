"""Expert datasets: recorded episodes come back from ``minari.load_dataset`` as they ran."""

from __future__ import annotations

import inspect
import math

import gymnasium as gym
import numpy as np
import pytest

minari = pytest.importorskip("minari")  # the datasets extra (Python 3.11+)

import auv_envs  # noqa: E402
from baselines import datasets, seeds  # noqa: E402
from baselines.registry import make_agent  # noqa: E402

#: (env id, agent, obs mode, env kwargs): a Box and a Dict observation mode, short episodes.
CASES = {
    "docking-state": ("auv_envs/DockingStation-v2", "pd-state", "state", {"time_limit": 2.0}),
    "acoustic-measurements": ("auv_envs/AcousticTracking-v2", "ls-kf", "measurements",
                              {"time_limit": 0.5}),
}
EPISODES = 2
FIRST_SEED = 4321


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """Both datasets, recorded into one datasets directory that does not exist yet."""
    root = tmp_path_factory.mktemp("minari") / "datasets"
    for env_id, agent, obs_mode, kwargs in CASES.values():
        datasets.record_dataset(agent, env_id.split("/")[1], obs_mode, episodes=EPISODES,
                                first_seed=FIRST_SEED, difficulty="paper", out=root,
                                env_kwargs=kwargs)
    return root


def _rerun(env_id, agent, obs_mode, kwargs, seed):
    """The episode again, with a fresh environment and agent."""
    env = gym.make(env_id, obs_mode=obs_mode, difficulty="paper", **kwargs)
    actor = make_agent(agent, env)
    obs, info = env.reset(seed=seed)
    actor.reset(seed)
    run = {"observations": [obs], "actions": [], "rewards": [], "terminations": [],
           "truncations": [], "infos": [info]}
    done = False
    while not done:
        action = actor.act(obs, info)
        obs, reward, terminated, truncated, info = env.step(action)
        run["actions"].append(np.asarray(action, dtype=np.float64))
        run["observations"].append(obs)
        run["rewards"].append(reward)
        run["terminations"].append(terminated)
        run["truncations"].append(truncated)
        run["infos"].append(info)
        done = terminated or truncated
    env.close()
    return run


def _assert_observations_equal(stored, observations):
    if isinstance(stored, dict):
        assert set(stored) == set(observations[0])
        for key, column in stored.items():
            _assert_observations_equal(column, [obs[key] for obs in observations])
        return
    expected = np.stack(observations)
    assert stored.dtype == expected.dtype and stored.shape == expected.shape
    np.testing.assert_array_equal(stored, expected)


@pytest.mark.parametrize("case", sorted(CASES))
def test_round_trip_matches_a_fresh_rerun(root, case, monkeypatch):
    env_id, agent, obs_mode, kwargs = CASES[case]
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    dataset_id = datasets.default_dataset_id(env_id, agent, obs_mode, "paper")
    assert dataset_id == f"auv_envs/{env_id.split('/')[1]}/{agent}-{obs_mode}-paper-v0"
    dataset = minari.load_dataset(dataset_id)
    assert dataset.total_episodes == EPISODES
    meta = dataset.storage.metadata["auv_envs"]
    assert (meta["env_id"], meta["agent"], meta["obs_mode"], meta["difficulty"]) == (
        env_id, agent, obs_mode, "paper")
    assert meta["env_kwargs"] == kwargs and meta["first_seed"] == FIRST_SEED
    space = dataset.action_space
    cls = auv_envs.task_class(env_id)
    assert meta["step_info_keys"] == list(dict.fromkeys(
        [*cls.metric_keys, *(f"reward_{term}" for term in cls.reward_terms)]))
    episodes = list(dataset.iterate_episodes())
    episode_seeds = [m["seed"] for m in dataset.storage.get_episode_metadata(range(EPISODES))]
    assert episode_seeds == [FIRST_SEED + k for k in range(EPISODES)]
    for seed, episode in zip(episode_seeds, episodes, strict=True):
        run = _rerun(env_id, agent, obs_mode, kwargs, seed)
        steps = len(run["rewards"])
        assert len(episode) == steps
        _assert_observations_equal(episode.observations, run["observations"])
        # Actions as the env applied them: clipped to the space, in its dtype.
        expected = np.clip(np.stack(run["actions"]), space.low, space.high).astype(space.dtype)
        np.testing.assert_array_equal(episode.actions, expected)
        assert all(space.contains(a) for a in episode.actions)
        np.testing.assert_array_equal(episode.rewards, np.array(run["rewards"], dtype=float))
        assert math.isclose(float(episode.rewards.sum()), sum(run["rewards"]), rel_tol=1e-12,
                            abs_tol=1e-12)
        np.testing.assert_array_equal(episode.terminations, run["terminations"])
        np.testing.assert_array_equal(episode.truncations, run["truncations"])
        assert episode.terminations[-1] or episode.truncations[-1]
        assert not (episode.terminations[:-1].any() or episode.truncations[:-1].any())
        # Per-step infos: the env's metric keys and reward terms, reset first.
        for key in meta["step_info_keys"]:
            column = episode.infos[key]
            assert len(column) == steps + 1
            np.testing.assert_array_equal(column, np.array([i[key] for i in run["infos"]],
                                                           dtype=column.dtype))
        # Episode metrics: NaN / "" until the last entry, which decodes to the env's dict.
        metrics = run["infos"][-1]["episode_metrics"]
        assert set(episode.infos["episode_metrics"]) == set(metrics)
        for name, column in episode.infos["episode_metrics"].items():
            assert len(column) == steps + 1
            if isinstance(metrics[name], str):
                assert list(column[:-1]) == [b""] * steps
            else:
                assert np.isnan(column[:-1]).all()
        decoded = datasets.episode_metrics(dataset, episode)
        assert decoded == {k: (None if isinstance(v, float) and math.isnan(v) else v)
                           for k, v in metrics.items()}
        assert all(type(decoded[k]) is type(v) for k, v in metrics.items() if v is not None)


def test_dataset_recovers_its_environment(root, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    env_id, agent, obs_mode, kwargs = CASES["docking-state"]
    dataset = minari.load_dataset(datasets.default_dataset_id(env_id, agent, obs_mode, "paper"))
    env = dataset.recover_environment()  # gym.make(spec): auv_envs' summary wrapper included
    try:
        assert env.spec.kwargs == {"task": auv_envs.ENVIRONMENTS[env_id], "obs_mode": obs_mode,
                                   "difficulty": "paper", **kwargs}
        obs, _ = env.reset(seed=FIRST_SEED)
        np.testing.assert_array_equal(obs, dataset[0].observations[0])
    finally:
        env.close()


def test_default_seeds_are_training_seeds():
    default = inspect.signature(datasets.record_dataset).parameters["first_seed"].default
    parsed = datasets.build_parser().parse_args(["record", "--agent", "a", "--env", "e"])
    assert default == parsed.first_seed == seeds.DATASET_SEED_BASE
    low, high = seeds.TRAIN_SEED_RANGE
    assert low <= seeds.DATASET_SEED_BASE < seeds.TRAIN_EVAL_SEED_BASE <= high


@pytest.mark.parametrize("kwargs, error, match", [
    ({"agent": "no-such-agent"}, ValueError, "unknown agent"),
    ({"env_id": "NoSuchEnv-v0"}, ValueError, "unknown env"),
    ({"env_id": "AcousticTracking-v2"}, ValueError, "does not apply to auv_envs/Acoustic"),
    ({"obs_mode": "features"}, ValueError, "does not apply .* obs mode 'features'"),
    ({"episodes": 0}, ValueError, "episodes must be a positive integer"),
    ({"first_seed": -1}, ValueError, "first_seed"),
    ({"difficulty": "extreme"}, ValueError, "difficulty"),
    ({"dataset_id": "auv_envs/no-version"}, ValueError, "NAMESPACE/NAME-vN"),
    ({"env_kwargs": {"difficulty": "hard"}}, ValueError, "argument of its own"),
    ({"env_kwargs": {"no_such_argument": 1}}, ValueError, "rejects arguments"),
])
def test_bad_requests_are_refused_before_anything_is_written(tmp_path, kwargs, error, match):
    request = {"agent": "pd-state", "env_id": "DockingStation-v2", "episodes": 1,
               "out": tmp_path / "out", **kwargs}
    with pytest.raises(error, match=match):
        datasets.record_dataset(**request)
    assert not (tmp_path / "out").exists()


def test_a_failing_episode_leaves_nothing_behind(tmp_path, monkeypatch):
    class FailsInSecondEpisode:
        def __init__(self, agent):
            self.agent, self.resets = agent, 0

        def reset(self, seed=None):
            self.resets += 1
            self.agent.reset(seed)

        def act(self, obs, info):
            if self.resets == 2:
                raise FloatingPointError("diverged")
            return self.agent.act(obs, info)

    monkeypatch.setattr(datasets, "make_agent",
                        lambda name, env: FailsInSecondEpisode(make_agent(name, env)))
    out = tmp_path / "new" / "datasets"
    with pytest.raises(datasets.RecordingError, match=r"episode 1 \(seed 11\).*diverged"):
        datasets.record_dataset("pd-state", "DockingStation-v2", episodes=2, first_seed=10,
                                out=out, env_kwargs={"time_limit": 0.5})
    assert not (tmp_path / "new").exists()


def test_command_line_refuses_an_existing_dataset_unless_overwrite(tmp_path, capsys,
                                                                   monkeypatch):
    out = tmp_path / "datasets"
    dataset_id = "auv_envs/DockingStation-v2/pd-state-state-paper-v0"
    command = ["record", "--agent", "pd-state", "--env", "auv_envs/DockingStation-v2",
               "--episodes", "1", "--env-kwargs", "time_limit=0.5", "--out", str(out)]
    assert datasets.main(command) == 0
    assert f"wrote 1 episodes (5 steps) as {dataset_id}" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        datasets.main(command)
    assert exit_info.value.code == 2
    assert "already exists" in capsys.readouterr().err
    # --overwrite replaces it; seeds reaching the held-out range are warned about.
    last = seeds.TRAIN_EVAL_SEED_BASE
    with pytest.warns(UserWarning, match=f"seeds {last - 1}-{last} reach {last}"):
        assert datasets.main([*command, "--overwrite", "--episodes", "2",
                              "--first-seed", str(last - 1)]) == 0
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    dataset = minari.load_dataset(dataset_id)
    assert dataset.total_episodes == 2
    assert dataset.storage.metadata["auv_envs"]["first_seed"] == last - 1
    assert sorted(p.name for p in out.iterdir()) == ["auv_envs"]  # no staging left
    for argv, match in [(["--agent", "pd-state", "--env", "NoSuchEnv-v0"], "unknown env"),
                        (["--agent", "pd-state", "--env", "DockingStation-v2", "--obs-mode",
                          "features"], "does not apply"),
                        (["--agent", "pd-state", "--env", "DockingStation-v2", "--episodes",
                          "0"], "positive"),
                        (["--agent", "pd-state", "--env", "DockingStation-v2",
                          "--env-kwargs", "colour=red"], "colour")]:
        with pytest.raises(SystemExit) as exit_info:
            datasets.main(["record", *argv, "--out", str(tmp_path / "other")])
        assert exit_info.value.code == 2
        assert match in capsys.readouterr().err
    assert not (tmp_path / "other").exists()
