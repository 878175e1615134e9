"""The acoustic RL front end (baselines/rl/detection_fixes.py): one definition, NumPy and JAX.

Checks that the positioner's fixed-shape solve on JAX (float32) gives the NumPy fixes of
the real detections, that the front end's observation on JAX is the CPU wrapper's, that
it holds the last step's fixes as documented, and that the batched wrapper forgets them
with each new episode.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from baselines.rl.config import ConfigError
from baselines.rl.detection_fixes import (
    FIX_KEYS,
    OBS_KEYS,
    DetectionFixes,
    FixParams,
    Held,
    observe,
)

ACOUSTIC = "auv_envs/AcousticTracking-v2"
ESTIMATE = np.array([150.0, 150.0, -15.0], np.float32)


def _observations(difficulty: str, seed: int, steps: int) -> tuple[gym.Env, list]:
    env = gym.make(ACOUSTIC, obs_mode="measurements", difficulty=difficulty)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(ESTIMATE)
        out.append(obs)
    return env, out


@pytest.mark.parametrize(("difficulty", "seed"), [("paper", 3), ("hard", 8)])
def test_the_fixed_shape_solve_on_jax_gives_the_numpy_fixes(difficulty, seed):
    import jax
    import jax.numpy as jnp

    env, observations = _observations(difficulty, seed, 60)
    positioner = FixParams.of(env).positioner

    @jax.jit
    def solve(obs):
        fixes = positioner.solve_fixed(
            *(obs[key].astype(jnp.float32) for key in ("tdoa", "azimuth", "elevation")),
            obs["mask"], obs.get("node_mask"), xp=jnp)
        return fixes.position, fixes.covariance, fixes.chi2, fixes.dof, fixes.valid

    compared = dropped = 0
    for obs in observations:
        nodes = obs.get("node_mask")
        reference = positioner.solve(obs["tdoa"], obs["azimuth"], obs["elevation"], obs["mask"],
                                     nodes=nodes)
        position, covariance, chi2, dof, valid = (np.asarray(a) for a in solve(
            {key: jnp.asarray(value) for key, value in obs.items()}))
        np.testing.assert_array_equal(valid, reference.valid)
        assert int(dof) == reference.dof
        dropped += nodes is not None and not nodes.all()
        both = reference.valid
        compared += int(both.sum())
        np.testing.assert_allclose(position[both], reference.position[both], atol=0.01)
        np.testing.assert_allclose(chi2[both], reference.chi2[both], rtol=0.01)
        stds = np.sqrt(np.diagonal(covariance[both], axis1=-2, axis2=-1))
        reference_stds = np.sqrt(np.diagonal(reference.covariance[both], axis1=-2, axis2=-1))
        np.testing.assert_allclose(stds, reference_stds, rtol=0.01)
    assert compared > 50  # real fixes were compared, not empty sets
    if difficulty == "hard":
        assert dropped > 0  # and some under node dropouts (the dof from the node mask)


def test_the_front_end_on_jax_gives_the_cpu_observation():
    import jax
    import jax.numpy as jnp

    env, observations = _observations("hard", 5, 80)
    wrapper = DetectionFixes(gym.make(ACOUSTIC, obs_mode="measurements", difficulty="hard"))
    params = wrapper.params
    step = jax.jit(lambda held, obs: observe(params, held, obs, jnp))
    held_cpu, held_jax = Held.start(params), Held.start(params, jnp)
    worst = 0.0
    for obs in observations:
        held_cpu, cpu = observe(params, held_cpu, obs)
        held_jax, traced = step(held_jax, {key: jnp.asarray(value) for key, value in obs.items()})
        assert set(cpu) == set(OBS_KEYS) and wrapper.observation_space.contains(cpu)
        for key in ("fix_valid", "held_fix_valid"):
            np.testing.assert_array_equal(cpu[key], np.asarray(traced[key]))
        np.testing.assert_allclose(cpu["held_age"], np.asarray(traced["held_age"]), atol=1e-6)
        for key in ("fix", "held_fix"):  # action units to metres: half the box's span
            metres = (cpu[key] - np.asarray(traced[key])) * params.span / 2.0
            worst = max(worst, float(np.max(np.abs(metres))))
        for key in ("fix_log_std", "fix_log_fit", "held_fix_log_std", "held_fix_log_fit"):
            np.testing.assert_allclose(cpu[key], np.asarray(traced[key]), atol=0.01)
    assert worst < 0.01, worst


def test_the_front_end_holds_the_last_step_with_a_fix():
    wrapper = DetectionFixes(gym.make(ACOUSTIC, obs_mode="measurements", difficulty="hard"))
    obs, _ = wrapper.reset(seed=21)
    assert not obs["held_fix_valid"].any() and obs["held_age"][0] == 0.0
    last, age, checked = None, 0, 0
    for _ in range(300):
        if obs["fix_valid"].any():
            last, age = obs, 0
        obs, *_ = wrapper.step(ESTIMATE)
        age += 1
        if last is None:
            continue
        for key in FIX_KEYS:  # the held tokens are those of the latest step with a fix
            np.testing.assert_array_equal(obs[f"held_{key}"], last[key])
        assert obs["held_age"][0] == pytest.approx(np.log1p(age))
        checked += age > 1  # a step after one without any valid fix
    assert checked > 0  # the hard level's dropouts left steps without a fix
    obs, _ = wrapper.reset(seed=22)  # a new episode holds nothing
    assert not obs["held_fix_valid"].any() and obs["held_age"][0] == 0.0


def test_the_batched_front_end_forgets_with_each_new_episode():
    import jax
    import jax.numpy as jnp

    from auv_envs.batched.functional import FunctionalEnv
    from baselines.rl.detection_fixes import DetectionFixesMJX

    base = FunctionalEnv("auv_envs/AcousticTracking-v2", obs_mode="measurements",
                         difficulty="paper", time_limit=0.05)
    env = DetectionFixesMJX(base.use_unit_actions())
    assert env.max_episode_steps == 5
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(2), 4))
    assert states.obs["fix"].shape == (4, 10, 8, 3)
    step = jax.jit(env.step_batch)
    restarted = 0
    for _ in range(7):
        states = step(states, jnp.zeros((4, 3)))
        done = np.asarray(states.done)
        held = states.info["detection_fixes"]
        age = np.asarray(states.obs["held_age"])[:, 0]
        # a new episode's first observation holds nothing; the others hold a fix
        assert np.all(age[done] == 0.0) and not np.asarray(states.obs["held_fix_valid"])[done].any()
        assert np.all(np.asarray(held.steps)[~done] >= 1)
        restarted += int(done.sum())
    assert restarted == 4  # every episode ended once in seven steps


def test_the_front_end_refuses_other_envs():
    with pytest.raises(ConfigError, match="obs_mode='measurements'"):
        DetectionFixes(gym.make(ACOUSTIC, obs_mode="state"))
    with pytest.raises(ConfigError, match="obs_mode='measurements'"):
        FixParams.of(gym.make("auv_envs/DockingStation-v2", obs_mode="features"))
