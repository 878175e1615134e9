"""Compiled PPO: rollouts and updates fused in JAX on the batched docking environment.

A compact PPO (Schulman et al. 2017, "Proximal Policy Optimization
Algorithms", arXiv:1707.06347: clipped surrogate, GAE(λ), a value baseline)
whose whole iteration (a rollout of ``num_envs`` batched
:class:`auv_envs.batched.docking_env.DockingMJX` environments, then the
minibatch epochs) is one compiled ``jax.jit`` call (``pip install -e
".[jax]"``; optax's Adam). Brax's PPO would be the library to use, but
``brax 0.14.2`` calls ``jax.device_put_replicated``, which JAX 0.10 (the one
that matches ``mujoco-mjx 3.17``) no longer has.

The policy is Stable-Baselines3's ``MlpPolicy`` in JAX: separate tanh MLPs
for the Gaussian mean and the value, a state-independent log standard
deviation, observations flattened as Gymnasium's ``FlattenObservation`` and
normalised as ``VecNormalize`` (running mean and variance, clipped at 10).
So a finished run is written *as* an SB3 policy (``model.zip``,
``vecnormalize.pkl``, ``policy.json``): it acts in the ordinary MuJoCo CPU
environment through :class:`baselines.rl.policy.PolicyAgent`, and
``evaluate.py --policy DIR`` ranks it beside every other agent::

    python -m baselines.rl.compiled --env DockingStation-v1 --difficulty paper \\
        --timesteps 1500000 --seed 0 --out runs/compiled-docking-s0
    python evaluate.py --policy runs/compiled-docking-s0 --envs DockingStation-v1 \\
        --difficulty paper --seeds 300000-300019
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import NamedTuple

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import optax

from auv_envs.batched.docking_env import DockingMJX

#: Hidden layers of the mean and value networks (SB3 ``net_arch``), tanh as in SB3.
HIDDEN_LAYERS = (64, 64)
#: ``VecNormalize``'s defaults: observations clipped at 10, variance epsilon.
CLIP_OBS, NORM_EPSILON = 10.0, 1e-8


class Settings(NamedTuple):
    """PPO's settings (SB3's names where they exist)."""

    num_envs: int = 256
    n_steps: int = 32
    n_minibatches: int = 32
    n_epochs: int = 5
    learning_rate: float = 3e-4  # decays linearly to 0, as train.py's lin_3.0e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5


DEFAULT_SETTINGS = Settings()


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


def init_params(key, obs_size: int, action_size: int) -> dict:
    """Mean network (head gain 0.01), value network (gain 1), log std 0: SB3's PPO start."""
    pi_key, vf_key = jax.random.split(key)
    sizes = (obs_size, *HIDDEN_LAYERS)
    return {"pi": _mlp_init(pi_key, sizes, action_size, 0.01),
            "vf": _mlp_init(vf_key, sizes, 1, 1.0),
            "log_std": jnp.zeros(action_size, jnp.float32)}


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


def _log_prob(params, mean, action):
    log_std = params["log_std"]
    return jnp.sum(-0.5 * ((action - mean) / jnp.exp(log_std)) ** 2 - log_std
                   - 0.5 * math.log(2 * math.pi), axis=-1)


