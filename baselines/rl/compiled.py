"""Compiled PPO: rollouts and updates fused in JAX on a batched environment of any family.

A compact PPO (Schulman et al. 2017, "Proximal Policy Optimization
Algorithms", arXiv:1707.06347: clipped surrogate, GAE(λ), a value baseline)
whose whole iteration (a rollout of ``num_envs`` batched environments of one family,
:class:`~auv_envs.batched.functional.FunctionalEnv` with the family's task on JAX, then
the
minibatch epochs) is one compiled ``jax.jit`` call (``pip install -e
".[jax]"``; optax's Adam). It writes its policy as Stable-Baselines3's, which Brax's
PPO (``scripts/brax_ppo.py``) does not; actions are taken in [-1, 1], mapped onto the
env's action box as ``RescaleAction`` maps them for the SB3 policy on the CPU env.

The policy is Stable-Baselines3's ``MlpPolicy`` in JAX: separate tanh MLPs
for the Gaussian mean and the value, a state-independent log standard
deviation, observations flattened as Gymnasium's ``FlattenObservation`` and
normalised as ``VecNormalize`` (running mean and variance, clipped at 10).
With ``policy: JointResidualPolicy`` (LARS capture, ``marker_track: true``) it is
:class:`~baselines.rl.marker_estimate.JointResidualPolicy` instead: a learned correction
on a servo over the marker tracker's observation (:mod:`baselines.rl.marker_track`,
computed in JAX by :class:`~baselines.rl.marker_track.MarkerTrackMJX`), not normalised;
with ``policy: DetectionSetPolicy`` (acoustic tracking, ``detection_fixes: true``) it is
:class:`~baselines.rl.detections.DetectionSetPolicy`, the set encoder over one
least-squares fix per detection (:mod:`baselines.rl.detection_fixes`, computed in JAX by
:class:`~baselines.rl.detection_fixes.DetectionFixesMJX`; :func:`set_features`).
Three settings serve partially observed tasks (:class:`Trainer`): ``lstm_hidden_size``
puts an LSTM core (:mod:`baselines.rl.recurrent`) under the mean's and the value's MLPs
(sb3-contrib's ``MlpLstmPolicy``), ``privileged_critic`` lets the value read the privileged
state of an env built with ``privileged=True``, and ``teacher`` replaces PPO's update by
distillation from a privileged teacher (:mod:`baselines.rl.teachers`, DAgger's rules
of :mod:`baselines.rl.dagger`).

So a finished run is written *as* an SB3 policy (``model.zip``,
``vecnormalize.pkl``, ``policy.json``): it acts in the ordinary MuJoCo CPU
environment through :class:`baselines.rl.policy.PolicyAgent`, and
``evaluate.py --policy DIR`` ranks it beside every other agent. ``train.py``
runs it from ``baselines/rl/hyperparams/cppo.yml`` (:func:`train_run`)::

    python train.py --algo cppo --env DockingStation-v2 --seed 0 --run-dir runs/cppo-s0
    python evaluate.py --policy runs/cppo-s0 --envs DockingStation-v2 \\
        --difficulty paper --seeds 300000-300019
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from auv_envs.batched.compile_cache import (  # noqa: F401  (re-exported: train.py, tests)
    cache_for,
    default_compilation_cache,
    use_compilation_cache,
)
from auv_envs.batched.functional import POLICY_KEY, PRIVILEGED_KEY, FunctionalEnv
from auv_envs.families import family
from baselines.rl import dagger
from baselines.rl.config import (
    COMPILED,
    CompiledSettings,
    ConfigError,
    TrainConfig,
    save_config,
    validate,
)
from baselines.rl.detection_fixes import DetectionFixesMJX, DetectionTrackMJX, token_size
from baselines.rl.marker_track import SLICES, MarkerTrackMJX
from baselines.rl.nav_filter import NavFilterMJX
from baselines.rl.recurrent import LSTMState, lstm_cell, lstm_init, lstm_unroll, torch_weights
from baselines.rl.training import (
    RunDirectory,
    TrainingDiverged,
    TrainResult,
    package_versions,
    stop_on_signals,
    write_run_info,
)

#: Hidden layers of the mean and value networks (SB3 ``net_arch``), tanh as in SB3.
HIDDEN_LAYERS = (64, 64)
#: ``VecNormalize``'s defaults: observations clipped at 10, variance epsilon.
CLIP_OBS, NORM_EPSILON = 10.0, 1e-8


#: PPO's settings (SB3's names where they exist); ``cppo.yml`` sets them.
Settings = CompiledSettings
DEFAULT_SETTINGS = Settings()
#: ``policy`` of a residual policy on a servo (SB3's class of that name is what it exports).
RESIDUAL = "JointResidualPolicy"
#: ``policy`` of the acoustic set encoder over the detection fixes (the same).
SET_POLICY = "DetectionSetPolicy"
#: :class:`~baselines.rl.detections.DetectionSetExtractor`'s widths (its defaults; the
#: export passes them).
SET_EMBED, SET_SUMMARY = 64, 64


def flatten_observation(obs, keys) -> jax.Array:
    """A ``Dict`` observation as one float32 vector: its parts raveled in the space's
    order ``keys``, as ``gymnasium.spaces.flatten`` (tested equal); an array as it is."""
    if keys is None:
        return obs.astype(jnp.float32)
    return jnp.concatenate([jnp.ravel(obs[key]).astype(jnp.float32) for key in keys])


# ---------------------------------------------------------------------- networks
def _dense(key, fan_in: int, fan_out: int, scale: float) -> dict:
    """An orthogonally initialised layer (SB3's initialisation), zero bias."""
    weight = jax.nn.initializers.orthogonal(scale)(key, (fan_in, fan_out), jnp.float32)
    return {"w": weight, "b": jnp.zeros(fan_out, jnp.float32)}


def _mlp_init(key, sizes, head: int, head_scale: float) -> list:
    keys = jax.random.split(key, len(sizes))
    layers = [_dense(k, a, b, math.sqrt(2.0)) for k, a, b in zip(keys[:-1], sizes[:-1], sizes[1:],
                                                                strict=True)]
    return [*layers, _dense(keys[-1], sizes[-1], head, head_scale)]


def _mlp(layers: list, x: jax.Array) -> jax.Array:
    for layer in layers[:-1]:
        x = jnp.tanh(x @ layer["w"] + layer["b"])
    return x @ layers[-1]["w"] + layers[-1]["b"]


def _affine(layer: dict, x: jax.Array) -> jax.Array:
    return x @ layer["w"] + layer["b"]


def _set_init(key, bands: int, track: bool = False) -> dict:
    """:class:`~baselines.rl.detections.DetectionSetExtractor`'s layers as SB3 starts
    them (orthogonal, gain sqrt(2), zero bias): the token MLP, the score, the summary."""
    keys = jax.random.split(key, 4)
    gain = math.sqrt(2.0)
    return {"embed": [_dense(keys[0], token_size(bands, track), SET_EMBED, gain),
                      _dense(keys[1], SET_EMBED, SET_EMBED, gain)],
            "score": _dense(keys[2], SET_EMBED, 1, gain),
            "summary": _dense(keys[3], SET_EMBED + 1, SET_SUMMARY, gain)}


def set_features(net: dict, obs: dict) -> jax.Array:
    """:class:`~baselines.rl.detections.DetectionSetExtractor`'s output for one
    observation of :mod:`baselines.rl.detection_fixes` (``vmap`` it over a batch): the
    attention-weighted mean of the valid fixes (zero when none is), then the set's
    summary. With a track (:class:`~baselines.rl.detection_fixes.DetectionTrack`'s
    observation) its token joins the set, every token with the track flag and its
    deviation from the track."""
    q, k = obs["fix_valid"].shape
    track = "track_fix" in obs
    bands = jnp.repeat(jnp.eye(q, dtype=jnp.float32), k, axis=0)  # (Q*K, Q)

    def part(prefix: str, held: float, age, one_hot, flag: float):
        n = one_hot.shape[0]
        fix = obs[f"{prefix}fix"].reshape(n, 3)
        columns = [fix, obs[f"{prefix}fix_log_std"].reshape(n, 3),
                   obs[f"{prefix}fix_log_fit"].reshape(n, 1), one_hot,
                   jnp.full((n, 1), held, jnp.float32), jnp.broadcast_to(age, (n, 1))]
        if track:
            columns += [jnp.full((n, 1), flag, jnp.float32),
                        obs[f"{prefix}fix_deviation"].reshape(n, 1)]
        return fix, obs[f"{prefix}fix_valid"].reshape(n) > 0.5, jnp.concatenate(columns, -1)

    parts = [part("", 0.0, jnp.float32(0.0), bands, 0.0),
             part("held_", 1.0, obs["held_age"][0], bands, 0.0)]
    if track:
        parts.append(part("track_", 0.0, jnp.float32(0.0), jnp.zeros((1, q), jnp.float32),
                          1.0))
    fix, valid, tokens = (jnp.concatenate(group) for group in zip(*parts, strict=True))
    h = jax.nn.relu(_affine(net["embed"][1], jax.nn.relu(_affine(net["embed"][0], tokens))))
    scores = jnp.where(valid, _affine(net["score"], h)[:, 0], -jnp.inf)
    weights = jax.nn.softmax(jnp.where(valid.any(), scores, 0.0)) * valid
    count = valid.sum().astype(jnp.float32)
    mean_h = (h * valid[:, None]).sum(axis=0) / jnp.maximum(count, 1.0)
    summary = jax.nn.relu(_affine(net["summary"], jnp.concatenate(
        [mean_h, (count / valid.shape[0])[None]])))
    return jnp.concatenate([(weights[:, None] * fix).sum(axis=0), summary])


def unflatten_observation(flat: jax.Array, space: gym.spaces.Dict) -> dict:
    """The inverse of :func:`flatten_observation` for one observation of ``space``."""
    out, start = {}, 0
    for key, part in space.spaces.items():
        size = int(np.prod(part.shape))
        out[key] = flat[start:start + size].reshape(part.shape)
        start += size
    return out


def init_params(key, obs_size: int, action_size: int,
                settings: Settings | None = None, space=None,
                value_size: int | None = None) -> dict:
    """SB3's PPO start: mean network (head gain 0.01), value network (gain 1), log std
    ``log_std_init`` (0 by default). With ``policy: JointResidualPolicy`` the mean's head
    starts at zero and the servo's per-joint gains at ``servo_gain``
    (:class:`~baselines.rl.marker_estimate.JointResidualPolicy`). With ``policy:
    DetectionSetPolicy`` (``space``: the observation space of
    :mod:`baselines.rl.detection_fixes`) the mean is the set encoder's pooled fix and
    the value network reads its features.

    With ``lstm_hidden_size`` (sb3-contrib's ``MlpLstmPolicy``): an LSTM core
    (:mod:`baselines.rl.recurrent`) under the mean's MLP, and one under the value's.
    ``value_size``: the critic reads a privileged vector of that size instead (an MLP on
    it, no core: the privileged state is the whole state)."""
    settings = settings or DEFAULT_SETTINGS
    log_std = jnp.full(action_size, settings.log_std_init, jnp.float32)
    if settings.lstm_hidden_size:
        hidden = settings.lstm_hidden_size
        core_key, pi_key, vf_core_key, vf_key = jax.random.split(key, 4)
        params = {"lstm": lstm_init(core_key, obs_size, hidden),
                  "pi": _mlp_init(pi_key, (hidden, *HIDDEN_LAYERS), action_size, 0.01),
                  "log_std": log_std}
        if value_size is None:
            params["vf_lstm"] = lstm_init(vf_core_key, obs_size, hidden)
        params["vf"] = _mlp_init(vf_key, (value_size or hidden, *HIDDEN_LAYERS), 1, 1.0)
        return params
    pi_key, vf_key = jax.random.split(key)
    if settings.policy == SET_POLICY:
        return {"set": _set_init(pi_key, space["fix_valid"].shape[0], "track_fix" in space.spaces),
                "vf": _mlp_init(vf_key, (value_size or 3 + SET_SUMMARY, *HIDDEN_LAYERS), 1,
                                1.0),
                "log_std": log_std}
    params = {"pi": _mlp_init(pi_key, (obs_size, *HIDDEN_LAYERS), action_size, 0.01),
              "vf": _mlp_init(vf_key, (value_size or obs_size, *HIDDEN_LAYERS), 1, 1.0),
              "log_std": log_std}
    if settings.policy == RESIDUAL:
        params["pi"][-1] = jax.tree_util.tree_map(jnp.zeros_like, params["pi"][-1])
        params["servo_gain"] = jnp.full(action_size, settings.servo_gain, jnp.float32)
    return params


def policy_mean(params: dict, obs: jax.Array, x: jax.Array) -> jax.Array:
    """The Gaussian's mean from the observation ``obs`` and the network's input ``x``
    (``obs`` normalised, or ``obs`` itself): the MLP's output, or with a servo's gains
    (``JointResidualPolicy``) the hold target plus the gains times the joint offset to
    the capture point plus the MLP's output (the observation of
    :mod:`baselines.rl.marker_track`)."""
    mean = _mlp(params["pi"], x)
    if "servo_gain" not in params:
        return mean
    return (obs[..., SLICES["hold_target"]] + params["servo_gain"]
            * obs[..., SLICES["joint_offset"]] + mean)


class Normalizer(NamedTuple):
    """``VecNormalize``'s running observation statistics (parallel update, count from 1e-4)."""

    mean: jax.Array
    var: jax.Array
    count: jax.Array

    @classmethod
    def create(cls, size: int) -> Normalizer:
        return cls(jnp.zeros(size), jnp.ones(size), jnp.float32(1e-4))

    def update(self, batch: jax.Array) -> Normalizer:
        mean, var, n = batch.mean(0), batch.var(0), batch.shape[0]
        delta = mean - self.mean
        total = self.count + n
        new_mean = self.mean + delta * n / total
        m2 = self.var * self.count + var * n + delta ** 2 * self.count * n / total
        return Normalizer(new_mean, m2 / total, total)

    def __call__(self, obs: jax.Array) -> jax.Array:
        return jnp.clip((obs - self.mean) / jnp.sqrt(self.var + NORM_EPSILON), -CLIP_OBS,
                        CLIP_OBS)

    def part(self, start: int, stop: int | None = None) -> Normalizer:
        """The statistics of the entries ``start:stop`` (one normaliser serves the
        policy's observation and the critic's privileged state, concatenated)."""
        return Normalizer(self.mean[start:stop], self.var[start:stop], self.count)


def _all_finite(tree) -> jax.Array:
    leaves = jax.tree_util.tree_leaves(tree)
    return jnp.all(jnp.stack([jnp.isfinite(leaf).all() for leaf in leaves]))


def non_finite_leaves(tree) -> list[str]:
    """The dotted names of the arrays of ``tree`` that hold a NaN or an infinity."""
    return [jax.tree_util.keystr(path, simple=True, separator=".")
            for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]
            if not bool(jnp.isfinite(leaf).all())]


