"""The batched environment: one shell, :class:`FunctionalEnv`, for every family's task.

A batched environment is a task's transition (``auv_envs/tasks/<family>/transition.py``)
evaluated on JAX arrays by the family's JAX task (``auv_envs/tasks/<family>/jax_task.py``,
named in :data:`auv_envs.families.FAMILIES`): :class:`FunctionalEnv` serves every one of
them (its spaces, its conventions, the end of a step, Playground's ``MjxEnv``
interface), :class:`State` is what its ``reset``/``step`` return (as MuJoCo Playground's
``mjx_env.State``), :class:`KeyDraws` the episode's random draws with NumPy
``Generator``'s interface over a JAX key, and :class:`World` the model a domain
randomiser varies.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from auv_envs.core import task
from auv_envs.core.cache import user_cache
from auv_envs.families import Family, family

#: MuJoCo's integrators by their MJCF names (``mjtIntegrator``'s order).
_INTEGRATOR_NAMES = ("Euler", "RK4", "implicit", "implicitfast")

#: The keys of an observation with the privileged state beside it (MuJoCo Playground's:
#: Brax's PPO takes them as ``policy_obs_key`` and ``value_obs_key``).
POLICY_KEY, PRIVILEGED_KEY = "state", "privileged_state"


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class State:
    """One environment's state (a batch of them under ``vmap``), as Playground's: frozen,
    changed by :meth:`replace` only.

    Attributes:
        data: everything the episode is: ``{"plant": ..., "episode": ...}``, the plant's
            state (docking: ``{"qpos": (7,), "qvel": (6,)}``; LARS: the arm's
            ``mjx.Data``; acoustic: the rig's) and the transition's ``EpisodeState``.
            Restoring ``data`` (and ``obs``) restarts an episode, as Playground's
            auto-reset does with a cached first state.
        obs: the observation (an array for ``state``, a dict for ``features``; a flat
            vector under Playground's conventions; with ``privileged``,
            ``{"state": <that>, "privileged_state": <the state-mode vector>}``).
        reward: the last step's reward.
        done: whether the last step ended the episode (terminated or truncated).
        metrics: the last step's metrics (the environment's ``STEP_METRICS``), its
            reward terms (``reward_<term>``) and the episode's summary so far
            (``episode_*``), with any keys a wrapper added kept.
        info: ``rng`` (the key of the step's draws), ``terminated``, ``truncation`` and
            ``final_obs`` (the observation that ended the episode; the present one
            otherwise), with any keys a wrapper added kept.
    """

    data: dict
    obs: object
    reward: jax.Array
    done: jax.Array
    metrics: dict
    info: dict

    def replace(self, **changes) -> State:
        return dataclasses.replace(self, **changes)

    @property
    def episode(self):
        """The transition's ``EpisodeState``."""
        return self.data["episode"]

    @property
    def plant(self):
        """The plant's state."""
        return self.data["plant"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class World:
    """What a batched env's ``mjx_model`` is (MuJoCo Playground's name for the model a
    domain randomiser varies): MuJoCo's model on MJX and the physics MuJoCo does not model.

    Attributes:
        mjx: the env's model on MuJoCo MJX (``mjx.Model``).
        physics: the family's randomised physical parameters (a dict of float32 arrays,
            named and ranged by the family's randomiser: for docking
            :class:`auv_envs.tasks.docking.randomization.DockingRandomization`); None:
            the nominal world, the env exactly as without a randomiser.
    """

    mjx: Any
    physics: Any = None


def _camera(model, camera):
    """:meth:`FunctionalEnv.render`'s ``camera`` as ``mujoco.Renderer.update_scene`` takes
    it: -1 (the free camera) for None, a name as it is, ``(body, distance)`` as a
    ``MjvCamera`` tracking the body."""
    import mujoco

    if camera is None:
        return -1
    if isinstance(camera, str):
        return camera
    body, distance = camera
    view = mujoco.MjvCamera()
    view.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    view.trackbodyid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
    if view.trackbodyid < 0:
        raise ValueError(f"no body {body!r} to track in the model")
    view.distance, view.elevation, view.azimuth = distance, -20.0, 135.0
    return view


class KeyDraws:
    """NumPy ``Generator``'s draws (``uniform``, ``standard_normal``, ``normal``, ``random``,
    ``integers``, ``permutation``)
    over a JAX key: each call splits a fresh key off, so a transition draws as it does on
    the CPU."""

    def __init__(self, key: jax.Array):
        self.key = key

    def _next(self) -> jax.Array:
        self.key, key = jax.random.split(self.key)
        return key

    @staticmethod
    def _shape(size) -> tuple:
        return () if size is None else (size,) if isinstance(size, int) else tuple(size)

    def uniform(self, low=0.0, high=1.0, size=None) -> jax.Array:
        return jax.random.uniform(self._next(), self._shape(size), minval=low, maxval=high)

    def standard_normal(self, size=None) -> jax.Array:
        return jax.random.normal(self._next(), self._shape(size))

    def normal(self, loc=0.0, scale=1.0, size=None) -> jax.Array:
        return loc + scale * self.standard_normal(size)

    def random(self, size=None) -> jax.Array:
        return jax.random.uniform(self._next(), self._shape(size))

    def integers(self, low, high=None, size=None) -> jax.Array:
        """Integers in ``[low, high)`` (``[0, low)`` without ``high``), as NumPy's."""
        low, high = (0, low) if high is None else (low, high)
        return jax.random.randint(self._next(), self._shape(size), low, high)

    def permutation(self, x) -> jax.Array:
        return jax.random.permutation(self._next(), x)


class FunctionalEnv:
    """Any family's environment as pure JAX functions of one episode: ``reset(rng) ->
    state``, ``step(state, action) -> state``, batched by :func:`jax.vmap`
    (:class:`auv_envs.batched.vector.TransitionVectorEnv` does it and speaks NumPy to
    Gymnasium), with MuJoCo Playground's ``MjxEnv`` interface.

    Args:
        env_id: a family's id or its batched twin's (``auv_envs/DockingStation-v2``,
            ``auv_envs/LampArrayDocking-v2``, ``auv_envs/DockingMission-v0``,
            ``auv_envs/LARSCapture-v0``, ``auv_envs/AcousticTracking-v2``; the family
            table :data:`auv_envs.families.FAMILIES` lists them and the JAX task of each).
        obs_mode: one of the family's batched modes (None: its default).
        auto_reset: reset an episode inside :meth:`step` when it ends.
        privileged: observations ``{"state": <obs_mode's>, "privileged_state": <the
            family's state vector>}``, for an asymmetric critic (below).
        randomization: the domain randomiser :meth:`randomize` draws worlds with (None: the
            family's shipped one, its task's ``randomization_class``). The env simulates
            the nominal world unless given others (Playground's
            ``wrap_for_brax_training(..., randomization_fn=...)``, ``gym.make_vec(...,
            randomize=True)``).
        **env_kwargs: the family's configuration (the CPU environment's arguments:
            ``difficulty``, ``time_limit``, ...), each checked as the CPU environment checks
            it; the task is built from their parameters (:meth:`Family.setup
            <auv_envs.families.Family.setup>`), without a Gymnasium environment.

    The family's task (:attr:`task`) holds what is the family's: its parameters, its
    plant on MJX, its metrics and its state vector; it returns the transition's
    :class:`~auv_envs.core.task.Transition` and this shell makes the :class:`State` of it.
    The family's own ways to start an episode are :meth:`reset_to` (the equivalence tests
    start the CPU and the batched env alike with them).

    Two conventions. Gymnasium's (the default, what :mod:`auv_envs.batched.vector` and
    the compiled PPO use): the observation and action as the CPU env's spaces, ``done``
    a bool that includes the time limit, the episode reset inside :meth:`step` with
    ``auto_reset``. MuJoCo Playground's and Brax's (:meth:`use_playground_conventions`,
    what :func:`auv_envs.batched.load` returns): a flat float32 observation vector,
    actions in [-1, 1] (mapped affinely onto the CPU env's action box), float32
    ``done``, ``info["truncation"]`` and metrics, no time limit and no reset inside
    the env (Brax's ``EpisodeWrapper`` ends an episode at ``episode_length`` steps and
    flags it as truncation; Playground's ``BraxAutoResetWrapper`` restores ``data``).

    Either convention takes ``privileged=True`` (:meth:`_offer_privileged`), Playground's
    observation for an asymmetric critic: ``{"state": ..., "privileged_state": ...}``,
    the observation as without it beside the family's ``obs_mode="state"`` vector (the
    true state, float32), for a critic that may read what the policy may not (Brax:
    ``make_ppo_networks(..., policy_obs_key="state", value_obs_key="privileged_state")``).
    The privileged state draws nothing: an episode is the same with or without it.
    """

    def __init__(self, env_id: str, obs_mode: str | None = None, auto_reset: bool = True,
                 privileged: bool = False, randomization=None, **env_kwargs):
        entry = self._served(env_id, obs_mode)
        obs_mode = entry.batched_mode if obs_mode is None else obs_mode
        task_class = entry.jax_task_class()
        self._use_randomization(randomization, task_class.randomization_class)
        #: The family's task on JAX (``auv_envs/tasks/<family>/jax_task.py``).
        self.task = task = task_class(entry.setup(entry.env_id, obs_mode=obs_mode,
                                                  **env_kwargs))
        self.env_id, self.obs_mode, self.auto_reset = env_id, obs_mode, auto_reset
        self.params, self.plant, self.ops = task.params, task.plant, task.ops
        self.calibration = task.calibration
        self.max_episode_steps = task.max_episode_steps
        self.observation_space, self.action_space = task.observation_space, task.action_space
        self._offer_privileged(privileged)

    plant = calibration = observation_space = action_space = None
    max_episode_steps: int
    auto_reset: bool = True
    #: Playground's and Brax's conventions (:meth:`use_playground_conventions`).
    playground: bool = False
    #: Observations ``{"state": ..., "privileged_state": ...}`` (:meth:`_offer_privileged`).
    privileged: bool = False
    #: The ``privileged_state`` entry's space (a float32 ``Box``) with ``privileged``.
    privileged_space = None
    #: The CPU env's action box when actions are taken in [-1, 1] (:meth:`use_unit_actions`).
    _action_box = None

    @property
    def dt(self) -> float:
        """The control period, s (one step)."""
        return self.task.dt

    @property
    def STEP_METRICS(self) -> tuple:  # noqa: N802  (the families' constant's name)
        """``metrics`` carried every step (the family transition's ``STEP_METRICS``)."""
        return self.task.transition.STEP_METRICS

    @property
    def render_camera(self):
        """What :meth:`render` draws from by default (the family's): a camera's name, or
        ``(body, distance)``, a camera tracking the body from ``distance`` m (None:
        MuJoCo's free camera)."""
        return self.task.render_camera

    def end_reason(self, code, success) -> str:
        """The CPU env's name of an episode's end from its summary's ``failure`` code
        (the family's; a family whose episodes only time out has none)."""
        return self.task.end_reason(code, success)

    @property
    def action_size(self) -> int:
        return self.action_space.shape[0]

    @property
    def observation_size(self):
        space = self.observation_space
        if hasattr(space, "spaces"):
            return {key: value.shape for key, value in space.spaces.items()}
        return space.shape[0]

    @property
    def episode_length(self) -> int:
        """The episode length in steps (its time limit, as the CPU environment's): what
        Brax's ``ppo.train(episode_length=...)`` is given."""
        return self.max_episode_steps

    @property
    def mj_model(self):
        """The env's MuJoCo model (the task's, as the CPU env composes it; the batched
        plant's copy on MJX switches its contacts off)."""
        return self.task.mj_model

    @property
    def xml_path(self) -> str:
        """A file of :attr:`mj_model`'s MJCF, its assets beside it: the model the env
        composed from ``assets/``, with the solver options it sets (timestep, integrator),
        written once under the user's cache (``<user cache>/models``,
        :func:`auv_envs.core.cache.user_cache`). ``mujoco.MjModel.from_xml_path`` of it is
        :attr:`mj_model`."""
        model = self.mj_model
        source = self.task.model_source.with_option(
            timestep=float(model.opt.timestep),
            integrator=_INTEGRATOR_NAMES[int(model.opt.integrator)])
        return str(source.write(user_cache() / "models"))

    @property
    def model_assets(self) -> dict:
        """The assets :attr:`xml_path`'s MJCF names (file name -> bytes)."""
        return dict(self.task.model_source.assets)

    @property
    def sim_dt(self) -> float:
        """The physics timestep, s."""
        return float(self.mj_model.opt.timestep)

    @property
    def n_substeps(self) -> int:
        """Physics steps a control period."""
        return int(round(self.dt / self.sim_dt))

    def render(self, trajectory, height: int = 240, width: int = 320,
               camera: str | None = None, scene_option=None):
        """Frames of ``trajectory`` (a list of unbatched :class:`State` s, or one), as MuJoCo
        Playground's ``MjxEnv.render``: :attr:`mj_model` posed at each state's plant
        configuration, seen by ``camera`` (default :attr:`render_camera`); (height, width,
        3) uint8 arrays, a list for a list."""
        import mujoco

        states = trajectory if isinstance(trajectory, list) else [trajectory]
        model = self.mj_model
        data = mujoco.MjData(model)
        camera = self.render_camera if camera is None else camera
        frames = []
        with mujoco.Renderer(model, height=height, width=width) as renderer:
            for state in states:
                plant = state.data["plant"]
                qpos = np.asarray(plant["qpos"] if isinstance(plant, dict) else plant.qpos,
                                  dtype=np.float64)
                if qpos.shape != (model.nq,):
                    raise ValueError(f"render takes unbatched states: qpos {qpos.shape}, "
                                     f"the model's ({model.nq},)")
                data.qpos[:] = qpos
                mujoco.mj_forward(model, data)
                renderer.update_scene(data, camera=_camera(model, camera),
                                      scene_option=scene_option)
                frames.append(renderer.render())
        return frames if isinstance(trajectory, list) else frames[0]

    #: The world the env simulates (:class:`World`; Playground's domain-randomisation
    #: wrapper sets it per batch entry under ``vmap``); the nominal one on first use.
    _mjx_model: World = None
    #: The family's shipped domain randomiser (:meth:`randomize`), None where it has none.
    randomization = None

    @property
    def mjx_model(self) -> World:
        """The world the env simulates (:class:`World`): what a domain randomiser varies;
        the nominal one (the plant's model, no physics changed) unless one was set."""
        if self._mjx_model is None:
            self._mjx_model = World(self.plant.model)
        return self._mjx_model

    def randomize(self, model: World, rng: jax.Array):
        """Playground's ``randomization_fn``: ``(worlds, in_axes)``, one world per key of
        ``rng`` (keys (N, 2)) drawn by :attr:`randomization` about ``model``, and the axes
        to ``vmap`` them over. ``ppo.train(..., randomization_fn=env.randomize)`` and
        ``wrap_for_brax_training(env, randomization_fn=functools.partial(env.randomize,
        rng=keys))`` take it."""
        if self.randomization is None:
            raise NotImplementedError(f"{type(self).__name__} has no domain randomiser")
        return self.randomization(model, rng)

    def _use_randomization(self, randomization, kind: type) -> None:
        """Set :attr:`randomization`: ``randomization`` (a ``kind``), or ``kind()``'s shipped
        ranges for None."""
        if randomization is not None and not isinstance(randomization, kind):
            raise TypeError(f"randomization must be a {kind.__name__}, got {randomization!r}")
        self.randomization = kind() if randomization is None else randomization

    @property
    def unwrapped(self) -> FunctionalEnv:
        return self

    def _policy_space(self) -> gym.spaces.Space:
        """The space of the observation the policy reads: ``observation_space`` itself, or
        its ``"state"`` entry with ``privileged``."""
        return self.observation_space[POLICY_KEY] if self.privileged else self.observation_space

    @staticmethod
    def _served(env_id: str, obs_mode: str | None) -> Family:
        """The family (:data:`auv_envs.families.FAMILIES`) of ``env_id``, checked to be
        built in ``obs_mode`` (None: its default)."""
        try:
            entry = family(env_id)
        except KeyError as error:
            raise ValueError(str(error)) from None
        if env_id in entry.previous:
            raise ValueError(f"{env_id!r} is a superseded version; the batched "
                             f"{entry.name} environment builds {entry.env_id!r}")
        if obs_mode is not None and obs_mode not in entry.batched_modes:
            raise ValueError(f"the batched {entry.name} environment builds obs_mode "
                             f"{entry.batched_modes}, got {obs_mode!r}")
        return entry

    def _offer_privileged(self, privileged: bool) -> None:
        """With ``privileged``, observations become ``{"state": ..., "privileged_state":
        ...}`` (class docstring) and ``observation_space`` a ``Dict`` of the two: the space
        as without it and a float32 ``Box`` of the state-mode vector's size (read off
        what :meth:`_state_observation` gives at reset, so it cannot disagree with it).
        The family's constructor calls this last, its ``observation_space`` set.

        Raises:
            TypeError: ``privileged`` is not a bool.
        """
        if not isinstance(privileged, bool | np.bool_):
            raise TypeError(f"privileged must be True or False, got {privileged!r}")
        self.privileged = bool(privileged)
        if not self.privileged:
            return
        shape = jax.eval_shape(self.reset, jax.random.PRNGKey(0)).obs[PRIVILEGED_KEY].shape
        self.privileged_space = gym.spaces.Box(-np.inf, np.inf, shape, np.float32)
        self.observation_space = self._observation_space(self.observation_space)

    def _observation_space(self, policy_space: gym.spaces.Space) -> gym.spaces.Space:
        """The observation space around the policy's: itself, or with ``privileged`` the
        ``Dict`` of it and the privileged state's."""
        if not self.privileged:
            return policy_space
        return gym.spaces.Dict({POLICY_KEY: policy_space, PRIVILEGED_KEY: self.privileged_space})

    def use_playground_conventions(self) -> FunctionalEnv:
        """Switch to MuJoCo Playground's and Brax's conventions (class docstring): the
        policy's observation space (:meth:`_policy_space`) becomes Gymnasium's flattening of
        the CPU env's (a ``Dict``'s entries concatenated in its key order, as
        ``gymnasium.spaces.flatten``), the action space [-1, 1]; with ``privileged`` the
        observation stays a dict, its ``"state"`` entry flattened. Returns this env."""
        self.playground, self.auto_reset = True, False
        space = self._policy_space()
        self._observation_keys = tuple(space.spaces) if hasattr(space, "spaces") else None
        flat = gym.spaces.flatten_space(space)
        self.observation_space = self._observation_space(gym.spaces.Box(
            flat.low.astype(np.float32), flat.high.astype(np.float32), dtype=np.float32))
        return self.use_unit_actions()

    def use_unit_actions(self) -> FunctionalEnv:
        """Take actions in [-1, 1], mapped affinely onto the CPU env's action box (as
        Gymnasium's ``RescaleAction(env, -1, 1)``; the identity for docking and LARS,
        whose boxes are [-1, 1]). Returns this env."""
        if self._action_box is None:
            self._action_box = self.action_space
            self.action_space = gym.spaces.Box(-1.0, 1.0, self._action_box.shape, np.float32)
        return self

    # ------------------------------------------------------------------ episodes
    def reset(self, rng: jax.Array, world: World | None = None) -> State:
        """A new episode drawn from ``rng`` (the CPU env's start distribution) in ``world``
        (default :attr:`mjx_model`)."""
        world = self._world(world)
        rng, key = jax.random.split(rng)
        return self._first(rng, self.task.reset(KeyDraws(key), world))

    def _world(self, world: World | None) -> World:
        """``world``, or the env's own (:attr:`mjx_model`) for None."""
        return self.mjx_model if world is None else world

    def reset_to(self, *args, **kwargs) -> State:
        """An episode started as the family's task's ``reset_to`` says (docking: from a
        plant state; LARS: in a CPU episode's scene; acoustic: from a CPU episode's
        plan), in this env's world."""
        rng, start = self.task.reset_to(*args, world=self.mjx_model, **kwargs)
        return self._first(rng, start)

    def truth(self, state: State, world: World | None = None) -> dict:
        """The ground truth of ``state`` in ``world`` (the family's task's; docking and
        LARS)."""
        return self.task.truth(state.plant, state.episode, self._world(world))

    def _first(self, rng, start) -> State:
        """The :class:`State` of an episode's start (a :class:`~auv_envs.core.task.Transition`
        without judgement)."""
        return self._started(rng, start.plant, start.episode, start.truth, start.obs,
                             self._metrics(start.truth, start.episode, None))

    def _step(self, state: State, action: jax.Array, world: World | None = None) -> State:
        """One step of the family's transition in ``world`` (without the auto-reset)."""
        rng, key, _ = self._keys(state)
        stepped = self.task.step(state.plant, state.episode, self._action(action),
                                 KeyDraws(key), self._world(world))
        judged = stepped.judged
        return self._conclude(state, rng, stepped.plant, stepped.episode, stepped.truth,
                              stepped.obs, judged.terms, judged.terminated,
                              self._metrics(stepped.truth, stepped.episode, judged))

    def _metrics(self, truth: dict, episode, judged) -> dict:
        """A step's metrics: the family's step metrics, its reward terms
        (``reward_<term>``, zero at reset) and the episode's summary so far
        (``episode_<key>``)."""
        terms = ({term: 0.0 for term in self.task.transition.REWARD_TERMS} if judged is None
                 else judged.terms)
        step, summary = self.task.metrics(truth, episode, judged)
        return {
            **step,
            **{f"reward_{term}": jnp.float32(value) for term, value in terms.items()},
            **{f"episode_{key}": value for key, value in summary.items()},
        }

    def _action(self, action) -> jax.Array:
        """The action the transition is given: clipped to the CPU env's action box; with
        unit actions first mapped onto it from [-1, 1]."""
        action = jnp.asarray(action, jnp.float32)
        if self._action_box is not None:
            low, high = self._action_box.low, self._action_box.high
            return low + (jnp.clip(action, -1.0, 1.0) + 1.0) * 0.5 * (high - low)
        return jnp.clip(action, self.action_space.low, self.action_space.high)

    def _state_observation(self, episode, truth) -> jax.Array:
        """The family's ``obs_mode="state"`` observation of ``episode`` at ``truth`` (what
        its transition's ``observe`` gives in that mode), drawing nothing."""
        return self.task.state_observation(episode, truth)

    def _present(self, obs, episode, truth):
        """The observation as this env gives it: the transition's ``obs`` (flattened under
        Playground's conventions) and, with ``privileged``, the state-mode vector of
        ``episode`` at ``truth`` beside it."""
        if self.playground:
            if self._observation_keys is None:
                obs = jnp.asarray(obs, jnp.float32).reshape(-1)
            else:
                obs = jnp.concatenate([jnp.asarray(obs[key], jnp.float32).reshape(-1)
                                       for key in self._observation_keys])
        if not self.privileged:
            return obs
        state = jnp.asarray(self._state_observation(episode, truth), jnp.float32).reshape(-1)
        return {POLICY_KEY: obs, PRIVILEGED_KEY: state}

    def _flag(self, value) -> jax.Array:
        """A bool of the step (``done``, ``terminated``, ``truncation``) as this env gives it."""
        return jnp.asarray(value, jnp.float32) if self.playground else jnp.asarray(value)

    def _metrics_out(self, metrics: dict) -> dict:
        if not self.playground:
            return metrics
        return {key: jnp.asarray(value, jnp.float32) for key, value in metrics.items()}

    def _started(self, rng, plant, episode, truth, obs, metrics: dict) -> State:
        """The state of an episode just begun (``truth``: the transition's at its start):
        no reward yet, not done, its first observation as ``final_obs``."""
        false = self._flag(jnp.bool_(False))
        obs = self._present(obs, episode, truth)
        info = {"rng": rng, "terminated": false, "truncation": false, "final_obs": obs}
        return State({"plant": plant, "episode": episode}, obs, jnp.float32(0.0), false,
                     self._metrics_out(metrics), info)

    def step(self, state: State, action: jax.Array, world: World | None = None) -> State:
        """One step of the family's transition in ``world`` (default :attr:`mjx_model`;
        :meth:`_step`); with ``auto_reset``, an episode that ended replaced by a fresh one
        (its ``data`` and ``obs``; the step's ``reward``, ``done``, ``metrics``,
        ``terminated``, ``truncation`` and ``final_obs`` kept)."""
        stepped = self._step(state, action, world)
        if not self.auto_reset:
            return stepped
        return self._restart(stepped, self._keys(state)[2], world)

    def step_batch(self, states: State, actions: jax.Array, worlds: World | None = None,
                   in_axes=None) -> State:
        """``jax.vmap(self.step)(states, actions)``, the same states, with the auto-reset
        made once for the batch and only on a step where an episode ended (under
        ``vmap`` a reset inside :meth:`step` is computed for every environment at every
        step, a large share of a step's time; ``docs/speed.md``). With ``worlds``
        (:meth:`randomize`'s, mapped over ``in_axes``) each environment simulates its own."""
        step, restart = (self._batched(f, worlds, in_axes) for f in (self._step, self._restart))
        stepped = step(states, actions)
        if not self.auto_reset:
            return stepped
        reset_keys = jax.vmap(lambda state: self._keys(state)[2])(states)
        return jax.lax.cond(jnp.any(stepped.done), lambda s: restart(s, reset_keys),
                            lambda s: s, stepped)

    def reset_batch(self, keys: jax.Array, worlds: World | None = None,
                    in_axes=None) -> State:
        """``jax.vmap(self.reset)(keys)``; with ``worlds``, each in its own."""
        return self._batched(self.reset, worlds, in_axes)(keys)

    def _batched(self, function, worlds: World | None, in_axes):
        """``function(*args, world)`` mapped over a batch of ``args``: entry ``i`` in world
        ``i`` of ``worlds`` (mapped over ``in_axes``), or all in the env's own for None."""
        if worlds is None:
            return jax.vmap(function)
        return lambda *args: jax.vmap(function, in_axes=(*[0] * len(args), in_axes))(
            *args, worlds)

    @staticmethod
    def _keys(state: State) -> jax.Array:
        """A step's keys from ``state.info["rng"]``: the next ``rng``, the step's draws'
        and the reset's."""
        return jax.random.split(state.info["rng"], 3)

    def _restart(self, stepped: State, reset_key, world: World | None = None) -> State:
        """``stepped`` with its episode, where it ended, replaced by a fresh one (in
        ``world``)."""
        fresh = self.reset(reset_key, world)

        def restart(new, old):
            return jnp.where(stepped.done, new, old).astype(old.dtype)

        return stepped.replace(
            data=jax.tree_util.tree_map(restart, fresh.data, stepped.data),
            obs=jax.tree_util.tree_map(restart, fresh.obs, stepped.obs),
            info={**stepped.info, "rng": restart(fresh.info["rng"], stepped.info["rng"])})

    def _conclude(self, state: State, rng, plant, episode, truth, obs, terms: dict,
                  terminated, metrics: dict) -> State:
        """The state a step from ``state`` returns (``truth``: the transition's after the
        step): its reward (the terms' sum), ``done`` at termination or the time limit
        (``info["truncation"]``; under Playground's conventions at termination only),
        and the keys of ``state.info`` and ``state.metrics`` that this env does not
        write kept."""
        reward = task.reward(terms)
        terminated = jnp.asarray(terminated, jnp.bool_)
        if self.playground:  # the time limit is the trainer's (Brax's EpisodeWrapper)
            truncated = jnp.bool_(False)
        else:
            truncated = task.truncated(terminated, episode.steps, self.max_episode_steps,
                                       self.ops)
        done = terminated | truncated
        obs = self._present(obs, episode, truth)
        info = {**state.info, "rng": rng, "terminated": self._flag(terminated),
                "truncation": self._flag(truncated), "final_obs": obs}
        return State({"plant": plant, "episode": episode}, obs, reward, self._flag(done),
                     {**state.metrics, **self._metrics_out(metrics)}, info)