# ---------------------------------------------------------------------- training
class Trainer:
    """PPO on a batched docking environment; :meth:`iteration` is one compiled call."""

    def __init__(self, env: DockingMJX, settings: Settings = DEFAULT_SETTINGS, total_iterations=1):
        self.env, self.settings = env, settings
        space = env.observation_space
        self.keys = tuple(space.spaces) if isinstance(space, gym.spaces.Dict) else None
        self.obs_size = int(gym.spaces.flatdim(space))
        self.action_size = env.action_size
        schedule = optax.linear_schedule(settings.learning_rate, 0.0,
                                         total_iterations * settings.n_epochs
                                         * settings.n_minibatches)
        self.optimizer = optax.chain(optax.clip_by_global_norm(settings.max_grad_norm),
                                     optax.adam(schedule, eps=1e-5))
        self._reset = jax.vmap(env.reset)
        self._reset_batch = jax.jit(self._reset)  # eager, op by op, it took 27 s on 2 cores
        self._step = jax.vmap(env.step)
        self.iteration = jax.jit(self._iteration)
        self.evaluate = jax.jit(self._evaluate, static_argnums=(2, 3))

    def init(self, key) -> tuple:
        net_key, env_key, key = jax.random.split(key, 3)
        params = init_params(net_key, self.obs_size, self.action_size)
        states = self._reset_batch(jax.random.split(env_key, self.settings.num_envs))
        normalizer = Normalizer.create(self.obs_size).update(self._flat(states.obs))
        return params, self.optimizer.init(params), normalizer, states, key

    def _flat(self, obs):
        return jax.vmap(lambda o: flatten_observation(o, self.keys))(obs)

    def _iteration(self, params, opt_state, normalizer, states, key):
        s = self.settings

        def act(carry, _):
            states, key = carry
            key, sample_key = jax.random.split(key)
            obs = self._flat(states.obs)
            x = normalizer(obs)
            mean = _mlp(params["pi"], x)
            action = mean + jnp.exp(params["log_std"]) * jax.random.normal(sample_key,
                                                                          mean.shape)
            value = _mlp(params["vf"], x)[:, 0]
            nxt = self._step(states, jnp.clip(action, -1.0, 1.0))
            out = (obs, action, _log_prob(params, mean, action), value, nxt.reward,
                   nxt.done.astype(jnp.float32), nxt.metrics["is_success"] & nxt.done)
            return (nxt, key), out

        (states, key), (obs, actions, log_probs, values, rewards, dones, successes) = \
            jax.lax.scan(act, (states, key), None, length=s.n_steps)
        last_value = _mlp(params["vf"], normalizer(self._flat(states.obs)))[:, 0]

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
            x = normalizer(obs)
            mean = _mlp(params["pi"], x)
            log_prob = _log_prob(params, mean, action)
            ratio = jnp.exp(log_prob - old_log_prob)
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
            policy_loss = -jnp.minimum(
                ratio * advantage,
                jnp.clip(ratio, 1 - s.clip_range, 1 + s.clip_range) * advantage).mean()
            value_loss = jnp.mean((ret - _mlp(params["vf"], x)[:, 0]) ** 2)
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

    def _evaluate(self, params, normalizer, episodes: int, steps: int, key=None):
        """Deterministic (mean) actions on ``episodes`` fresh batched episodes:
        ``(success rate, mean return)``."""
        key = jax.random.PRNGKey(12345) if key is None else key
        states = self._reset(jax.random.split(key, episodes))

        def act(carry, _):
            states, done, success, total = carry
            mean = _mlp(params["pi"], normalizer(self._flat(states.obs)))
            nxt = self._step(states, jnp.clip(mean, -1.0, 1.0))
            ended = nxt.done & ~done
            total = total + jnp.where(done, 0.0, nxt.reward)
            return (nxt, done | nxt.done, success | (ended & nxt.metrics["is_success"]),
                    total), None

        false = jnp.zeros(episodes, bool)
        (_, _, success, total), _ = jax.lax.scan(
            act, (states, false, false, jnp.zeros(episodes)), None, length=steps)
        return success.mean(), total.mean()