def _log_prob(params, mean, action):
    log_std = params["log_std"]
    return jnp.sum(-0.5 * ((action - mean) / jnp.exp(log_std)) ** 2 - log_std
                   - 0.5 * math.log(2 * math.pi), axis=-1)


# ---------------------------------------------------------------------- training


class Rollout(NamedTuple):
    """What a batch of environments carries from one step to the next: their states, the
    policy's and the value's memories (None without ``lstm_hidden_size``; no value memory
    with a privileged critic) and which environments begin an episode at this step."""

    env: object
    actor: LSTMState | None
    critic: LSTMState | None
    starts: jax.Array
    #: The teacher's memory (distillation; None otherwise).
    teacher: object = None
    #: Iterations done so far (the teacher's share of the actions decays with it).
    iteration: jax.Array | int = 0


class Steps(NamedTuple):
    """A rollout's steps, arrays ``(time, envs, ...)``: what the update reads."""

    obs: jax.Array
    #: the privileged states (None without them)
    privileged: jax.Array | None
    #: where an episode begins at the step
    starts: jax.Array
    #: the sampled actions; with a teacher, its labels
    action: jax.Array
    #: their log probabilities (zero with a teacher)
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    #: ``done`` as a float
    done: jax.Array
    #: success where an episode ended
    success: jax.Array
    #: the policy's mean action
    mean: jax.Array


