"""What every environment shares: the episode loop (:class:`TaskEnv`), argument checks,
action validation, pickling, the episode summary on an outside time limit.

A task family subclasses :class:`TaskEnv` and supplies the hooks that make it
that task (draw an episode, simulate one period, score it, observe it, report
it); the loop around them (reset, step, render, close, the done guard,
time-limit truncation, the reward-term dict, pickling) is written once, here.
"""

from __future__ import annotations

import abc
import copy
import dataclasses
import importlib
import math
import sys
from collections.abc import Iterable
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from auv_envs.core import difficulty as levels
from auv_envs.core import task
from auv_envs.core.ops import FLOATS, Backend

#: Everything mj_step reads that is not derived: time, qpos, qvel, act,
#: qacc_warmstart, ctrl, applied forces, mocap poses, equality flags, userdata.
_INTEGRATION_STATE = mujoco.mjtState.mjSTATE_INTEGRATION

_FLOAT_MAX = sys.float_info.max


def check_choice(name: str, value, valid: Iterable) -> None:
    """Raise ``ValueError`` naming the valid values when ``value`` is not one of them."""
    valid = tuple(valid)
    if value not in valid:
        raise ValueError(f"unknown {name} {value!r}; valid values: {', '.join(map(repr, valid))}")


def reject_unknown_kwargs(unknown: dict, valid: Iterable[str], env_name: str) -> None:
    """Raise ``TypeError`` listing the valid keywords when unknown ones were passed."""
    if unknown:
        raise TypeError(
            f"{env_name} got unknown argument(s) {', '.join(sorted(unknown))}; "
            f"valid arguments: {', '.join(sorted(valid))}"
        )


def check_positive_int(name: str, value) -> int:
    """``value`` when it is an ``int`` of at least 1 (not a bool), else ``ValueError``."""
    if isinstance(value, bool) or not (isinstance(value, int) and value >= 1):
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return value


def check_image_size(image_size, name: str = "image_size") -> tuple[int, int]:
    """``(width, height)`` of an ``image_size``-like argument called ``name``; ``ValueError``
    unless it is two whole sizes of at least 8 pixels."""
    try:
        width, height = (int(v) for v in tuple(image_size))
        whole = all(float(v) == int(v) for v in image_size)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be (width, height), got {image_size!r}") from exc
    if not whole:
        raise ValueError(f"{name} must be whole pixels, got {image_size!r}")
    if width < 8 or height < 8:
        raise ValueError(f"{name} must be at least 8x8 pixels, got {width}x{height}")
    return width, height


#: What a NumPy dtype kind is, for the message refusing an action of that kind.
_KINDS = {"b": "booleans", "c": "complex numbers", "O": "Python objects", "U": "text",
          "S": "bytes", "M": "dates", "m": "time spans", "V": "raw bytes"}


