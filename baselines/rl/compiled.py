"""Compiled PPO: rollouts and updates fused in JAX on a batched environment of any family.

A compact PPO (Schulman et al. 2017, "Proximal Policy Optimization
Algorithms", arXiv:1707.06347: clipped surrogate, GAE(λ), a value baseline)
whose whole iteration (a rollout of ``num_envs`` batched environments of one family,
:class:`~auv_envs.batched.docking_env.DockingMJX`,
:class:`~auv_envs.batched.lars_env.LARSMJX` or
:class:`~auv_envs.batched.acoustic_env.AcousticMJX`, then the
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

from auv_envs.batched.compile_cache import (  # noqa: F401  (re-exported: train.py, tests)
    default_compilation_cache,
    use_compilation_cache,
)
from auv_envs.batched.functional import FunctionalEnv
from auv_envs.batched.registry import FAMILIES
from baselines.rl.config import (
    COMPILED,
    CompiledSettings,
    ConfigError,
    TrainConfig,
    save_config,
    validate,
)
from baselines.rl.detection_fixes import DetectionFixesMJX, token_size
from baselines.rl.marker_track import SLICES, MarkerTrackMJX
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


def _set_init(key, bands: int) -> dict:
    """:class:`~baselines.rl.detections.DetectionSetExtractor`'s layers as SB3 starts
    them (orthogonal, gain sqrt(2), zero bias): the token MLP, the score, the summary."""
    keys = jax.random.split(key, 4)
    gain = math.sqrt(2.0)
    return {"embed": [_dense(keys[0], token_size(bands), SET_EMBED, gain),
                      _dense(keys[1], SET_EMBED, SET_EMBED, gain)],
            "score": _dense(keys[2], SET_EMBED, 1, gain),
            "summary": _dense(keys[3], SET_EMBED + 1, SET_SUMMARY, gain)}


def set_features(net: dict, obs: dict) -> jax.Array:
    """:class:`~baselines.rl.detections.DetectionSetExtractor`'s output for one
    observation of :mod:`baselines.rl.detection_fixes` (``vmap`` it over a batch): the
    attention-weighted mean of the valid fixes (zero when none is), then the set's
    summary."""
    q, k = obs["fix_valid"].shape
    bands = jnp.repeat(jnp.eye(q, dtype=jnp.float32), k, axis=0)  # (Q*K, Q)

    def part(prefix: str, held: float, age):
        fix = obs[f"{prefix}fix"].reshape(q * k, 3)
        flags = jnp.stack([jnp.full(q * k, held, jnp.float32),
                           jnp.broadcast_to(age, (q * k,))], axis=-1)
        tokens = jnp.concatenate([fix, obs[f"{prefix}fix_log_std"].reshape(q * k, 3),
                                  obs[f"{prefix}fix_log_fit"].reshape(q * k, 1), bands,
                                  flags], axis=-1)
        return fix, obs[f"{prefix}fix_valid"].reshape(q * k) > 0.5, tokens

    now = part("", 0.0, jnp.float32(0.0))
    before = part("held_", 1.0, obs["held_age"][0])
    fix, valid, tokens = (jnp.concatenate(pair) for pair in zip(now, before, strict=True))
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
                settings: Settings | None = None, space=None) -> dict:
    """SB3's PPO start: mean network (head gain 0.01), value network (gain 1), log std
    ``log_std_init`` (0 by default). With ``policy: JointResidualPolicy`` the mean's head
    starts at zero and the servo's per-joint gains at ``servo_gain``
    (:class:`~baselines.rl.marker_estimate.JointResidualPolicy`). With ``policy:
    DetectionSetPolicy`` (``space``: the observation space of
    :mod:`baselines.rl.detection_fixes`) the mean is the set encoder's pooled fix and
    the value network reads its features."""
    settings = settings or DEFAULT_SETTINGS
    pi_key, vf_key = jax.random.split(key)
    if settings.policy == SET_POLICY:
        return {"set": _set_init(pi_key, space["fix_valid"].shape[0]),
                "vf": _mlp_init(vf_key, (3 + SET_SUMMARY, *HIDDEN_LAYERS), 1, 1.0),
                "log_std": jnp.full(action_size, settings.log_std_init, jnp.float32)}
    sizes = (obs_size, *HIDDEN_LAYERS)
    params = {"pi": _mlp_init(pi_key, sizes, action_size, 0.01),
              "vf": _mlp_init(vf_key, sizes, 1, 1.0),
              "log_std": jnp.full(action_size, settings.log_std_init, jnp.float32)}
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
class Trainer:
    """PPO on a batched environment (actions in [-1, 1]: :meth:`FunctionalEnv.use_unit_actions`);
    :meth:`iteration` is one compiled call."""

    def __init__(self, env: FunctionalEnv, settings: Settings = DEFAULT_SETTINGS,
                 total_iterations=1):
        self.env, self.settings = env, settings
        space = env.observation_space
        self.keys = tuple(space.spaces) if isinstance(space, gym.spaces.Dict) else None
        self.obs_size = int(gym.spaces.flatdim(space))
        self.action_size = env.action_size
        if settings.policy == RESIDUAL and not isinstance(env, MarkerTrackMJX):
            raise ConfigError("policy JointResidualPolicy reads the marker tracker's observation: "
                              "set marker_track: true")
        if (settings.policy == SET_POLICY) != isinstance(env, DetectionFixesMJX):
            raise ConfigError("policy DetectionSetPolicy reads the detection fixes, and they are "
                              "read by it only: set both policy: DetectionSetPolicy and "
                              "detection_fixes: true, or neither")
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

    def init(self, key) -> tuple:
        net_key, env_key, key = jax.random.split(key, 3)
        params = init_params(net_key, self.obs_size, self.action_size, self.settings,
                             self.env.observation_space)
        states = self._reset_batch(jax.random.split(env_key, self.settings.num_envs))
        normalizer = Normalizer.create(self.obs_size).update(self._flat(states.obs))
        return params, self.optimizer.init(params), normalizer, states, key

    def _flat(self, obs):
        return jax.vmap(lambda o: flatten_observation(o, self.keys))(obs)

    def _input(self, normalizer: Normalizer, obs: jax.Array) -> jax.Array:
        """The networks' input: ``obs`` normalised, or as it is (``normalize: false``)."""
        return normalizer(obs) if self.settings.normalize else obs

    def _heads(self, params: dict, obs: jax.Array, x: jax.Array) -> tuple:
        """The Gaussian's mean and the value of a batch of flat observations ``obs``
        (``x``: the networks' input, :meth:`_input`)."""
        if "set" not in params:
            return policy_mean(params, obs, x), _mlp(params["vf"], x)[:, 0]
        space = self.env.observation_space
        features = jax.vmap(lambda flat: set_features(
            params["set"], unflatten_observation(flat, space)))(x)
        return features[:, :3], _mlp(params["vf"], features)[:, 0]

    def _iteration(self, params, opt_state, normalizer, states, key):
        s = self.settings

        def act(carry, _):
            states, key = carry
            key, sample_key = jax.random.split(key)
            obs = self._flat(states.obs)
            mean, value = self._heads(params, obs, self._input(normalizer, obs))
            action = mean + jnp.exp(params["log_std"]) * jax.random.normal(sample_key,
                                                                          mean.shape)
            nxt = self._step(states, jnp.clip(action, -1.0, 1.0))
            out = (obs, action, _log_prob(params, mean, action), value, nxt.reward,
                   nxt.done.astype(jnp.float32), nxt.metrics["is_success"] & nxt.done)
            return (nxt, key), out

        (states, key), (obs, actions, log_probs, values, rewards, dones, successes) = \
            jax.lax.scan(act, (states, key), None, length=s.n_steps)
        last_obs = self._flat(states.obs)
        last_value = self._heads(params, last_obs, self._input(normalizer, last_obs))[1]

        def gae(carry, step):
            advantage, next_value = carry
            reward, done, value = step
            delta = reward + s.gamma * next_value * (1.0 - done) - value
            advantage = delta + s.gamma * s.gae_lambda * (1.0 - done) * advantage
            return (advantage, value), advantage

        _, advantages = jax.lax.scan(gae, (jnp.zeros_like(last_value), last_value),
                                     (rewards, dones, values), reverse=True)
        returns = advantages + values
        batch = jax.tree_util.tree_map(lambda a: a.reshape(-1, *a.shape[2:]),
                                       (obs, actions, log_probs, advantages, returns))

        def loss_fn(params, mb):
            obs, action, old_log_prob, advantage, ret = mb
            mean, value = self._heads(params, obs, self._input(normalizer, obs))
            log_prob = _log_prob(params, mean, action)
            ratio = jnp.exp(log_prob - old_log_prob)
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
            policy_loss = -jnp.minimum(
                ratio * advantage,
                jnp.clip(ratio, 1 - s.clip_range, 1 + s.clip_range) * advantage).mean()
            value_loss = jnp.mean((ret - value) ** 2)
            entropy = jnp.sum(params["log_std"] + 0.5 * math.log(2 * math.pi * math.e))
            return policy_loss + s.vf_coef * value_loss - s.ent_coef * entropy

        def epoch(carry, key):
            params, opt_state = carry
            order = jax.random.permutation(key, batch[0].shape[0])
            minibatches = jax.tree_util.tree_map(
                lambda a: a[order].reshape(s.n_minibatches, -1, *a.shape[1:]), batch)

            def update(carry, mb):
                params, opt_state = carry
                grads = jax.grad(loss_fn)(params, mb)
                updates, opt_state = self.optimizer.update(grads, opt_state, params)
                return (optax.apply_updates(params, updates), opt_state), None

            return jax.lax.scan(update, (params, opt_state), minibatches)[0], None

        key, epoch_key = jax.random.split(key)
        (params, opt_state), _ = jax.lax.scan(epoch, (params, opt_state),
                                              jax.random.split(epoch_key, s.n_epochs))
        normalizer = normalizer.update(batch[0])
        stats = {"episodes": dones.sum(), "successes": successes.sum(),
                 "reward": rewards.mean()}
        return params, opt_state, normalizer, states, key, stats

    def compile_evaluation(self, episodes: int, steps: int):
        """:meth:`evaluate` compiled ahead of time for ``episodes`` x ``steps``, from the
        shapes of the parameters alone: ``f(params, normalizer) -> (success rate, mean
        return, standard deviation of the returns)``. Needing no trained parameters, it
        compiles in a thread while the first reset and iteration compile (most of XLA's
        compiling runs on one core)."""
        params = jax.eval_shape(lambda: init_params(jax.random.PRNGKey(0), self.obs_size,
                                                    self.action_size, self.settings,
                                                    self.env.observation_space))
        normalizer = jax.eval_shape(lambda: Normalizer.create(self.obs_size))
        return self.evaluate.lower(params, normalizer, episodes, steps).compile()

    def _evaluate(self, params, normalizer, episodes: int, steps: int, key=None):
        """Deterministic (mean) actions on ``episodes`` fresh batched episodes:
        ``(success rate, mean return, standard deviation of the returns)``."""
        key = jax.random.PRNGKey(12345) if key is None else key
        states = self._reset(jax.random.split(key, episodes))

        def act(carry, _):
            states, done, success, total = carry
            obs = self._flat(states.obs)
            mean = self._heads(params, obs, self._input(normalizer, obs))[0]
            nxt = self._step(states, jnp.clip(mean, -1.0, 1.0))
            ended = nxt.done & ~done
            total = total + jnp.where(done, 0.0, nxt.reward)
            return (nxt, done | nxt.done, success | (ended & nxt.metrics["is_success"]),
                    total), None

        false = jnp.zeros(episodes, bool)
        (_, _, success, total), _ = jax.lax.scan(
            act, (states, false, false, jnp.zeros(episodes)), None, length=steps)
        return success.mean(), total.mean(), total.std()