def local_devices(count: int | None = None) -> list:
    """The first ``count`` of JAX's local devices (None: all of them)."""
    devices = jax.local_devices()
    if count is None:
        return devices
    if not 1 <= count <= len(devices):
        raise ConfigError(f"devices {count}: this host has {len(devices)} local "
                          f"{devices[0].platform} device(s)")
    return devices[:count]


def batch_devices(settings: Settings, count: int | None = None) -> list:
    """The devices a run splits its environments over: ``count`` of them (None: as many
    local devices as split the batch evenly, all of them where they do). Each device
    needs whole environments and an equal share of every minibatch."""
    recurrent = settings.lstm_hidden_size > 0
    minibatch = settings.num_envs // settings.n_minibatches if recurrent else (
        settings.num_envs * settings.n_steps // settings.n_minibatches)

    def fits(n: int) -> bool:
        return settings.num_envs % n == 0 and minibatch % n == 0

    if count is None:
        devices = local_devices()
        return devices[:max(n for n in range(1, len(devices) + 1) if fits(n))]
    devices = local_devices(count)
    if not fits(count):
        unit = "environments" if recurrent else "steps"
        raise ConfigError(f"devices {count}: num_envs ({settings.num_envs}) and a minibatch "
                          f"({minibatch} {unit}) must split evenly over the devices")
    return devices


class DataParallel:
    """The environment batch split over ``devices`` (a mesh of one axis, ``"envs"``).

    Arrays with a batch of environments (or a minibatch of their steps) along an axis are
    split along it, a slice a device; everything else (the networks, the optimiser, the
    normaliser, the keys) is replicated. The iteration stays one compiled program: XLA
    partitions it, each device steps its own environments and computes its share of a
    minibatch's gradient, and the reductions (the gradient's mean, the normaliser's
    statistics, the auto-reset's ``any``) are summed across the devices.
    """

    def __init__(self, devices):
        self.devices = tuple(devices)
        self.mesh = Mesh(np.array(self.devices), ("envs",))
        self.whole = NamedSharding(self.mesh, P())

    def _layout(self, apply, tree, size: int | None, axis: int):
        split = NamedSharding(self.mesh, P(*(None,) * axis, "envs"))
        return jax.tree_util.tree_map(
            lambda a: apply(a, split if a.ndim > axis and a.shape[axis] == size
                            else self.whole), tree)

    def put(self, tree, size: int | None, axis: int = 0):
        """``tree`` placed on the devices: split along ``axis`` where it has ``size``
        entries, replicated elsewhere (everywhere with ``size`` None)."""
        return self._layout(jax.device_put, tree, size, axis)

    def constrain(self, tree, size: int | None, axis: int = 0):
        """:meth:`put`'s layout inside a traced function."""
        return self._layout(jax.lax.with_sharding_constraint, tree, size, axis)


