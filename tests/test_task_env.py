"""The one Gymnasium env (auv_envs.core.env.TaskEnv) and the task protocol it runs
(CPUTask), on a toy task.

The toy task moves a point along a line by the action; its terms are a
progress reward and a constant cost, it succeeds within 0.1 of the goal and
fails beyond 5 from it. The real tasks' behaviour through the same loop is
pinned by their seeded rollouts (test_envs_generic.py, test_difficulty.py).
"""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np
import pytest
from gymnasium import spaces

from auv_envs.core.env import CPUTask, TaskEnv

PRESETS = {"easy": {}, "paper": {"noise": 0.1}, "hard": {"noise": 0.3}}


@dataclasses.dataclass
class _Episode:
    steps: int = 0
    done: bool = False
    position: float = 0.0
    path: float = 0.0


class LineTask(CPUTask):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    obs_modes = ("state",)
    reward_terms = ("progress", "cost")
    metric_keys = ("distance",)
    difficulty_presets = PRESETS
    _closeables = ("canvas",)

    def __init__(self, obs_mode="state", render_mode=None, max_steps=5, noise=None,
                 difficulty="easy", **unknown):
        self._accept_arguments(unknown, obs_mode=obs_mode, render_mode=render_mode,
                               max_steps=max_steps, noise=noise, difficulty=difficulty)
        self.noise = self._apply_difficulty(difficulty, noise=noise)["noise"] or 0.0
        self.obs_mode, self.render_mode = obs_mode, render_mode
        self.calibration = {"goal": 1.0}
        self.physics = None
        self.dt, self.max_episode_steps = 1.0, max_steps
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)
        self.canvas = _Canvas()
        self._episode = _Episode()

    def _begin_episode(self, rng, options):
        self._episode = _Episode(position=float(rng.uniform(-0.5, 0.5)))
        return self.truth_now(), {"start": self._episode.position}

    def simulate(self, action):
        self._episode.position += float(action[0])
        self._episode.path += abs(float(action[0]))
        self._episode.steps += 1
        return self.truth_now()

    def assess(self, truth, action):
        before = truth["distance"] + abs(float(action[0]))
        terms = {"progress": before - truth["distance"], "cost": -0.5}
        return terms, truth["distance"] < 0.1 or truth["distance"] > 5.0

    def observe(self, truth):
        return np.array([self._episode.position], dtype=np.float32)

    def step_info(self, truth):
        return {"distance": truth["distance"]}

    def truth_now(self):
        return {"distance": abs(self.calibration["goal"] - self._episode.position)}

    def summarise(self, truth):
        return {"steps": self._episode.steps, "path": self._episode.path,
                "final_distance": truth["distance"]}

    def render_frame(self):
        return np.zeros((4, 4, 3), dtype=np.uint8)


def Line(**arguments) -> TaskEnv:  # noqa: N802  (reads as the env it builds)
    return TaskEnv(LineTask, **arguments)


class _Canvas:
    closed = 0

    def close(self):
        _Canvas.closed += 1


def test_reset_reports_zero_terms_and_the_tasks_extras():
    env = Line()
    obs, info = env.reset(seed=3)
    assert info["reward_progress"] == 0.0 and info["reward_cost"] == 0.0
    assert info["start"] == pytest.approx(float(obs[0]))
    assert "episode_metrics" not in info


def test_step_sums_the_terms_in_order_and_reports_each():
    env = Line()
    env.reset(seed=3)
    _, reward, terminated, truncated, info = env.step(np.array([0.25], np.float32))
    assert reward == info["reward_progress"] + info["reward_cost"]
    assert info["reward_cost"] == -0.5
    assert not terminated and not truncated


def test_truncation_after_max_episode_steps_with_the_summary():
    env = Line(max_steps=3)
    env.reset(seed=3)
    outcomes = [env.step(np.zeros(1, np.float32)) for _ in range(3)]
    assert [o[3] for o in outcomes] == [False, False, True]
    assert not any(o[2] for o in outcomes)
    assert outcomes[-1][4]["episode_metrics"] == {"steps": 3, "path": 0.0,
                                                  "final_distance": outcomes[-1][4]["distance"]}
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, np.float32))
    env.reset(seed=4)
    env.step(np.zeros(1, np.float32))  # a new episode steps again