def action_array(action, shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as a new float64 array of ``shape``; ``ValueError`` saying what was
    given when it is ``None``, not real numbers (complex, booleans, text, objects) or
    of another shape. The first half of the one action rule (:func:`clip_actions`)."""
    if action is None:
        raise ValueError(f"action is None; expected real numbers of shape {shape}")
    try:
        raw = np.asarray(action)
    except ValueError as exc:  # ragged nesting
        raise ValueError(f"action {action!r:.80} is not an array of shape {shape}: "
                         f"{exc}") from exc
    if raw.dtype.kind not in "iuf":
        raise ValueError(f"action must be real numbers, got "
                         f"{_KINDS.get(raw.dtype.kind, raw.dtype)} ({raw.dtype}): {action!r:.80}")
    if raw.shape != shape:
        raise ValueError(f"action has shape {raw.shape}, expected {shape}")
    return np.array(raw, dtype=np.float64)  # always a copy: never alias the caller's array


def clip_actions(a: np.ndarray, space: spaces.Box) -> np.ndarray:
    """The one action rule's second half, for the CPU and the batched envs alike: NaN or
    inf anywhere raises ``ValueError``; finite values outside the bounds are clipped to
    them (in place, in float64, before any cast, so 1e300 clips as 2.0 does)."""
    # min/max propagate NaN, and are finite only if every entry is.
    if not (math.isfinite(a.min()) and math.isfinite(a.max())):
        raise ValueError(f"action must be finite, got {a.tolist()!r:.200}")
    np.clip(a, space.low, space.high, out=a)
    return a


class ActionValidator:
    """Checks and clips actions for one fixed Box space (an env builds it once).

    The rule of every ``auv_envs`` env, CPU and batched (:func:`action_array`,
    :func:`clip_actions`): real numbers of the space's shape; non-finite
    entries raise ``ValueError``; finite out-of-range entries are clipped to
    the bounds. The bounds are read into Python floats here, not on every step.
    """

    def __init__(self, space: spaces.Box):
        self.space = space
        self._bounds = tuple(zip(space.low.ravel().tolist(), space.high.ravel().tolist(),
                                 strict=True))

    def __call__(self, action) -> np.ndarray:
        a = action_array(action, self.space.shape)
        # Fast path, in Python floats (a handful of NumPy reductions cost more than
        # the env's physics): every entry finite and inside its bounds. NaN fails
        # every comparison and +-inf fails the finite range, so both take the slow path.
        for x, (low, high) in zip(a.ravel().tolist(), self._bounds, strict=True):
            if not (low <= x <= high and -_FLOAT_MAX <= x <= _FLOAT_MAX):
                break
        else:
            return a
        return clip_actions(a, self.space)


def validate_action(action, space: spaces.Box) -> np.ndarray:
    """:class:`ActionValidator` for a single call (the envs keep one per action space)."""
    return ActionValidator(space)(action)


def get_physics_state(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """A copy of the full integration state of ``data`` (``mj_getState``)."""
    state = np.empty(mujoco.mj_stateSize(model, _INTEGRATION_STATE))
    mujoco.mj_getState(model, data, state, _INTEGRATION_STATE)
    return state


def set_physics_state(model: mujoco.MjModel, data: mujoco.MjData, state: np.ndarray) -> None:
    """Restore a :func:`get_physics_state` copy and recompute the derived quantities."""
    mujoco.mj_setState(model, data, state, _INTEGRATION_STATE)
    mujoco.mj_forward(model, data)  # leaves the integration state (warm start too) unchanged


class ReconstructingPickleMixin:
    """Pickle a task as its constructor arguments plus its explicit run-time state.

    The class must record its arguments in ``__init__`` with
    :meth:`_accept_arguments` (or set ``self._init_kwargs``). The run-time
    state is, by default, MuJoCo's integration state of ``self.physics``
    (an object with ``model`` and ``data``, or None) plus a deep copy of
    ``self._episode`` (everything else that changes during an episode); a
    class that keeps more overrides ``_get_runtime_state()`` /
    ``_set_runtime_state(state)`` and calls these. MuJoCo models, data and
    renderers are rebuilt rather than pickled.
    """

    def _accept_arguments(self, unknown: dict, **arguments) -> None:
        """Record the constructor ``arguments`` and check the ones every env shares.

        Sets ``self._init_kwargs`` (what pickling rebuilds the env from); unknown
        keywords raise ``TypeError`` listing the valid ones; ``obs_mode`` must be
        one of the class's ``obs_modes`` and ``render_mode`` None or one of
        ``metadata["render_modes"]`` (``ValueError`` naming the valid values).
        """
        self._init_kwargs = dict(arguments)
        reject_unknown_kwargs(unknown, arguments, type(self).__name__)
        check_choice("obs_mode", arguments["obs_mode"], self.obs_modes)
        check_choice(
            "render_mode", arguments["render_mode"], (None, *self.metadata["render_modes"])
        )

    def _configuration(self, kind: type, **changes):
        """The family's configuration ``kind`` (a dataclass) of the arguments
        :meth:`_accept_arguments` recorded, those it has fields for (the rendering ones are
        the shell's), with ``changes``."""
        names = {field.name for field in dataclasses.fields(kind)}
        recorded = {name: value for name, value in self._init_kwargs.items() if name in names}
        return kind(**{**recorded, **changes})

    def _get_runtime_state(self) -> dict:
        physics = self.physics
        return {
            "physics": None if physics is None else get_physics_state(physics.model,
                                                                      physics.data),
            "episode": copy.deepcopy(self._episode),
        }

    def _set_runtime_state(self, state: dict) -> None:
        physics = self.physics
        if physics is not None:
            set_physics_state(physics.model, physics.data, state["physics"])
        self._episode = copy.deepcopy(state["episode"])

    def __getstate__(self):
        rng = getattr(self, "rng", None)
        return {
            "init_kwargs": dict(self._init_kwargs),
            "rng_state": None if rng is None else rng.bit_generator.state,
            "runtime": self._get_runtime_state(),
        }

    def __setstate__(self, state):
        self.__init__(**state["init_kwargs"])
        if state["rng_state"] is not None:
            rng = np.random.Generator(np.random.PCG64())
            rng.bit_generator.state = state["rng_state"]
            self.rng = rng
        self._set_runtime_state(state["runtime"])


@dataclasses.dataclass
class ShellEpisode:
    """A task's hold on an episode of its transition: its typed state and what the
    transition's last call returned (the observation, the judgement) for its hooks."""

    state: Any = None
    obs: Any = None
    judged: Any = None

    @property
    def steps(self) -> int:
        return 0 if self.state is None else self.state.steps


_REQUIRED_CLASS_ATTRIBUTES = ("obs_modes", "reward_terms", "metric_keys")


class CPUTask(ReconstructingPickleMixin, abc.ABC):
    """A task family on the CPU: what the one Gymnasium env, :class:`TaskEnv`, runs.

    The design is dm_control's (one ``Environment`` running a ``Task``'s hooks): a task
    is everything that makes the family that family (its model, plant, renderers, its
    observation, info and summary), the env the loop around it, written once.

    **What a task declares** (checked when the class is defined):
    ``obs_modes`` (the ``obs_mode`` values it offers, the first the default),
    ``reward_terms`` (the names of the terms that sum to the reward, each
    reported as ``info["reward_<term>"]``), ``metric_keys`` (the ``info``
    keys with the task's metrics at every step), ``difficulty_presets`` (the
    keywords each level of :mod:`auv_envs.core.difficulty` sets; the shipped
    families resolve ``difficulty`` in their configuration's ``params``
    (``auv_envs/tasks/<family>/config.py``), a new task may with
    :meth:`_apply_difficulty`), ``metadata`` (Gymnasium's: ``render_modes``,
    ``render_fps``). Its ``__init__`` takes the env's arguments (``render_mode``
    among them), records them (:meth:`_accept_arguments`) and sets ``calibration``
    (what an agent may know), ``physics`` (the MuJoCo model and data with named
    accessors), ``action_space``, ``observation_space``, ``dt``,
    ``max_episode_steps`` and ``_episode`` (everything else an episode changes, with
    ``steps``).

    **Hooks** (the truth is a dict the task computes once a step and shares
    between them):

    * :meth:`begin_episode` ``(rng, options) -> (truth, extras)``: draw the
      episode from ``rng`` (held as :attr:`rng` for the episode's later draws),
      place the physics; ``extras`` are added to the reset ``info``.
    * :meth:`simulate` ``(action) -> truth``: one control period (counts
      ``_episode.steps``); by default one step of the task's ``transition``
      (:mod:`auv_envs.core.task`) from the plant's MuJoCo data, the action as
      :meth:`command` gives it.
    * :meth:`assess` ``(truth, action) -> (terms, terminated)``: the reward
      terms (a dict in ``reward_terms`` order) and whether the episode ended
      in success or failure; by default the transition's judgement.
    * :meth:`observe` ``(truth)``, :meth:`step_info` ``(truth)`` (without
      the reward terms, which the loop adds), :meth:`summarise`
      ``(truth)``, :meth:`truth_now` ``()`` (the truth now, for the summary
      of an episode cut short), :meth:`render_frame` ``()``.

    ``close`` closes the attributes named in ``_closeables``.
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 30}
    obs_modes: ClassVar[tuple[str, ...]]
    reward_terms: ClassVar[tuple[str, ...]]
    metric_keys: ClassVar[tuple[str, ...]]
    difficulty_presets: ClassVar[dict[str, dict[str, Any]]]
    #: Attributes holding renderers or plots, closed (and set to None) by :meth:`close`.
    _closeables: ClassVar[tuple[str, ...]] = ()
    #: The task's plant on the CPU (the transition's ``Backend.plant``).
    _plant: Any = None
    #: The task's transition (``auv_envs/tasks/<family>/transition.py``), which
    #: :meth:`simulate` steps.
    transition: ClassVar[Any] = None
    #: :meth:`_backend`'s last value (rebuilt when the generator changes).
    _backend_cache: Backend | None = None
    #: The episode's generator (given to :meth:`begin_episode`; None before the first).
    rng: np.random.Generator | None = None
    render_mode: str | None = None

    #: What an agent may know about the task (camera, layout, nominal model...), read-only.
    calibration: Any
    #: The MuJoCo model and data with the task's named accessors.
    physics: Any
    #: Control period, s (one env step).
    dt: float
    #: Steps of an episode that runs to its time limit.
    max_episode_steps: int
    observation_space: spaces.Space
    action_space: spaces.Space

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for name in _REQUIRED_CLASS_ATTRIBUTES:
            value = getattr(cls, name, None)
            if not (isinstance(value, tuple) and value
                    and all(isinstance(v, str) and v for v in value)):
                raise TypeError(f"{cls.__name__}.{name} must be a non-empty tuple of names, "
                                f"got {value!r}")
        presets = getattr(cls, "difficulty_presets", None)
        if not isinstance(presets, dict):
            raise TypeError(f"{cls.__name__}.difficulty_presets must be a dict of levels")
        levels.check_presets(presets)

    @classmethod
    def preset(cls, level: str) -> dict[str, Any]:
        """The keywords ``difficulty=level`` sets (a copy), to start a variation from."""
        check_choice("difficulty", level, cls.difficulty_presets)
        return dict(cls.difficulty_presets[level])

    def _apply_difficulty(self, difficulty: str, **given) -> dict[str, Any]:
        """Set ``self.difficulty`` and return the keywords ``given`` with every one left
        None filled from the level's preset (:func:`auv_envs.core.difficulty.resolve`)."""
        resolved = levels.resolve(self.difficulty_presets, difficulty, given)
        #: The difficulty level (:mod:`auv_envs.core.difficulty`).
        self.difficulty = difficulty
        return resolved

    def close(self):
        for name in self._closeables:
            closeable = getattr(self, name, None)
            if closeable is not None:
                closeable.close()
            setattr(self, name, None)

    def _backend(self, rng: np.random.Generator) -> Backend:
        """The CPU backend of the task's transition: Python floats, ``rng`` (the episode's
        generator) and ``_plant``; built once per generator."""
        backend = self._backend_cache
        if backend is None or backend.draws is not rng:
            backend = self._backend_cache = Backend(FLOATS, rng, self._plant)
        return backend

    # ------------------------------------------------------------------ the hooks
    def begin_episode(self, rng: np.random.Generator, options: dict | None) -> tuple[dict, dict]:
        """Draw a new episode from ``rng``; return its first truth and extra reset info.
        Holds ``rng`` as :attr:`rng` and calls :meth:`_begin_episode`."""
        self.rng = rng
        return self._begin_episode(rng, options)

    @abc.abstractmethod
    def _begin_episode(self, rng: np.random.Generator, options: dict | None) -> tuple[dict, dict]:
        """The family's start of an episode (:meth:`begin_episode`)."""

    def simulate(self, action: np.ndarray) -> dict:
        """Apply the (validated) action for one control period; return the truth after it:
        the task's ``transition.step`` from the plant's state (the physics' MuJoCo data),
        its episode state, observation and judgement kept in ``_episode``."""
        ep = self._episode
        stepped = self.transition.step(self.params, self.physics.data, ep.state,
                                       self.command(action), self._backend(self.rng))
        ep.state, ep.obs, ep.judged = stepped.episode, stepped.obs, stepped.judged
        return stepped.truth

    def command(self, action: np.ndarray):
        """The validated action as the transition takes it (the array itself)."""
        return action

    def assess(self, truth: dict, action: np.ndarray) -> tuple[dict, bool]:
        """The reward terms (in ``reward_terms`` order) and whether the episode terminated:
        the transition's judgement of the step."""
        judged = self._episode.judged
        return judged.terms, judged.terminated

    @abc.abstractmethod
    def observe(self, truth: dict):
        """The observation of ``obs_mode``."""

    @abc.abstractmethod
    def step_info(self, truth: dict) -> dict:
        """The step's ``info`` without the reward terms."""

    @abc.abstractmethod
    def truth_now(self) -> dict:
        """The truth now (for the summary of an episode cut short)."""

    @abc.abstractmethod
    def summarise(self, truth: dict) -> dict:
        """The episode's summary."""

    @abc.abstractmethod
    def render_frame(self):
        """The ``render_mode="rgb_array"`` frame."""


def load_task(task) -> type[CPUTask]:
    """``task`` (a :class:`CPUTask` subclass, or its ``"module:Class"`` path) as a class."""
    if isinstance(task, str):
        module, _, name = task.partition(":")
        try:
            task = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError, ValueError) as exc:
            raise ValueError(f"no task {task!r}: {exc}") from exc
    if not (isinstance(task, type) and issubclass(task, CPUTask)):
        raise TypeError(f"task must be a CPUTask subclass or its 'module:Class' path, "
                        f"got {task!r}")
    return task


class TaskEnv(gym.Env):
    """The Gymnasium environment of every ``auv_envs`` task: one class, the task its part.

    ``gym.make("auv_envs/DockingStation-v2", ...)`` builds
    ``TaskEnv(task="auv_envs.tasks.docking.env:DockingStationTask", ...)`` (the family
    table, :data:`auv_envs.families.FAMILIES`, names each id's task); any other
    :class:`CPUTask` runs the same way, ``TaskEnv(MyTask, **arguments)``.

    Args:
        task: the task's class (a :class:`CPUTask`) or its ``"module:Class"`` path.
        render_mode: None or ``"rgb_array"``.
        **arguments: the task's arguments (its class's docstring lists them).

    The loop: ``step`` validates the action (finite values outside the space are
    clipped, NaN or inf raise ``ValueError``), refuses to run after the episode ended,
    sums the terms in order, truncates after ``max_episode_steps`` and puts the episode's
    summary in the last step's ``info["episode_metrics"]``. The task is :attr:`task`;
    its own attributes and methods (``physics``, ``lights_in_view()``, ``plot``...) are
    read through the env as well (``env.unwrapped.physics`` is
    ``env.unwrapped.task.physics``). Pickled as the task's arguments and its episode.
    """

    metadata = CPUTask.metadata

    def __init__(self, task, render_mode: str | None = None, **arguments):
        task_class = load_task(task)
        self._adopt(task_class(render_mode=render_mode, **arguments))

    def _adopt(self, task_: CPUTask) -> None:
        """Run ``task_``: its spaces, metadata and render mode become the env's."""
        #: The task this env runs (a :class:`CPUTask`).
        self.task = task_
        self.metadata = task_.metadata
        self.render_mode = task_.render_mode
        self.observation_space = task_.observation_space
        self.action_space = task_.action_space
        self._validate_action = ActionValidator(self.action_space)
        self._reward_keys = tuple(f"reward_{name}" for name in task_.reward_terms)
        self._done = False

    def __getattr__(self, name: str):
        # The task's attributes, read through the env (class docstring); only reached for
        # names the env itself lacks.
        if name == "task" or name.startswith("__"):
            raise AttributeError(name)
        try:
            return getattr(self.task, name)
        except AttributeError:
            raise AttributeError(f"{type(self).__name__} (task {type(self.task).__name__}) "
                                 f"has no attribute {name!r}") from None

    # ------------------------------------------------------------------ the loop
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        truth, extras = self.task.begin_episode(self.np_random, options)
        self._done = False
        obs = self.task.observe(truth)
        info = self.task.step_info(truth)
        for key in self._reward_keys:
            info[key] = 0.0
        info.update(extras)
        return obs, info

    def step(self, action):
        a = self._validate_action(action)
        if self._done:
            raise RuntimeError("step() called after the episode ended; call reset()")
        task_ = self.task
        truth = task_.simulate(a)
        terms, terminated = task_.assess(truth, a)
        reward = float(task.reward(terms))
        truncated = bool(task.truncated(terminated, task_._episode.steps,
                                        task_.max_episode_steps, FLOATS))
        self._done = terminated or truncated
        obs = task_.observe(truth)
        info = task_.step_info(truth)
        for key, value in zip(self._reward_keys, terms.values(), strict=True):
            info[key] = float(value)
        if self._done:
            info["episode_metrics"] = task_.summarise(truth)
        return obs, reward, terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self.task.render_frame()

    def close(self):
        self.task.close()

    def episode_metrics(self) -> dict:
        """The episode's summary so far: what ``info["episode_metrics"]`` holds at its end.

        Read by :class:`EpisodeSummary` when a time limit outside the env
        (``gym.make(..., max_episode_steps=N)``) truncates the episode.
        """
        return self.task.summarise(self.task.truth_now())

    def __getstate__(self):
        rng = self._np_random
        return {"task": self.task, "done": self._done, "spec": self.spec,
                "rng_state": None if rng is None else rng.bit_generator.state,
                "rng_seed": self._np_random_seed}

    def __setstate__(self, state):
        task_ = state["task"]
        self._adopt(task_)
        self._done, self.spec = state["done"], state["spec"]
        if state["rng_state"] is not None:
            if task_.rng is not None and task_.rng.bit_generator.state == state["rng_state"]:
                self._np_random = task_.rng  # one generator, the env's and the episode's
            else:
                rng = np.random.Generator(np.random.PCG64())
                rng.bit_generator.state = state["rng_state"]
                self._np_random = rng
            self._np_random_seed = state["rng_seed"]


class EpisodeSummary(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Puts the episode's summary in ``info`` when a wrapper below truncated the episode.

    Every ``auv_envs`` env writes ``info["episode_metrics"]`` on the step that
    ends its episode, including truncation at its own ``time_limit``. Each id
    also registers that limit as ``max_episode_steps``, so Gymnasium's
    ``TimeLimit`` (which ``gym.make`` puts below this wrapper) truncates on the
    same step. When ``gym.make(id, max_episode_steps=N)`` asks for a shorter
    episode, ``TimeLimit`` truncates first and the env has written no summary;
    this wrapper then adds ``env.unwrapped.episode_metrics()``, so an episode
    truncated from outside is summarised like one the env truncated itself.

    The other way round, an env built with a longer ``time_limit`` than its
    default (``gym.make(id, time_limit=200)``) lengthens the ``TimeLimit``
    below to its own ``max_episode_steps`` when that limit is still the
    registered default: the env's keyword sets its episode length, and an
    explicit ``max_episode_steps=N`` still wins.
    """

    def __init__(self, env: gym.Env):
        # Recorded (no arguments) in the env's spec, so gym.make(env.spec) rebuilds it.
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        unwrapped = env.unwrapped
        if unwrapped.spec is None:
            return
        registered = gym.spec(unwrapped.spec.id).max_episode_steps
        own = unwrapped.max_episode_steps
        layer = env
        while isinstance(layer, gym.Wrapper):
            if isinstance(layer, gym.wrappers.TimeLimit):
                # TimeLimit keeps its limit in this attribute (Gymnasium 1.x).
                if layer._max_episode_steps == registered and own != registered:
                    layer._max_episode_steps = own
                    layer._cached_spec = None
                break
            layer = layer.env

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if (terminated or truncated) and "episode_metrics" not in info:
            info = {**info, "episode_metrics": self.env.unwrapped.episode_metrics()}
        return obs, reward, terminated, truncated, info