#: Episodes of each batched evaluation during training.
EVAL_EPISODES = 64


#: The batched twins of the front ends a run key switches on (the CPU wrappers:
#: :data:`baselines.rl.config.FRONT_ENDS`), in the order they apply.
BATCHED_FRONT_ENDS = {"detection_fixes": DetectionFixesMJX, "marker_track": MarkerTrackMJX}


def make_env(env_id: str, obs_mode: str, env_kwargs: dict | str,
             marker_track: bool = False, detection_fixes: bool = False) -> FunctionalEnv:
    """The batched env of ``env_id`` (a CPU id with a batched twin) that the compiled PPO
    trains on, built with ``env_kwargs`` (a difficulty level alone: a string): episodes
    reset themselves, actions in [-1, 1]; with ``marker_track``, the LARS ``features``
    observation replaced by the marker tracker's (:class:`MarkerTrackMJX`); with
    ``detection_fixes``, the acoustic ``measurements`` by the detection fixes
    (:class:`DetectionFixesMJX`)."""
    env_kwargs = {"difficulty": env_kwargs} if isinstance(env_kwargs, str) else env_kwargs
    try:
        env = FAMILIES[env_id][0](obs_mode=obs_mode, **env_kwargs).use_unit_actions()
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"cannot build the batched {env_id} with obs_mode={obs_mode!r} and "
                          f"env_kwargs {env_kwargs}: {exc}") from exc
    chosen = {"detection_fixes": detection_fixes, "marker_track": marker_track}
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
          detection_fixes: bool = False) -> dict:
    """Train and write ``out`` as an SB3 policy directory; returns its manifest.

    ``env_kwargs``: the environment's arguments (a difficulty level alone: a string);
    ``marker_track``, ``detection_fixes``: train on the marker tracker's observation, on
    the detection fixes (:func:`make_env`).

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
    env = make_env(env_id, obs_mode, env_kwargs, marker_track, detection_fixes)
    env_kwargs = {"difficulty": env_kwargs} if isinstance(env_kwargs, str) else dict(env_kwargs)
    difficulty = env_kwargs.get("difficulty", "paper")
    per_iteration = settings.num_envs * settings.n_steps
    iterations = max(1, math.ceil(timesteps / per_iteration))
    trainer = Trainer(env, settings, iterations)
    run = {"env_id": env_id, "obs_mode": obs_mode, "seed": seed, "difficulty": difficulty,
           "env_kwargs": env_kwargs, "marker_track": marker_track,
           "detection_fixes": detection_fixes,
           "settings": settings._asdict(), "command": command}
    checkpoint_dir = Path(checkpoint_dir or Path(out) / "checkpoints")
    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=1) as pool:
        compiling = (pool.submit(trainer.compile_evaluation, EVAL_EPISODES,
                                 env.max_episode_steps) if evals else None)
        params, opt_state, normalizer, states, key = trainer.init(jax.random.PRNGKey(seed))
        evaluate = None
        curve = []
        every = max(1, iterations // evals) if evals else iterations + 1
        i = 0
        last_checkpoint = None
        while i < iterations and not (i and stop()):
            i += 1
            params, opt_state, normalizer, states, key, stats = trainer.iteration(
                params, opt_state, normalizer, states, key)
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
            curve.append(row)
            print(f"[eval] step {row['step']}: success {100 * success:.0f} % over "
                  f"{EVAL_EPISODES} batched episodes ({row['wall_s']} s)", flush=True)
            if checkpoints and i < iterations:
                last_checkpoint = checkpoint_dir / f"step_{row['step']}"
                export(params, normalizer, last_checkpoint,
                       {**run, "n_timesteps": row["step"], "wall_time_s": row["wall_s"],
                        "curve": list(curve), "group": None})
        if evaluate is None and compiling is not None:
            compiling.cancel()  # stopped before the first evaluation
    wall = time.perf_counter() - start
    manifest = export(params, normalizer, Path(out), {
        **run, "n_timesteps": i * per_iteration, "wall_time_s": round(wall, 1),
        "curve": curve, "group": group})
    return {**manifest, "finished": i == iterations}


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
    from baselines.rl.manifest import MANIFEST_FILE, MODEL_FILE, NORMALIZER_FILE

    out.mkdir(parents=True, exist_ok=True)
    env_kwargs = run.get("env_kwargs") or {"difficulty": run["difficulty"]}
    settings = Settings(**run["settings"])
    residual = settings.policy == RESIDUAL
    front_ends = tuple(name for name in BATCHED_FRONT_ENDS if run.get(name))
    cpu = gym.make(run["env_id"], obs_mode=run["obs_mode"], **env_kwargs).unwrapped
    wrapped = wrap_env(cpu, flatten_obs=not front_ends, front_ends=front_ends)
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
    model = PPO(policy_class, wrapped, seed=0, device="cpu", policy_kwargs=policy_kwargs)
    policy = model.policy

    def copy(modules, layers):
        for module, layer in zip(modules, layers, strict=True):
            module.weight.copy_(torch.as_tensor(np.array(layer["w"]).T))
            module.bias.copy_(torch.as_tensor(np.array(layer["b"])))

    def linear(sequence):
        return [m for m in sequence if isinstance(m, torch.nn.Linear)]

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
        "name": out.name, "algo": "ppo", "env_id": run["env_id"], "obs_mode": run["obs_mode"],
        "flatten_obs": not front_ends, "env_kwargs": env_kwargs,
        **{name: True for name in front_ends},
        "trainer": "baselines.rl.compiled (PPO fused in JAX on the batched MJX env)",
        "seed": run["seed"], "n_timesteps": run["n_timesteps"],
        "wall_time_s": run["wall_time_s"], "settings": run["settings"],
        "command": run.get("command", ""),
        "versions": {"jax": jax.__version__, "optax": optax.__version__},
        "description": f"PPO compiled in JAX (batched env, trained at "
                       f"{run['difficulty']})",
        "files": {name: sha256_file(out / name) for name in files},
    }
    if run.get("group"):
        manifest["group"] = run["group"]
    (out / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def train_run(config: TrainConfig, run_dir: str | Path, command: str = "",
              compilation_cache: Path | None = None) -> TrainResult:
    """``train.py --algo cppo``: train ``config`` (``baselines/rl/hyperparams/cppo.yml``
    resolved) into a new run directory laid out as a ``train.py`` run.

    ``RUN_DIR/config.yml`` (the resolved config), ``run.json`` (command, versions,
    status, steps, wall time), ``eval_curve.csv``, ``final/`` (the policy:
    ``evaluate.py --policy RUN_DIR``, ``train.py --export``) and, with
    ``checkpoints: true``, ``checkpoints/step_<N>/``. ``compilation_cache``: keep
    compiled programs there (:func:`use_compilation_cache`). SIGINT or SIGTERM
    writes the policy so far to ``final/`` and stops (status ``interrupted``); a
    compiled run cannot be resumed, but the same config and seed train the same
    policy again.
    """
    validate(config)
    if config.algo != COMPILED:
        raise ConfigError(f"train_run trains {COMPILED!r} configs, got {config.algo!r}")
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
            "segments": [{"command": command, "start_step": 0, "status": "running"}]}
    write_run_info(run, info)
    flag = SimpleNamespace(stop_signal=None)
    try:
        with stop_on_signals(flag, "writing the policy so far after this iteration"):
            manifest = train(config.env_id, {"difficulty": "paper", **config.run["env_kwargs"]},
                             config.run["n_timesteps"], config.seed, run.final,
                             Settings(**config.hyperparams), config.run["evals"],
                             checkpoints=config.run["checkpoints"],
                             checkpoint_dir=run.checkpoints, command=command,
                             stop=lambda: flag.stop_signal is not None,
                             obs_mode=config.run["obs_mode"],
                             marker_track=config.run["marker_track"],
                             detection_fixes=config.run["detection_fixes"])
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
