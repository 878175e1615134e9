"""A digest of seeded batched rollouts: run it on two commits to show they agree bit for bit.

    python scripts/batched_trajectories.py

Per case (a family's id, a batched mode, a level), eight environments reset from one key
and stepped 60 times under seeded uniform actions, their episodes cut at 40 steps (so the
auto-reset runs); every step's observation, reward, done flag, metrics (by name) and
``data`` are hashed in order and the SHA-256's first 16 hex digits printed. A change that
must leave the batched episodes unchanged must leave every digest unchanged. At commits
before the one batched shell (``FunctionalEnv(env_id, ...)``) the family table's batched
class builds the env.
"""

from __future__ import annotations

import hashlib
import inspect

import jax
import numpy as np

import auv_envs  # noqa: F401

#: (id, batched mode, keywords) of each digest.
CASES = [("auv_envs/DockingStation-v2", "features", {}),
         ("auv_envs/LampArrayDocking-v2", "state", {"difficulty": "hard"}),
         ("auv_envs/DockingMission-v0", "nav_features", {"difficulty": "paper"}),
         ("auv_envs/LARSCapture-v0", "features", {"difficulty": "hard"}),
         ("auv_envs/AcousticTracking-v2", "measurements", {"difficulty": "paper"})]


def make(env_id: str, mode: str, kw: dict):
    """The batched env of ``env_id`` in ``mode`` with the keywords ``kw``."""
    from auv_envs.batched.functional import FunctionalEnv

    if "env_id" in inspect.signature(FunctionalEnv.__init__).parameters:
        return FunctionalEnv(env_id, obs_mode=mode, **kw)
    from auv_envs.families import family
    return family(env_id).batched_class()(env_id, obs_mode=mode, **kw)


def main() -> None:
    for env_id, mode, kw in CASES:
        digest_case(env_id, mode, kw)


def digest_case(env_id: str, mode: str, kw: dict) -> None:
    """Print the digest of one case's rollout."""
    env = make(env_id, mode, kw)
    env.max_episode_steps = 40
    n = 8
    states = jax.jit(env.reset_batch)(jax.random.split(jax.random.PRNGKey(3), n))
    step = jax.jit(env.step_batch)
    rng = np.random.default_rng(0)
    low, high = env.action_space.low, env.action_space.high
    digest = hashlib.sha256()

    def feed(tree):
        for leaf in jax.tree_util.tree_leaves(tree):
            a = np.asarray(leaf)
            digest.update(str(a.dtype).encode() + a.tobytes())

    for _ in range(60):
        actions = rng.uniform(low, high, (n, env.action_size)).astype(np.float32)
        states = step(states, actions)
        metrics = {key: states.metrics[key] for key in sorted(states.metrics)}
        feed((states.obs, states.reward, states.done, metrics, states.data))
    print(env_id, mode, digest.hexdigest()[:16], flush=True)


if __name__ == "__main__":
    main()