class Trainer:
    """PPO on a batched environment (actions in [-1, 1]: :meth:`FunctionalEnv.use_unit_actions`);
    :meth:`iteration` is one compiled call.

    With ``lstm_hidden_size`` the policy and the value carry an LSTM core each
    (:mod:`baselines.rl.recurrent`): the rollout holds their states per environment and
    clears them where an episode begins (the auto-reset's ``done``), the update replays
    each environment's whole rollout from the state it began with (truncated
    backpropagation through time over ``n_steps``), minibatches being groups of
    environments. With ``privileged_critic`` (the env built with ``privileged=True``:
    observations ``{"state": ..., "privileged_state": ...}``) the value reads the
    privileged state and the policy only the ``state`` entry. With a ``teacher``
    (:mod:`baselines.rl.teachers`, reading the privileged state) the update is
    distillation instead of PPO: the teacher labels every step the rollout visits, the
    rollout acts with the teacher's action with a probability that decays from 1 to 0
    over ``teacher_fraction`` of the run and with the policy's mean otherwise (DAgger:
    Ross, Gordon and Bagnell 2011, "A Reduction of Imitation Learning and Structured
    Prediction to No-Regret Online Learning", AISTATS), and the policy's mean is fitted
    to the labels (squared error); there is no critic.

    ``devices``: the local devices to split the environments over (:class:`DataParallel`;
    default: :func:`batch_devices`, all that split the batch evenly). On one device the
    program is the single-device one.
    """

    def __init__(self, env: FunctionalEnv, settings: Settings = DEFAULT_SETTINGS,
                 total_iterations=1, devices=None):
        self.env, self.settings = env, settings
        self.devices = tuple(batch_devices(settings) if devices is None else devices)
        #: The split over several devices; None on one.
        self.parallel = DataParallel(self.devices) if len(self.devices) > 1 else None
        space = env.observation_space
        self.privileged = settings.privileged_critic or bool(settings.teacher)
        is_split = isinstance(space, gym.spaces.Dict) and PRIVILEGED_KEY in space.spaces
        if self.privileged != is_split:
            raise ConfigError("privileged_critic and teacher read the privileged state of an "
                              "env built with privileged=True, and such an env is read by "
                              "them only")
        if settings.teacher and settings.privileged_critic:
            raise ConfigError("a teacher replaces the critic: set privileged_critic: false")
        #: What the value reads: nothing (distillation), the privileged state, the
        #: policy's observation through a memory of its own, or that observation as it is.
        self.critic = ("none" if settings.teacher else
                       "privileged" if settings.privileged_critic else
                       "memory" if settings.lstm_hidden_size else "obs")
        self.privileged_size = None
        if self.privileged:
            self.privileged_size = int(gym.spaces.flatdim(space[PRIVILEGED_KEY]))
            space = space[POLICY_KEY]
        self.policy_space = space
        self.keys = tuple(space.spaces) if isinstance(space, gym.spaces.Dict) else None
        self.obs_size = int(gym.spaces.flatdim(space))
        self.action_size = env.action_size
        self.recurrent = settings.lstm_hidden_size > 0
        if settings.policy == RESIDUAL and not isinstance(env, MarkerTrackMJX):
            raise ConfigError("policy JointResidualPolicy reads the marker tracker's observation: "
                              "set marker_track: true")
        if settings.policy == SET_POLICY and not isinstance(env, DetectionFixesMJX):
            raise ConfigError("policy DetectionSetPolicy reads the detection fixes: set "
                              "detection_fixes: true (or detection_track: true)")
        if self.recurrent and settings.policy != "MlpPolicy":
            raise ConfigError("lstm_hidden_size gives MlpPolicy a memory only")
        if settings.state_prediction_coef and not (self.recurrent and self.privileged):
            raise ConfigError("state_prediction_coef needs lstm_hidden_size and a teacher or "
                              "privileged_critic: true")
        self.teacher = None
        if settings.teacher:
            from baselines.rl.teachers import make_teacher

            self.teacher = make_teacher(settings.teacher, env)
        self.total_iterations = total_iterations
        schedule = optax.linear_schedule(settings.learning_rate, 0.0,
                                         total_iterations * settings.n_epochs
                                         * settings.n_minibatches)
        self.optimizer = optax.chain(optax.clip_by_global_norm(settings.max_grad_norm),
                                     optax.adam(schedule, eps=1e-5))
        self._reset = jax.vmap(env.reset)
        self._reset_batch = jax.jit(self._reset)  # eager, op by op, it took 27 s on 2 cores
        self._step = env.step_batch
        self.iteration = jax.jit(self._iteration)
        self.all_finite = jax.jit(_all_finite)  # one small program, one scalar to the host
        self.evaluate = jax.jit(self._evaluate, static_argnums=(2, 3))

    def init_params(self, key) -> dict:
        """The networks' first parameters (:func:`init_params`)."""
        params = init_params(key, self.obs_size, self.action_size, self.settings,
                             self.policy_space,
                             self.privileged_size if self.critic == "privileged" else None)
        if self.critic == "none":
            params = {name: part for name, part in params.items()
                      if name not in ("vf", "vf_lstm")}
        if self.settings.state_prediction_coef:  # training only: never exported
            params["state_head"] = _dense(jax.random.fold_in(key, 1),
                                          self.settings.lstm_hidden_size,
                                          self.privileged_size, 1.0)
        return params

    def init(self, key) -> tuple:
        """``(params, optimiser state, normaliser, rollout, key)`` to start training from."""
        net_key, env_key, key = jax.random.split(key, 3)
        params = self.init_params(net_key)
        states = self._reset_batch(jax.random.split(env_key, self.settings.num_envs))
        obs, privileged = self._split(states.obs)
        normalizer = Normalizer.create(self.obs_size + (self.privileged_size or 0)).update(
            self._joined(obs, privileged))
        rollout = self._fresh_rollout(states)
        opt_state = self.optimizer.init(params)
        if self.parallel is not None:
            params, opt_state, normalizer, key = self.parallel.put(
                (params, opt_state, normalizer, key), None)
            rollout = self.parallel.put(rollout, self.settings.num_envs)
        return params, opt_state, normalizer, rollout, key

    def _split_envs(self, tree, size: int | None, axis: int = 0):
        """``tree`` split over the devices along ``axis`` where it has ``size`` entries,
        replicated elsewhere (:meth:`DataParallel.constrain`); as it is on one device."""
        if self.parallel is None:
            return tree
        return self.parallel.constrain(tree, size, axis)

    def _fresh_rollout(self, states) -> Rollout:
        """Environments just reset: blank memories, every one at an episode's start."""
        n = states.reward.shape[0]
        memory = (LSTMState.zeros(n, self.settings.lstm_hidden_size)
                  if self.recurrent else None)
        return Rollout(states, memory, memory if self.critic == "memory" else None,
                       jnp.ones(n, bool),
                       self.teacher.init(n) if self.teacher is not None else None,
                       jnp.int32(0))

    # ------------------------------------------------------------------ observations
    def _flat(self, obs):
        return jax.vmap(lambda o: flatten_observation(o, self.keys))(obs)

    def _split(self, obs) -> tuple:
        """A batch of observations as ``(the policy's, flat; the privileged state or None)``."""
        if not self.privileged:
            return self._flat(obs), None
        return self._flat(obs[POLICY_KEY]), obs[PRIVILEGED_KEY].astype(jnp.float32)

    @staticmethod
    def _joined(obs, privileged):
        return obs if privileged is None else jnp.concatenate([obs, privileged], axis=-1)

    def _input(self, normalizer: Normalizer, obs: jax.Array) -> jax.Array:
        """The policy's input: ``obs`` normalised, or as it is (``normalize: false``)."""
        if not self.settings.normalize:
            return obs
        return normalizer.part(0, self.obs_size)(obs) if self.privileged else normalizer(obs)

    def _value_input(self, normalizer: Normalizer, privileged: jax.Array) -> jax.Array:
        """The privileged critic's input, normalised like the policy's."""
        if not self.settings.normalize:
            return privileged
        return normalizer.part(self.obs_size)(privileged)

    # ------------------------------------------------------------------ networks
    def _heads(self, params: dict, obs: jax.Array, x: jax.Array, privileged=None,
               normalizer=None) -> tuple:
        """The Gaussian's mean and the value of a batch of flat observations ``obs``
        (``x``: the networks' input, :meth:`_input`; ``privileged``: the critic's, with
        ``privileged_critic``) for a policy without memory."""
        if "set" not in params:
            mean = policy_mean(params, obs, x)
            features = x
        else:
            space = self.policy_space
            features = jax.vmap(lambda flat: set_features(
                params["set"], unflatten_observation(flat, space)))(x)
            mean = features[:, :3]
        if self.critic == "none":
            return mean, jnp.zeros(mean.shape[:-1])
        if self.critic == "privileged":
            features = self._value_input(normalizer, privileged)
        return mean, _mlp(params["vf"], features)[:, 0]

    def _recurrent_heads(self, params: dict, normalizer: Normalizer, rollout: Rollout, obs,
                         privileged) -> tuple:
        """One step of the recurrent policy and value on a batch: ``(mean, value,
        actor memory, critic memory)``, the memories cleared where ``rollout.starts``."""
        x = self._input(normalizer, obs)
        actor = lstm_cell(params["lstm"], rollout.actor.cleared(rollout.starts), x)
        critic = None
        if self.critic == "memory":
            critic = lstm_cell(params["vf_lstm"], rollout.critic.cleared(rollout.starts), x)
            value = _mlp(params["vf"], critic.h)[:, 0]
        else:
            value = self._value_of_state(params, normalizer, privileged, actor.h)
        return _mlp(params["pi"], actor.h), value, actor, critic

    def _value_of_state(self, params, normalizer, privileged, like):
        """The value without a memory of its own: from the privileged state, or none
        (zeros shaped as ``like`` without its last axis) under distillation."""
        if self.critic == "none":
            return jnp.zeros(like.shape[:-1])
        return _mlp(params["vf"], self._value_input(normalizer, privileged))[..., 0]

    def policy_step(self, params: dict, normalizer: Normalizer, rollout: Rollout):
        """The policy's mean action and value on the present observations of ``rollout``,
        and the rollout's memories after them."""
        obs, privileged = self._split(rollout.env.obs)
        if self.recurrent:
            mean, value, actor, critic = self._recurrent_heads(params, normalizer, rollout,
                                                               obs, privileged)
            return mean, value, rollout._replace(actor=actor, critic=critic)
        mean, value = self._heads(params, obs, self._input(normalizer, obs), privileged,
                                  normalizer)
        return mean, value, rollout

    def sequence_heads(self, params: dict, normalizer: Normalizer, first: Rollout, obs,
                        privileged, starts) -> tuple:
        """The recurrent policy's means ``(time, envs, actions)`` and values ``(time, envs)``
        over stored rollouts, replayed from the memories ``first`` they began with."""
        return self._sequence(params, normalizer, first, obs, privileged, starts)[:2]

    def _sequence(self, params, normalizer, first: Rollout, obs, privileged, starts):
        """:meth:`sequence_heads` and the policy's LSTM outputs ``(time, envs, hidden)``."""
        x = self._input(normalizer, obs)
        _, hidden = lstm_unroll(params["lstm"], first.actor, x, starts)
        if self.critic == "memory":
            _, critic = lstm_unroll(params["vf_lstm"], first.critic, x, starts)
            value = _mlp(params["vf"], critic)[..., 0]
        else:
            value = self._value_of_state(params, normalizer, privileged, hidden)
        return _mlp(params["pi"], hidden), value, hidden

    def state_prediction_loss(self, params, normalizer, hidden, privileged) -> jax.Array:
        """The auxiliary loss of ``state_prediction_coef``: the squared error of a linear
        head on the LSTM's outputs ``hidden`` to the privileged state, normalised as the
        critic reads it (summed over its entries, averaged over the steps)."""
        target = self._value_input(normalizer, privileged)
        return jnp.mean(jnp.sum((_affine(params["state_head"], hidden) - target) ** 2, -1))

    # ------------------------------------------------------------------ one iteration
    def teacher_share(self, iteration) -> jax.Array:
        """DAgger's probability of acting with the teacher's action at ``iteration``: 1
        decaying linearly to 0 over ``teacher_fraction`` of the run."""
        return dagger.linear_share(iteration,
                                   self.settings.teacher_fraction * self.total_iterations, jnp)

    def collect(self, params, normalizer, rollout: Rollout, key) -> tuple:
        """``n_steps`` of every environment: ``(rollout after, key, steps)``
        (:class:`Steps`). Without a teacher the policy acts stochastically; with one, the
        rollout acts with the teacher's action (:meth:`teacher_share`) or the policy's
        mean."""
        s = self.settings
        share = self.teacher_share(rollout.iteration) if self.teacher is not None else None

        def act(carry, _):
            rollout, key = carry
            key, sample_key = jax.random.split(key)
            obs, privileged = self._split(rollout.env.obs)
            mean, value, stepped = self.policy_step(params, normalizer, rollout)
            if self.teacher is None:
                action = mean + jnp.exp(params["log_std"]) * jax.random.normal(sample_key,
                                                                              mean.shape)
                executed, log_prob = action, _log_prob(params, mean, action)
            else:
                action, teacher = self.teacher.act(rollout.teacher, privileged,
                                                   rollout.starts)
                stepped = stepped._replace(teacher=teacher)
                executed = dagger.mix(action, mean,
                                      jax.random.uniform(sample_key, mean.shape[:1]), share,
                                      jnp)
                log_prob = jnp.zeros(mean.shape[:1])
            nxt = self._split_envs(self._step(stepped.env, jnp.clip(executed, -1.0, 1.0)),
                                   s.num_envs)
            out = Steps(obs, privileged, rollout.starts, action, log_prob, value, nxt.reward,
                        nxt.done.astype(jnp.float32), nxt.metrics["is_success"] & nxt.done,
                        mean)
            return (stepped._replace(env=nxt, starts=nxt.done), key), out

        (rollout, key), steps = jax.lax.scan(act, (rollout, key), None, length=s.n_steps)
        return rollout._replace(iteration=rollout.iteration + 1), key, steps

    def _iteration(self, params, opt_state, normalizer, rollout: Rollout, key):
        s = self.settings
        first = rollout
        rollout, key, (obs, privileged, starts, actions, log_probs, values, rewards, dones,
                       successes, means) = self.collect(params, normalizer, rollout, key)
        if self.teacher is not None:
            objective, targets = self._distillation_loss, (actions,)
        else:
            last_value = self.policy_step(params, normalizer, rollout)[1]

            def gae(carry, step):
                advantage, next_value = carry
                reward, done, value = step
                delta = reward + s.gamma * next_value * (1.0 - done) - value
                advantage = delta + s.gamma * s.gae_lambda * (1.0 - done) * advantage
                return (advantage, value), advantage

            _, advantages = jax.lax.scan(gae, (jnp.zeros_like(last_value), last_value),
                                         (rewards, dones, values), reverse=True)
            objective = self._ppo_loss
            targets = (actions, log_probs, advantages, advantages + values)
        steps = (obs, privileged, starts, *targets)
        epochs = self._recurrent_epochs if self.recurrent else self._epochs
        params, opt_state = epochs(objective, params, opt_state, normalizer, first, steps, key)
        key, _ = jax.random.split(key)
        normalizer = normalizer.update(self._joined(*jax.tree_util.tree_map(
            lambda a: a.reshape(-1, *a.shape[2:]), (obs, privileged))))
        stats = {"episodes": dones.sum(), "successes": successes.sum(),
                 "reward": rewards.mean()}
        if self.teacher is not None:  # the student's actions against the labels, before
            stats["imitation_error"] = self._distillation_loss(params, means, None, actions)
        params, opt_state, normalizer, key = self._split_envs(
            (params, opt_state, normalizer, key), None)
        return (params, opt_state, normalizer, self._split_envs(rollout, s.num_envs), key,
                stats)

    def _ppo_loss(self, params, mean, value, action, old_log_prob, advantage, ret):
        """PPO's clipped surrogate, the value's squared error and the entropy bonus."""
        s = self.settings
        log_prob = _log_prob(params, mean, action)
        ratio = jnp.exp(log_prob - old_log_prob)
        advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        policy_loss = -jnp.minimum(
            ratio * advantage,
            jnp.clip(ratio, 1 - s.clip_range, 1 + s.clip_range) * advantage).mean()
        value_loss = jnp.mean((ret - value) ** 2)
        entropy = jnp.sum(params["log_std"] + 0.5 * math.log(2 * math.pi * math.e))
        return policy_loss + s.vf_coef * value_loss - s.ent_coef * entropy

    @staticmethod
    def _distillation_loss(params, mean, value, label):
        """The squared error of the policy's mean to the teacher's action (summed over the
        action's entries, averaged over the steps)."""
        del params, value
        return dagger.imitation_loss(mean, label)

    def _update(self, loss_fn):
        """One optimiser step per minibatch of ``loss_fn(params, minibatch)``."""
        def update(carry, mb):
            params, opt_state = carry
            grads = jax.grad(loss_fn)(params, mb)
            updates, opt_state = self.optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), None
        return update

    def _epochs(self, objective, params, opt_state, normalizer, first, steps, key):
        """``n_epochs`` passes over the rollout's steps, shuffled into minibatches:
        ``objective(params, mean, value, *targets)`` minimised."""
        s = self.settings
        obs, privileged, _, *targets = steps
        batch = jax.tree_util.tree_map(lambda a: a.reshape(-1, *a.shape[2:]),
                                       (obs, privileged, *targets))

        def loss_fn(params, mb):
            obs, privileged, *targets = mb
            mean, value = self._heads(params, obs, self._input(normalizer, obs), privileged,
                                      normalizer)
            return objective(params, mean, value, *targets)

        def epoch(carry, key):
            order = jax.random.permutation(key, batch[0].shape[0])
            minibatches = jax.tree_util.tree_map(
                lambda a: a[order].reshape(s.n_minibatches, -1, *a.shape[1:]), batch)
            minibatches = self._split_envs(minibatches, order.shape[0] // s.n_minibatches, 1)
            return jax.lax.scan(self._update(loss_fn), carry, minibatches)[0], None

        _, epoch_key = jax.random.split(key)
        return jax.lax.scan(epoch, (params, opt_state),
                            jax.random.split(epoch_key, s.n_epochs))[0]

    def _recurrent_epochs(self, objective, params, opt_state, normalizer, first: Rollout,
                          steps, key):
        """``n_epochs`` passes over the rollout, minibatches being groups of environments,
        each replayed whole from the memories it began with."""
        s = self.settings
        memories = (first.actor, first.critic)

        def loss_fn(params, mb):
            (actor, critic), (obs, privileged, starts, *targets) = mb
            mean, value, hidden = self._sequence(
                params, normalizer, first._replace(actor=actor, critic=critic), obs,
                privileged, starts)
            loss = objective(params, mean, value, *targets)
            if s.state_prediction_coef:
                loss += s.state_prediction_coef * self.state_prediction_loss(
                    params, normalizer, hidden, privileged)
            return loss

        def epoch(carry, key):
            order = jax.random.permutation(key, s.num_envs)
            groups = (jax.tree_util.tree_map(  # envs first: (groups, envs, ...)
                lambda a: a[order].reshape(s.n_minibatches, -1, *a.shape[1:]), memories),
                jax.tree_util.tree_map(  # time first: (groups, time, envs, ...)
                lambda a: jnp.swapaxes(a[:, order].reshape(
                    a.shape[0], s.n_minibatches, -1, *a.shape[2:]), 0, 1), steps))
            group = s.num_envs // s.n_minibatches
            groups = (self._split_envs(groups[0], group, 1),
                      self._split_envs(groups[1], group, 2))
            return jax.lax.scan(self._update(loss_fn), carry, groups)[0], None

        _, epoch_key = jax.random.split(key)
        return jax.lax.scan(epoch, (params, opt_state),
                            jax.random.split(epoch_key, s.n_epochs))[0]

    # ------------------------------------------------------------------ evaluation
    def compile_evaluation(self, episodes: int, steps: int):
        """:meth:`evaluate` compiled ahead of time for ``episodes`` x ``steps``, from the
        shapes of the parameters alone: ``f(params, normalizer) -> (success rate, mean
        return, standard deviation of the returns)``. Needing no trained parameters, it
        compiles in a thread while the first reset and iteration compile (most of XLA's
        compiling runs on one core)."""
        params = jax.eval_shape(lambda: self.init_params(jax.random.PRNGKey(0)))
        normalizer = jax.eval_shape(
            lambda: Normalizer.create(self.obs_size + (self.privileged_size or 0)))
        if self.parallel is not None:  # as the run holds them: replicated
            params, normalizer = jax.tree_util.tree_map(
                lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=self.parallel.whole),
                (params, normalizer))
        return self.evaluate.lower(params, normalizer, episodes, steps).compile()

    def _evaluate(self, params, normalizer, episodes: int, steps: int, key=None):
        """Deterministic (mean) actions on ``episodes`` fresh batched episodes:
        ``(success rate, mean return, standard deviation of the returns)``."""
        key = jax.random.PRNGKey(12345) if key is None else key

        def split(tree):  # where the episodes split evenly over the devices
            return tree if episodes % len(self.devices) else self._split_envs(tree, episodes)

        rollout = split(self._fresh_rollout(self._reset(jax.random.split(key, episodes))))

        def act(carry, _):
            rollout, done, success, total = carry
            mean, _, rollout = self.policy_step(params, normalizer, rollout)
            nxt = split(self._step(rollout.env, jnp.clip(mean, -1.0, 1.0)))
            ended = nxt.done & ~done
            total = total + jnp.where(done, 0.0, nxt.reward)
            return (rollout._replace(env=nxt, starts=nxt.done), done | nxt.done,
                    success | (ended & nxt.metrics["is_success"]), total), None

        false = jnp.zeros(episodes, bool)
        (_, _, success, total), _ = jax.lax.scan(
            act, (rollout, false, false, jnp.zeros(episodes)), None, length=steps)
        return success.mean(), total.mean(), total.std()


