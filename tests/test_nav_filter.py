"""The navigation filter as a learner's front end (baselines/rl/nav_filter.py): in JAX
(float32) the estimates nav-homing-ofnmpc-ekf's filter makes in NumPy (float64; that one is
tested against Stone Soup's Kalman filter in test_navigation_filter.py), in the CPU
wrapper, the batched env and an exported policy."""

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import auv_envs  # noqa: F401 (registers the ids)
from baselines.docking.agents import MissionAgent
from baselines.rl import compiled
from baselines.rl import nav_filter as nf
from baselines.rl.agents import load_policy_agent
from baselines.rl.config import ConfigError

MISSION = "auv_envs/DockingMission-v0"
STEPS = 300


def _episode(level: str, seed: int):
    """The observations of the first STEPS steps of the pipeline's approach, and its
    filter's estimate after each."""
    env = gym.make(MISSION, obs_mode="nav_features", difficulty=level)
    obs, _ = env.reset(seed=seed)
    agent = MissionAgent(env.unwrapped)
    agent.reset()
    observations, estimates = [], []
    for _ in range(STEPS):
        action = agent.act(obs, {})
        observations.append(obs)
        estimates.append(agent.filter.p.copy())
        obs, _, terminated, truncated, info = env.step(action)
        assert not (terminated or truncated)
    return env, observations, np.array(estimates), agent.filter, info["true_position"]


@pytest.mark.parametrize("level", ["paper", "hard"])
def test_the_filter_estimates_as_the_pipelines_navigation_filter(level):
    """NumPy: the pipeline's own estimates, the same fixes taken and rejected; JAX (float32,
    jit): the same fixes, and within 2 mm of the float64 estimates at every step."""
    env, observations, expected, oracle, truth = _episode(level, seed=11)
    params = nf.params_of(env).nav
    state, state32 = nf.FilterState.start(params), nf.FilterState.start(params, jnp)
    step32 = jax.jit(lambda s, o: nf.step(params, s, o, jnp))
    got, got32 = [], []
    for obs in observations:
        state = nf.step(params, state, obs)
        state32 = step32(state32, {k: jnp.asarray(v) for k, v in obs.items()})
        got.append(state.position)
        got32.append(np.asarray(state32.position))
    np.testing.assert_allclose(np.array(got), expected, atol=1e-6)
    assert (int(state.fixes), int(state.rejected)) == (oracle.fixes, oracle.rejected)
    assert (int(state32.fixes), int(state32.rejected)) == (oracle.fixes, oracle.rejected)
    assert oracle.fixes > 5
    np.testing.assert_allclose(np.array(got32), expected, atol=0.002)
    # the estimate is of the vehicle (a step earlier): within 10 % of its range (hard's
    # USBL is coarse)
    assert np.linalg.norm(np.array(got)[-1] - truth) < 0.1 * np.linalg.norm(truth)


def test_the_wrapper_adds_the_estimate_and_starts_afresh_each_episode():
    env = nf.NavFilter(gym.make(MISSION, obs_mode="nav_features"))
    obs, _ = env.reset(seed=2)
    assert env.observation_space.contains(obs)
    added = {name for name, _ in nf.ADDED}
    assert added <= set(obs) and set(env.unwrapped.observation_space.spaces) < set(obs)
    for _ in range(30):
        obs, *_ = env.step(np.zeros(4, np.float32))
    assert int(env.state.nav.length) == 31
    # nav_entrance is the entrance from the estimate, in body axes
    R = nf.rotation(np.asarray(obs["attitude"], float))
    np.testing.assert_allclose(R @ obs["nav_entrance"], -obs["nav_position"], atol=1e-3)
    env.reset(seed=3)
    assert int(env.state.nav.length) == 1 and int(env.state.nav.fixes) <= 1


def test_the_filter_refuses_other_envs_and_modes():
    with pytest.raises(ConfigError, match="nav_features"):
        nf.NavFilter(gym.make(MISSION, obs_mode="nav"))
    with pytest.raises(ConfigError, match="navigation"):
        nf.NavFilter(gym.make("auv_envs/DockingStation-v2", obs_mode="features"))
    with pytest.raises(ConfigError, match="nav_filter"):
        compiled.make_env("auv_envs/DockingStation-v2", "features", "paper", nav_filter=True)