def test_termination_wins_over_truncation_on_the_same_step():
    env = Line(max_steps=2)
    obs, _ = env.reset(seed=3)
    obs, _, terminated, truncated, _ = env.step(np.array([0.5], np.float32))
    assert not terminated and not truncated
    to_goal = np.array([1.0 - float(obs[0])], np.float32)  # the second step reaches the goal
    _, _, terminated, truncated, info = env.step(to_goal)
    assert terminated and not truncated and "episode_metrics" in info


def test_actions_are_clipped_and_non_finite_ones_refused():
    env = Line()
    start, _ = env.reset(seed=0)
    obs, *_ = env.step(np.array([7.0], np.float32))
    assert float(obs[0]) == pytest.approx(float(start[0]) + 1.0)  # clipped to the bound
    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([bad], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(2, np.float32))


def test_render_and_close():
    assert Line().render() is None
    env = Line(render_mode="rgb_array")
    assert env.render().shape == (4, 4, 3)
    closed = _Canvas.closed
    env.close()
    env.close()  # twice: no error
    assert _Canvas.closed == closed + 1 and env.canvas is None


def test_episode_metrics_mid_episode():
    env = Line()
    env.reset(seed=1)
    env.step(np.array([0.5], np.float32))
    assert env.episode_metrics()["steps"] == 1


def test_difficulty_presets_resolve_and_explicit_keywords_win():
    assert Line().noise == 0.0 and Line(difficulty="hard").noise == 0.3
    assert Line(difficulty="hard", noise=0.05).noise == 0.05
    assert Line(difficulty="paper").difficulty == "paper"
    with pytest.raises(ValueError, match="difficulty"):
        Line(difficulty="medium")
    preset = LineTask.preset("hard")
    preset["noise"] = 9.0  # a copy: the class's preset is untouched
    assert LineTask.preset("hard") == {"noise": 0.3}
    with pytest.raises(ValueError, match="difficulty"):
        LineTask.preset("medium")


def test_unknown_keyword_is_refused():
    with pytest.raises(TypeError, match="valid arguments"):
        Line(colour="red")


def _task(**attributes):
    body = {"obs_modes": ("state",), "reward_terms": ("r",), "metric_keys": ("m",),
            "difficulty_presets": PRESETS, **attributes}
    return type("Task", (CPUTask,), body)


@pytest.mark.parametrize("name", ["obs_modes", "reward_terms", "metric_keys"])
@pytest.mark.parametrize("value", [None, (), "state", ("a", 3)])
def test_a_task_must_declare_its_contract(name, value):
    with pytest.raises(TypeError, match=name):
        _task(**{name: value})


def test_a_task_must_declare_all_three_levels():
    with pytest.raises(TypeError, match="difficulty_presets"):
        _task(difficulty_presets=None)
    with pytest.raises(ValueError, match="presets must be given"):
        _task(difficulty_presets={"easy": {}, "paper": {}})
    with pytest.raises(ValueError, match="easy"):
        _task(difficulty_presets={"easy": {"noise": 1.0}, "paper": {}, "hard": {}})


def test_a_task_without_its_hooks_cannot_be_built():
    with pytest.raises(TypeError, match="abstract"):
        _task()()


def test_the_env_runs_a_task_named_by_its_path_and_refuses_others():
    env = TaskEnv(f"{__name__}:LineTask", max_steps=4)
    assert isinstance(env.task, LineTask) and env.max_episode_steps == 4
    assert env.metadata["render_fps"] == 10
    with pytest.raises(ValueError, match="no task"):
        TaskEnv(f"{__name__}:NoSuchTask")
    with pytest.raises(TypeError, match="CPUTask"):
        TaskEnv(dict)


def test_the_tasks_attributes_read_through_the_env():
    env = Line(difficulty="hard")
    assert env.noise == 0.3 and env.calibration == {"goal": 1.0}
    with pytest.raises(AttributeError, match="colour"):
        env.colour  # noqa: B018


def test_a_pickled_env_goes_on_as_the_original():
    env = Line(max_steps=50)
    env.reset(seed=5)
    env.step(np.array([0.1], np.float32))
    twin = pickle.loads(pickle.dumps(env))
    same = copy.deepcopy(env)
    for other in (twin, same):
        assert other.np_random is other.task.rng  # one generator: the env's and the episode's
    action = np.array([0.2], np.float32)
    first = [env.step(action)[:2] for _ in range(3)]
    assert [twin.step(action)[:2] for _ in range(3)] == first
    assert [same.step(action)[:2] for _ in range(3)] == first
    assert twin.reset()[0] == env.reset()[0]  # the generator's state travelled too