#: Episodes of each batched evaluation during training.
EVAL_EPISODES = 64


#: The batched twins of the front ends a run key switches on (the CPU wrappers:
#: :data:`baselines.rl.config.FRONT_ENDS`), in the order they apply.
BATCHED_FRONT_ENDS = {"detection_fixes": DetectionFixesMJX,
                      "detection_track": DetectionTrackMJX, "marker_track": MarkerTrackMJX,
                      "nav_filter": NavFilterMJX}


def make_env(env_id: str, obs_mode: str, env_kwargs: dict | str,
             marker_track: bool = False, detection_fixes: bool = False,
             privileged: bool = False, nav_filter: bool = False,
             detection_track: bool = False) -> FunctionalEnv:
    """The batched env of ``env_id`` (a CPU id with a batched twin) that the compiled PPO
    trains on, built with ``env_kwargs`` (a difficulty level alone: a string): episodes
    reset themselves, actions in [-1, 1]; with ``marker_track``, the LARS ``features``
    observation replaced by the marker tracker's (:class:`MarkerTrackMJX`); with
    ``detection_fixes``, the acoustic ``measurements`` by the detection fixes
    (:class:`DetectionFixesMJX`; with ``detection_track`` the same with a Kalman track's
    token, :class:`DetectionTrackMJX`); with ``nav_filter``, the mission's ``nav_features`` with
    the navigation filter's estimate added (:class:`NavFilterMJX`); with ``privileged``,
    observations ``{"state": ..., "privileged_state": ...}`` for a privileged critic or a
    teacher (a front end reads and replaces the ``"state"`` entry)."""
    env_kwargs = {"difficulty": env_kwargs} if isinstance(env_kwargs, str) else env_kwargs
    extra = {"privileged": True} if privileged else {}
    try:
        env = FunctionalEnv(family(env_id).env_id, obs_mode=obs_mode, **extra,
                            **env_kwargs).use_unit_actions()
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"cannot build the batched {env_id} with obs_mode={obs_mode!r} and "
                          f"env_kwargs {env_kwargs}: {exc}") from exc
    chosen = {"detection_fixes": detection_fixes, "detection_track": detection_track,
              "marker_track": marker_track, "nav_filter": nav_filter}
    for name, wrapper in BATCHED_FRONT_ENDS.items():
        if chosen[name]:
            try:
                env = wrapper(env)
            except ConfigError as exc:
                raise ConfigError(f"{name}: {exc}") from exc
    return env