def test_the_batched_filter_restarts_with_each_episode():
    """The carry rides in the state's info and starts afresh where an episode restarts."""
    env = compiled.make_env(MISSION, "nav_features", {"difficulty": "paper",
                                                      "time_limit": 2.0}, nav_filter=True)
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    states = jax.vmap(env.reset)(keys)
    assert set(env.observation_space.spaces) >= {name for name, _ in nf.ADDED}
    step = jax.jit(env.step_batch)
    zero = jnp.zeros((2, 4))
    lengths = []
    for _ in range(25):  # 2 s at 0.1 s: one restart
        states = step(states, zero)
        lengths.append(np.asarray(states.info["nav_filter"].nav.length))
    lengths = np.array(lengths)
    assert lengths.max() == 20 and (lengths[-1] < 10).all()
    assert np.isfinite(np.asarray(states.obs["nav_position"])).all()


def test_a_policy_on_the_filter_exports_and_acts_on_the_cpu_as_on_jax(tmp_path):
    """An iteration of 4 envs x 4 steps, the policy written, then acting in the CPU env
    (through NavFilter) as the JAX policy acts on the same filter's observation."""
    kwargs = {"difficulty": "paper"}
    env = compiled.make_env(MISSION, "nav_features", kwargs, nav_filter=True)
    settings = compiled.Settings(num_envs=4, n_steps=4, n_minibatches=2, n_epochs=1)
    trainer = compiled.Trainer(env, settings)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    params, opt_state, normalizer, rollout, key, _ = trainer.iteration(
        params, opt_state, normalizer, rollout, key)
    params["pi"][-1]["w"] = params["pi"][-1]["w"] * 100.0  # actions far from zero
    run = {"env_id": MISSION, "obs_mode": "nav_features", "seed": 0, "n_timesteps": 16,
           "wall_time_s": 0.0, "difficulty": "paper", "env_kwargs": kwargs,
           "nav_filter": True, "settings": settings._asdict(), "curve": []}
    manifest = compiled.export(params, normalizer, tmp_path / "policy", run)
    assert manifest["nav_filter"] and manifest["flatten_obs"]
    cpu = gym.make(MISSION, obs_mode="nav_features", **kwargs).unwrapped
    agent = load_policy_agent(tmp_path / "policy", cpu)
    front = nf.NavFilter(gym.make(MISSION, obs_mode="nav_features", **kwargs))
    for seed in (4, 5):  # one agent, two episodes: its filter starts afresh with each
        obs, info = cpu.reset(seed=seed)
        agent.reset(seed)
        front.clear()
        for _ in range(15):
            seen = {k: jnp.asarray(v) for k, v in front.observation(obs).items()}
            flat = compiled.flatten_observation(seen, trainer.keys)
            unit = np.clip(np.asarray(compiled._mlp(params["pi"], normalizer(flat[None]))[0]),
                           -1.0, 1.0)
            action = agent.act(obs, info)
            np.testing.assert_allclose(action, np.asarray(env._action(unit)), rtol=1e-4,
                                       atol=1e-3)
            obs, _, terminated, truncated, info = cpu.step(action)
            assert not (terminated or truncated)


def test_a_shipped_policy_says_which_front_end_it_reads_through():
    from baselines.rl.config import FRONT_END_WORDS, FRONT_ENDS
    from baselines.rl.manifest import policies_root, read_manifest

    assert set(FRONT_END_WORDS) == set(FRONT_ENDS)
    manifest = read_manifest(policies_root() / "cppo-mission-nav-filter-s0")
    assert manifest["nav_filter"] is True
    assert "through the navigation filter" in manifest["description"]


def test_the_shipped_agent_reports_its_filters_estimate():
    """The leaderboard scores a policy agent's position estimate where its front end makes
    one (the navigation filter), as it scores the pipeline's; other policy agents have
    none."""
    from baselines.registry import make_agent

    env = gym.make(MISSION, obs_mode="nav_features", difficulty="paper")
    agent = make_agent("cppo-mission-nav-filter-s0", env.unwrapped)
    obs, info = env.reset(seed=7)
    agent.reset(7)
    estimates = []
    for _ in range(100):
        action = agent.act(obs, info)
        estimates.append(agent.position_estimate())
        obs, _, terminated, truncated, info = env.step(action)
        assert not (terminated or truncated)
    assert estimates[0] is None  # no fix yet
    assert np.linalg.norm(estimates[-1] - info["true_position"]) \
        < 0.1 * np.linalg.norm(info["true_position"])
    docking = gym.make("auv_envs/DockingStation-v2", obs_mode="features").unwrapped
    assert not hasattr(make_agent("cppo-docking-features-hard-s0", docking),
                       "position_estimate")