def train(env_id: str, difficulty: str, timesteps: int, seed: int, out: Path,
          settings: Settings = DEFAULT_SETTINGS, evals: int = 10, group: str | None = None,
          checkpoints: bool = False) -> dict:
    """Train and write ``out`` as an SB3 policy directory; returns its manifest.

    ``group``: the leaderboard pools policies of one group (training seeds) into one row.
    ``checkpoints``: also write the policy at each of the ``evals`` evaluations, as
    ``out/checkpoints/step_<N>`` (each a policy directory whose manifest holds the
    training wall time so far), to find when a run first reached a success rate
    on the CPU environment (``evaluate.py --policy``).
    """
    env = DockingMJX(env_id, obs_mode="features", difficulty=difficulty)
    per_iteration = settings.num_envs * settings.n_steps
    iterations = max(1, math.ceil(timesteps / per_iteration))
    trainer = Trainer(env, settings, iterations)
    run = {"seed": seed, "difficulty": difficulty, "settings": settings._asdict()}
    start = time.perf_counter()
    params, opt_state, normalizer, states, key = trainer.init(jax.random.PRNGKey(seed))
    curve = []
    every = max(1, iterations // evals)
    for i in range(1, iterations + 1):
        params, opt_state, normalizer, states, key, stats = trainer.iteration(
            params, opt_state, normalizer, states, key)
        if i % every == 0 or i == iterations:
            success, mean_return = (float(v) for v in trainer.evaluate(
                params, normalizer, 64, env.max_episode_steps))
            # train.py's curve columns (scripts/plot_seeds.py reads both kinds of run).
            row = {"step": i * per_iteration, "wall_s": round(time.perf_counter() - start, 1),
                   "success_rate": success, "mean_return": mean_return,
                   "train_success_rate": float(stats["successes"]) / max(
                       1.0, float(stats["episodes"]))}
            curve.append(row)
            print(f"[eval] step {row['step']}: success {100 * success:.0f} % over 64 batched "
                  f"episodes ({row['wall_s']} s)", flush=True)
            if checkpoints and i < iterations:
                export(env, params, normalizer, Path(out) / "checkpoints" / f"step_{row['step']}",
                       {**run, "n_timesteps": row["step"], "wall_time_s": row["wall_s"],
                        "curve": list(curve), "group": None})
    wall = time.perf_counter() - start
    return export(env, params, normalizer, Path(out), {
        **run, "n_timesteps": iterations * per_iteration, "wall_time_s": round(wall, 1),
        "curve": curve, "group": group})


def export(env: DockingMJX, params: dict, normalizer: Normalizer, out: Path, run: dict) -> dict:
    """Write the policy as Stable-Baselines3 files (``model.zip``, ``vecnormalize.pkl``)
    and a ``policy.json`` manifest that :mod:`baselines.rl.agents` reads."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from auv_envs.core.assets import sha256_file
    from baselines.rl.envs import wrap_env
    from baselines.rl.policy import MANIFEST_FILE, MODEL_FILE, NORMALIZER_FILE

    out.mkdir(parents=True, exist_ok=True)
    cpu = gym.make(env.env_id, obs_mode="features").unwrapped
    wrapped = wrap_env(cpu, flatten_obs=True)
    model = PPO("MlpPolicy", wrapped, seed=0, device="cpu", policy_kwargs={
        "net_arch": list(HIDDEN_LAYERS), "activation_fn": torch.nn.Tanh})
    policy = model.policy
    with torch.no_grad():
        linear = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
        for module, layer in zip([*linear, policy.action_net], params["pi"], strict=True):
            module.weight.copy_(torch.as_tensor(np.array(layer["w"]).T))
            module.bias.copy_(torch.as_tensor(np.array(layer["b"])))
        linear = [m for m in policy.mlp_extractor.value_net if isinstance(m, torch.nn.Linear)]
        for module, layer in zip([*linear, policy.value_net], params["vf"], strict=True):
            module.weight.copy_(torch.as_tensor(np.array(layer["w"]).T))
            module.bias.copy_(torch.as_tensor(np.array(layer["b"])))
        policy.log_std.copy_(torch.as_tensor(np.array(params["log_std"])))
    model.save(out / MODEL_FILE)
    vec = VecNormalize(DummyVecEnv([lambda: wrapped]), norm_obs=True, norm_reward=False,
                       clip_obs=CLIP_OBS, epsilon=NORM_EPSILON)
    vec.obs_rms.mean = np.asarray(normalizer.mean, np.float64)
    vec.obs_rms.var = np.asarray(normalizer.var, np.float64)
    vec.obs_rms.count = float(normalizer.count)
    vec.save(str(out / NORMALIZER_FILE))
    with open(out / "eval_curve.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(run["curve"][0]) if run["curve"]
                                else ["step"])
        writer.writeheader()
        writer.writerows(run["curve"])
    manifest = {
        "name": out.name, "algo": "ppo", "env_id": env.env_id, "obs_mode": "features",
        "flatten_obs": True, "env_kwargs": {"difficulty": run["difficulty"]},
        "trainer": "baselines.rl.compiled (PPO fused in JAX on the batched MJX env)",
        "seed": run["seed"], "n_timesteps": run["n_timesteps"],
        "wall_time_s": run["wall_time_s"], "settings": run["settings"],
        "command": " ".join(["python -m baselines.rl.compiled", *sys.argv[1:]]),
        "versions": {"jax": jax.__version__, "optax": optax.__version__},
        "description": f"PPO compiled in JAX on the batched env, features, trained at "
                       f"{run['difficulty']}",
        "files": {name: sha256_file(out / name) for name in (MODEL_FILE, NORMALIZER_FILE)},
    }
    if run.get("group"):
        manifest["group"] = run["group"]
    (out / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def default_compilation_cache() -> Path:
    """``$XDG_CACHE_HOME/auv_envs/jax`` (``~/.cache/auv_envs/jax`` without it)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "auv_envs" / "jax"


def use_compilation_cache(directory: Path) -> None:
    """Keep compiled programs in ``directory`` (JAX's persistent compilation cache).

    A run compiles its iteration, reset and evaluation: on 2 CPU cores about
    90 s pass before learning starts. A later run with the same environment,
    level and settings (another seed, say) loads them from here instead and
    starts in about 33 s, most of it tracing
    (``benchmarks/compiled_startup.py``). The cache is keyed on the compiled
    program, the JAX version and the device, so a stale entry is never used;
    deleting the directory is always safe.
    """
    directory.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(directory))
    # Cache the env's smaller programs too (JAX's default skips those under 1 s).
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="DockingStation-v1",
                        choices=["DockingStation-v1", "LampArrayDocking-v1"])
    parser.add_argument("--difficulty", default="paper", choices=["easy", "paper", "hard"])
    parser.add_argument("--timesteps", type=int, default=1_500_000,
                        help="env steps (default: the shipped policies' budget)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num-envs", type=int, default=DEFAULT_SETTINGS.num_envs)
    parser.add_argument("--evals", type=int, default=10)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--group", default=None,
                        help="pool this policy with others of the group on the leaderboard")
    parser.add_argument("--checkpoints", action="store_true",
                        help="also write the policy at every evaluation, under OUT/checkpoints")
    parser.add_argument("--compilation-cache", type=Path, default=default_compilation_cache(),
                        metavar="DIR", help="JAX's persistent compilation cache (default: "
                        "%(default)s); a later run of the same shapes loads its programs "
                        "instead of compiling them")
    parser.add_argument("--no-compilation-cache", action="store_true",
                        help="compile everything afresh, write no cache")
    args = parser.parse_args(argv)
    if args.timesteps <= 0 or args.num_envs <= 0:
        parser.error("--timesteps and --num-envs must be positive")
    if not args.no_compilation_cache:
        use_compilation_cache(args.compilation_cache)
    settings = Settings(num_envs=args.num_envs)
    if (args.num_envs * settings.n_steps) % settings.n_minibatches:
        parser.error(f"--num-envs x {settings.n_steps} steps must split into "
                     f"{settings.n_minibatches} minibatches")
    manifest = train(f"auv_envs/{args.env}", args.difficulty, args.timesteps, args.seed,
                     args.out, settings, args.evals, args.group, args.checkpoints)
    print(f"wrote {args.out} ({manifest['wall_time_s']} s, {manifest['n_timesteps']} steps)")


if __name__ == "__main__":
    main()