def train(env_id: str, env_kwargs: dict | str, timesteps: int, seed: int, out: Path,
          settings: Settings = DEFAULT_SETTINGS, evals: int = 10, group: str | None = None,
          checkpoints: bool = False, checkpoint_dir: Path | None = None, command: str = "",
          stop=lambda: False, obs_mode: str = "features", marker_track: bool = False,
          detection_fixes: bool = False, nav_filter: bool = False,
          detection_track: bool = False, devices: int | None = None) -> dict:
    """Train and write ``out`` as an SB3 policy directory; returns its manifest.

    ``env_kwargs``: the environment's arguments (a difficulty level alone: a string);
    ``marker_track``, ``detection_fixes``, ``detection_track``, ``nav_filter``: train on
    the marker tracker's observation, on the detection fixes (with a track), with the
    navigation filter (:func:`make_env`). ``devices``: how many local devices to split the
    environments over (None: :func:`batch_devices`' choice).

    ``group``: the leaderboard pools policies of one group (training seeds) into one row.
    ``evals``: batched evaluations of :data:`EVAL_EPISODES` episodes during the run, the
    last at its end (0: none; the curve is then empty and the policy is judged by
    ``evaluate.py`` alone).
    ``checkpoints``: also write the policy at each of the ``evals`` evaluations, as
    ``<checkpoint_dir or out/checkpoints>/step_<N>`` (each a policy directory whose
    manifest holds the training wall time so far), to find when a run first reached a
    success rate on the CPU environment (``scripts/time_to_success.py``).
    ``command``: the command line to record. ``stop()`` is asked after every
    iteration; when it says True the policy so far is written and the manifest's
    ``finished`` is False. An iteration that leaves a parameter or a normalisation
    statistic non-finite raises :class:`~baselines.rl.training.TrainingDiverged` at once,
    writing nothing more (the checkpoints written before it stay).
    """
    env = make_env(env_id, obs_mode, env_kwargs, marker_track, detection_fixes,
                   settings.privileged_critic or bool(settings.teacher), nav_filter,
                   detection_track)
    env_kwargs = {"difficulty": env_kwargs} if isinstance(env_kwargs, str) else dict(env_kwargs)
    difficulty = env_kwargs.get("difficulty", "paper")
    per_iteration = settings.num_envs * settings.n_steps
    iterations = max(1, math.ceil(timesteps / per_iteration))
    trainer = Trainer(env, settings, iterations, batch_devices(settings, devices))
    run = {"env_id": env_id, "obs_mode": obs_mode, "seed": seed, "difficulty": difficulty,
           "env_kwargs": env_kwargs, "marker_track": marker_track,
           "detection_fixes": detection_fixes, "detection_track": detection_track,
           "nav_filter": nav_filter,
           "settings": settings._asdict(), "command": command}
    checkpoint_dir = Path(checkpoint_dir or Path(out) / "checkpoints")
    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=1) as pool:
        compiling = (pool.submit(trainer.compile_evaluation, EVAL_EPISODES,
                                 env.max_episode_steps) if evals else None)
        params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(seed))
        evaluate = None
        curve = []
        every = max(1, iterations // evals) if evals else iterations + 1
        i = 0
        last_checkpoint = None
        while i < iterations and not (i and stop()):
            i += 1
            params, opt_state, normalizer, rollout, key, stats = trainer.iteration(
                params, opt_state, normalizer, rollout, key)
            if not bool(trainer.all_finite((params, normalizer))):
                if compiling is not None:
                    compiling.cancel()
                raise TrainingDiverged(i * per_iteration, non_finite_leaves(
                    {"policy": params, "normalizer": normalizer}), last_checkpoint,
                    resumable=False)
            if not evals or (i % every and i != iterations):
                continue
            evaluate = evaluate or compiling.result()
            success, mean_return, std_return = (float(v) for v in evaluate(params, normalizer))
            # train.py's curve columns (its plot and scripts/plot_seeds.py read both runs).
            row = {"step": i * per_iteration, "wall_s": round(time.perf_counter() - start, 1),
                   "mean_return": mean_return, "std_return": std_return,
                   "success_rate": success, "episodes": EVAL_EPISODES,
                   "train_success_rate": float(stats["successes"]) / max(
                       1.0, float(stats["episodes"]))}
            if "imitation_error" in stats:
                row["imitation_error"] = float(stats["imitation_error"])
            curve.append(row)
            imitation = (f", imitation error {row['imitation_error']:.3g}"
                         if "imitation_error" in row else "")
            print(f"[eval] step {row['step']}: success {100 * success:.0f} % over "
                  f"{EVAL_EPISODES} batched episodes{imitation} ({row['wall_s']} s)",
                  flush=True)
            if checkpoints and i < iterations:
                last_checkpoint = checkpoint_dir / f"step_{row['step']}"
                export(params, normalizer.part(0, trainer.obs_size), last_checkpoint,
                       {**run, "n_timesteps": row["step"], "wall_time_s": row["wall_s"],
                        "curve": list(curve), "group": None})
        if evaluate is None and compiling is not None:
            compiling.cancel()  # stopped before the first evaluation
    wall = time.perf_counter() - start
    manifest = export(params, normalizer.part(0, trainer.obs_size), Path(out), {
        **run, "n_timesteps": i * per_iteration, "wall_time_s": round(wall, 1),
        "curve": curve, "group": group})
    return {**manifest, "finished": i == iterations}


def _description(settings: Settings, difficulty: str) -> str:
    """What a policy directory's manifest says of how it learned."""
    how = (f"distilled (DAgger) from the privileged teacher {settings.teacher}"
           if settings.teacher else "PPO")
    memory = " with an LSTM memory" if settings.lstm_hidden_size else ""
    critic = ", privileged critic" if settings.privileged_critic else ""
    return (f"{how}, compiled in JAX{memory}{critic} (batched env, trained at "
            f"{difficulty})")


def export(params: dict, normalizer: Normalizer, out: Path, run: dict) -> dict:
    """Write the policy as Stable-Baselines3 files (``model.zip``, ``vecnormalize.pkl``)
    and a ``policy.json`` manifest that :mod:`baselines.rl.agents` reads; ``run`` names
    the CPU env (``env_id``, ``obs_mode``) the policy acts in."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from auv_envs.core.assets import sha256_file
    from baselines.registry import LazyFactory
    from baselines.rl.config import CUSTOM_POLICIES
    from baselines.rl.envs import wrap_env
    from baselines.rl.manifest import MANIFEST_FILE, MODEL_FILE, NORMALIZER_FILE, RECURRENT_ALGO

    out.mkdir(parents=True, exist_ok=True)
    env_kwargs = run.get("env_kwargs") or {"difficulty": run["difficulty"]}
    settings = Settings(**run["settings"])
    residual = settings.policy == RESIDUAL
    front_ends = tuple(name for name in BATCHED_FRONT_ENDS if run.get(name))
    cpu = gym.make(run["env_id"], obs_mode=run["obs_mode"], **env_kwargs).unwrapped
    # MlpPolicy reads the observation flattened (after any front end), as the trainer does
    flatten = not front_ends or settings.policy == "MlpPolicy"
    wrapped = wrap_env(cpu, flatten_obs=flatten, front_ends=front_ends)
    policy_kwargs = {"net_arch": list(HIDDEN_LAYERS), "activation_fn": torch.nn.Tanh}
    if residual:
        policy_kwargs["servo_gain"] = settings.servo_gain
    if settings.policy == SET_POLICY:
        policy_kwargs = {"net_arch": {"pi": [], "vf": list(HIDDEN_LAYERS)},
                         "activation_fn": torch.nn.Tanh,
                         "features_extractor_kwargs": {"embed_dim": SET_EMBED,
                                                       "summary_dim": SET_SUMMARY}}
    policy_class = (LazyFactory(CUSTOM_POLICIES[settings.policy]).resolve()
                    if settings.policy in CUSTOM_POLICIES else "MlpPolicy")
    recurrent = settings.lstm_hidden_size > 0
    if recurrent:  # sb3-contrib's RecurrentPPO: one LSTM under the mean, one under the value
        from sb3_contrib import RecurrentPPO

        policy_kwargs.update(lstm_hidden_size=settings.lstm_hidden_size, n_lstm_layers=1,
                             shared_lstm=False,
                             enable_critic_lstm=not settings.privileged_critic)
        model = RecurrentPPO("MlpLstmPolicy", wrapped, seed=0, device="cpu",
                             policy_kwargs=policy_kwargs)
    else:
        model = PPO(policy_class, wrapped, seed=0, device="cpu", policy_kwargs=policy_kwargs)
    policy = model.policy

    def copy(modules, layers):
        for module, layer in zip(modules, layers, strict=True):
            module.weight.copy_(torch.as_tensor(np.array(layer["w"]).T))
            module.bias.copy_(torch.as_tensor(np.array(layer["b"])))

    def linear(sequence):
        return [m for m in sequence if isinstance(m, torch.nn.Linear)]

    def core(module, cell):
        for name, value in torch_weights(cell).items():
            getattr(module, name).copy_(torch.as_tensor(value))

    # JointResidualPolicy wraps SB3's extractor and puts the servo before the mean's head
    extractor = policy.mlp_extractor.inner if residual else policy.mlp_extractor
    with torch.no_grad():
        if settings.policy == SET_POLICY:  # the actor is the set encoder's pooled fix
            encoder, net = policy.features_extractor, params["set"]
            copy([*linear(encoder.embed), encoder.score, *linear(encoder.summary)],
                 [*net["embed"], net["score"], net["summary"]])
        else:
            head = policy.action_net.linear if residual else policy.action_net
            copy([*linear(extractor.policy_net), head], params["pi"])
        if recurrent:
            core(policy.lstm_actor, params["lstm"])
        # A privileged critic read what the exported policy never sees, and a distilled
        # policy has none: neither is written (the model's value head stays at its start
        # and is never used to act).
        if not (settings.privileged_critic or settings.teacher):
            if recurrent:
                core(policy.lstm_critic, params["vf_lstm"])
            copy([*linear(extractor.value_net), policy.value_net], params["vf"])
        policy.log_std.copy_(torch.as_tensor(np.array(params["log_std"])))
        if residual:
            policy.action_net.servo_gain.copy_(torch.as_tensor(np.array(params["servo_gain"])))
    model.save(out / MODEL_FILE)
    files = [MODEL_FILE]
    if settings.normalize:
        vec = VecNormalize(DummyVecEnv([lambda: wrapped]), norm_obs=True, norm_reward=False,
                           clip_obs=CLIP_OBS, epsilon=NORM_EPSILON)
        vec.obs_rms.mean = np.asarray(normalizer.mean, np.float64)
        vec.obs_rms.var = np.asarray(normalizer.var, np.float64)
        vec.obs_rms.count = float(normalizer.count)
        vec.save(str(out / NORMALIZER_FILE))
        files.append(NORMALIZER_FILE)
    with open(out / "eval_curve.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(run["curve"][0]) if run["curve"]
                                else ["step"])
        writer.writeheader()
        writer.writerows(run["curve"])
    manifest = {
        "name": out.name, "algo": RECURRENT_ALGO if recurrent else "ppo",
        "env_id": run["env_id"], "obs_mode": run["obs_mode"],
        "flatten_obs": flatten, "env_kwargs": env_kwargs,
        **{name: True for name in front_ends},
        "trainer": "baselines.rl.compiled (compiled in JAX on the batched MJX env)",
        "seed": run["seed"], "n_timesteps": run["n_timesteps"],
        "wall_time_s": run["wall_time_s"], "settings": run["settings"],
        "command": run.get("command", ""),
        "versions": {"jax": jax.__version__, "optax": optax.__version__},
        "description": _description(settings, run["difficulty"]),
        "files": {name: sha256_file(out / name) for name in files},
    }
    if settings.privileged_critic:
        manifest["critic"] = "privileged_state (training only; not exported)"
    if settings.teacher:
        manifest["teacher"] = settings.teacher
    if run.get("group"):
        manifest["group"] = run["group"]
    (out / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def train_run(config: TrainConfig, run_dir: str | Path, command: str = "",
              compilation_cache: Path | None = None, devices: int | None = None
              ) -> TrainResult:
    """``train.py --algo cppo``: train ``config`` (``baselines/rl/hyperparams/cppo.yml``
    resolved) into a new run directory laid out as a ``train.py`` run.

    ``RUN_DIR/config.yml`` (the resolved config), ``run.json`` (command, versions,
    status, steps, wall time), ``eval_curve.csv``, ``final/`` (the policy:
    ``evaluate.py --policy RUN_DIR``, ``train.py --export``) and, with
    ``checkpoints: true``, ``checkpoints/step_<N>/``. ``compilation_cache``: keep
    compiled programs there (:func:`use_compilation_cache`). ``devices``: how many local
    devices to split the environments over (None: :func:`batch_devices`' choice; the
    devices used are recorded in ``run.json``). SIGINT or SIGTERM
    writes the policy so far to ``final/`` and stops (status ``interrupted``); a
    compiled run cannot be resumed, but the same config and seed train the same
    policy again.
    """
    validate(config)
    if config.algo != COMPILED:
        raise ConfigError(f"train_run trains {COMPILED!r} configs, got {config.algo!r}")
    settings = Settings(**config.hyperparams)
    used = batch_devices(settings, devices)
    run = RunDirectory(run_dir)
    if run.config.exists():
        raise ConfigError(f"{run.path} already holds a run; pick another --run-dir")
    if compilation_cache is not None:
        use_compilation_cache(compilation_cache)
    run.path.mkdir(parents=True, exist_ok=True)
    save_config(config, run.config)
    info = {**package_versions(), "jax": jax.__version__, "optax": optax.__version__,
            "algo": config.algo, "env_id": config.env_id, "seed": config.seed,
            "command": command, "n_timesteps": config.run["n_timesteps"], "status": "running",
            "devices": [str(device) for device in used],
            "segments": [{"command": command, "start_step": 0, "status": "running"}]}
    write_run_info(run, info)
    flag = SimpleNamespace(stop_signal=None)
    try:
        with stop_on_signals(flag, "writing the policy so far after this iteration"):
            manifest = train(config.env_id, {"difficulty": "paper", **config.run["env_kwargs"]},
                             config.run["n_timesteps"], config.seed, run.final,
                             settings, config.run["evals"],
                             checkpoints=config.run["checkpoints"],
                             checkpoint_dir=run.checkpoints, command=command,
                             stop=lambda: flag.stop_signal is not None,
                             obs_mode=config.run["obs_mode"], devices=len(used),
                             **{name: config.run[name] for name in BATCHED_FRONT_ENDS})
    except TrainingDiverged as exc:
        exc.run_dir = run.path
        info["segments"][0].update(status="diverged", diverged_at=exc.step, error=str(exc))
        info.update(status="diverged")
        write_run_info(run, info)
        raise
    shutil.copy2(run.final / "eval_curve.csv", run.eval_curve)
    status = "finished" if manifest["finished"] else "interrupted"
    steps, wall = manifest["n_timesteps"], manifest["wall_time_s"]
    info["segments"][0].update(end_step=steps, status=status, wall_time_s=wall)
    info.update(status=status, steps=steps, wall_time_s=wall)
    write_run_info(run, info)
    stopped_by = None if manifest["finished"] else signal.Signals(flag.stop_signal).name
    return TrainResult(run.path, steps, manifest["finished"], stopped_by, None, wall)
