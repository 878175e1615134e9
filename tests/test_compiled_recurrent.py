"""The compiled PPO's memory (baselines.rl.recurrent, lstm_hidden_size): the cell against
PyTorch's LSTM, the update's replay against the rollout it replays, and the exported
RecurrentPPO acting in the CPU env as the JAX policy acts, episode after episode."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("optax")
pytest.importorskip("mujoco.mjx")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import torch  # noqa: E402

import auv_envs  # noqa: E402,F401
from baselines.rl import compiled, recurrent  # noqa: E402
from baselines.rl.agents import load_policy_agent  # noqa: E402
from baselines.rl.config import ConfigError  # noqa: E402

ENV_ID = "auv_envs/DockingStation-v2"
HIDDEN = 8
#: Short episodes, so that a 12-step rollout of 4 envs crosses episode starts.
KWARGS = {"difficulty": "paper", "time_limit": 0.6}
SETTINGS = compiled.Settings(num_envs=4, n_steps=12, n_minibatches=2, n_epochs=1,
                             lstm_hidden_size=HIDDEN)


def test_the_cell_is_pytorchs_lstm():
    params = recurrent.lstm_init(jax.random.PRNGKey(0), 5, HIDDEN)
    params["b"] = params["b"] + 0.3 * jax.random.normal(jax.random.PRNGKey(1), (4 * HIDDEN,))
    xs = np.array(jax.random.normal(jax.random.PRNGKey(2), (7, 3, 5)))
    torch_lstm = torch.nn.LSTM(5, HIDDEN)
    with torch.no_grad():
        for name, value in recurrent.torch_weights(params).items():
            getattr(torch_lstm, name).copy_(torch.as_tensor(value))
        want, (h, c) = torch_lstm(torch.as_tensor(xs))
    starts = jnp.zeros((7, 3), bool)
    last, got = recurrent.lstm_unroll(params, recurrent.LSTMState.zeros(3, HIDDEN),
                                      jnp.asarray(xs), starts)
    np.testing.assert_allclose(np.asarray(got), want.numpy(), atol=1e-5)
    np.testing.assert_allclose(np.asarray(last.c), c.numpy()[0], atol=1e-5)


def test_an_episode_start_clears_the_memory():
    params = recurrent.lstm_init(jax.random.PRNGKey(0), 2, HIDDEN)
    xs = jax.random.normal(jax.random.PRNGKey(3), (6, 1, 2))
    starts = jnp.zeros((6, 1), bool).at[3].set(True)
    _, through = recurrent.lstm_unroll(params, recurrent.LSTMState.zeros(1, HIDDEN), xs, starts)
    _, fresh = recurrent.lstm_unroll(params, recurrent.LSTMState.zeros(1, HIDDEN), xs[3:],
                                     jnp.zeros((3, 1), bool))
    np.testing.assert_allclose(np.asarray(through[3:]), np.asarray(fresh), atol=1e-6)
    # and before the start the memory mattered: the same inputs from a blank state differ
    _, blank = recurrent.lstm_unroll(params, recurrent.LSTMState.zeros(1, HIDDEN), xs[1:3],
                                     jnp.zeros((2, 1), bool))
    assert np.abs(np.asarray(through[2]) - np.asarray(blank[1])).max() > 1e-3


@pytest.fixture(scope="module")
def trained():
    """One iteration of the recurrent PPO on short docking episodes."""
    env = compiled.make_env(ENV_ID, "features", KWARGS)
    trainer = compiled.Trainer(env, SETTINGS)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    first = rollout
    after, _, steps = jax.jit(trainer.collect)(params, normalizer, rollout, key)
    params2, *_ = trainer.iteration(params, opt_state, normalizer, rollout, key)
    return trainer, params, normalizer, first, after, steps, params2


def test_the_update_replays_the_rollout_it_learns_from(trained):
    """Truncated BPTT replays each env's rollout from the memory it began with, clearing it
    at the same episode starts: its means and values are the rollout's."""
    trainer, params, normalizer, first, _, steps, params2 = trained
    assert bool(steps.starts[0].all()) and float(steps.done.sum()) > 0  # episodes end in it
    assert bool(steps.starts[1:].any())
    mean, value = trainer.sequence_heads(params, normalizer, first, steps.obs,
                                         steps.privileged, steps.starts)
    np.testing.assert_allclose(np.asarray(value), np.asarray(steps.value), atol=1e-5)
    np.testing.assert_allclose(np.asarray(mean), np.asarray(steps.mean), atol=1e-5)
    np.testing.assert_allclose(np.asarray(compiled._log_prob(params, mean, steps.action)),
                               np.asarray(steps.log_prob), atol=1e-4)
    assert bool(trainer.all_finite(params2))
    assert any(float(jnp.abs(a - b).max()) > 0 for a, b in zip(
        jax.tree_util.tree_leaves(params), jax.tree_util.tree_leaves(params2), strict=True))


def test_the_exported_recurrent_policy_acts_as_the_jax_one(trained, tmp_path):
    """Written as sb3-contrib's RecurrentPPO, the policy acts in the CPU env as the JAX
    policy acts, carrying its memory across act() and starting blank at each reset()."""
    trainer, _, normalizer, *_, params = trained
    params = dict(params)
    params["pi"] = [*params["pi"][:-1], {"w": params["pi"][-1]["w"] * 300.0,
                                        "b": params["pi"][-1]["b"]}]
    run = {"env_id": ENV_ID, "obs_mode": "features", "seed": 0, "n_timesteps": 48,
           "wall_time_s": 0.0, "difficulty": "paper", "env_kwargs": KWARGS,
           "settings": SETTINGS._asdict(), "curve": []}
    manifest = compiled.export(params, normalizer, tmp_path / "policy", run)
    assert manifest["algo"] == "recurrentppo"
    cpu = gym.make(ENV_ID, obs_mode="features", difficulty="paper").unwrapped
    agent = load_policy_agent(tmp_path / "policy", cpu)
    assert agent.recurrent

    def jax_actions(observations, memory_kept=True):
        memory, out = recurrent.LSTMState.zeros(1, HIDDEN), []
        for k, obs in enumerate(observations):
            flat = compiled.flatten_observation({key: jnp.asarray(v) for key, v in obs.items()},
                                                trainer.keys)[None]
            start = jnp.asarray([k == 0 or not memory_kept])
            memory = recurrent.lstm_cell(params["lstm"], memory.cleared(start),
                                         normalizer(flat))
            out.append(np.clip(np.asarray(compiled._mlp(params["pi"], memory.h))[0], -1, 1))
        return np.stack(out)

    for seed in (4, 5):  # one agent, two episodes: its memory starts blank with each
        obs, info = cpu.reset(seed=seed)
        agent.reset(seed)
        observations, acted = [], []
        for _ in range(25):
            observations.append(obs)
            acted.append(agent.act(obs, info))
            obs, _, terminated, truncated, info = cpu.step(acted[-1])
            if terminated or truncated:
                break
        expected = jax_actions(observations)
        np.testing.assert_allclose(np.stack(acted), expected, atol=1e-4)
        # the memory matters: without it the same observations give other actions
        assert np.abs(jax_actions(observations, memory_kept=False) - expected).max() > 1e-2


def test_a_memory_is_given_to_mlp_policies_only():
    env = compiled.make_env("auv_envs/AcousticTracking-v2", "measurements", "paper",
                            detection_fixes=True)
    with pytest.raises(ConfigError, match="lstm_hidden_size"):
        compiled.Trainer(env, SETTINGS._replace(policy=compiled.SET_POLICY, normalize=False))


# ---------------------------------------------------------------- privileged critic
def test_a_privileged_critic_reads_what_the_exported_policy_never_sees(tmp_path):
    """The value reads the privileged state in training; the exported policy's inputs are
    the CPU env's own observation (flattened), its memory's width that observation's."""
    settings = SETTINGS._replace(privileged_critic=True)
    env = compiled.make_env(ENV_ID, "features", KWARGS, privileged=True)
    trainer = compiled.Trainer(env, settings)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(1))
    assert "vf_lstm" not in params and rollout.critic is None
    assert params["vf"][0]["w"].shape[0] == trainer.privileged_size
    assert params["lstm"]["w_ih"].shape[0] == trainer.obs_size
    params, *_ = trainer.iteration(params, opt_state, normalizer, rollout, key)
    assert bool(trainer.all_finite(params))
    run = {"env_id": ENV_ID, "obs_mode": "features", "seed": 0, "n_timesteps": 48,
           "wall_time_s": 0.0, "difficulty": "paper", "env_kwargs": KWARGS,
           "settings": settings._asdict(), "curve": []}
    manifest = compiled.export(params, normalizer.part(0, trainer.obs_size),
                               tmp_path / "policy", run)
    assert manifest["critic"].startswith("privileged_state")
    cpu = gym.make(ENV_ID, obs_mode="features", difficulty="paper").unwrapped
    agent = load_policy_agent(tmp_path / "policy", cpu)
    flat_size = gym.spaces.flatdim(cpu.observation_space)
    assert agent._model.observation_space.shape == (flat_size,) == (trainer.obs_size,)
    assert agent._model.policy.lstm_actor.input_size == flat_size
    obs, info = cpu.reset(seed=2)
    assert cpu.action_space.contains(agent.act(obs, info))
    with pytest.raises(ConfigError, match="privileged"):  # it needs the privileged env
        compiled.Trainer(compiled.make_env(ENV_ID, "features", KWARGS), settings)


def test_the_memory_learns_to_predict_the_privileged_state(tmp_path):
    """state_prediction_coef: a linear head on the LSTM regresses the privileged state; its
    loss alone, minimised over a rollout, falls, and the head is never exported."""
    settings = SETTINGS._replace(privileged_critic=True, state_prediction_coef=1.0,
                                 learning_rate=3e-3)
    env = compiled.make_env(ENV_ID, "features", KWARGS, privileged=True)
    trainer = compiled.Trainer(env, settings, total_iterations=1000)  # a slow decay
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(3))
    assert params["state_head"]["w"].shape == (HIDDEN, trainer.privileged_size)
    _, _, steps = jax.jit(trainer.collect)(params, normalizer, rollout, key)
    batch = (steps.obs, steps.privileged, steps.starts)

    def loss(params):
        hidden = trainer._sequence(params, normalizer, rollout, *batch)[2]
        return float(trainer.state_prediction_loss(params, normalizer, hidden,
                                                   steps.privileged))

    fit = jax.jit(lambda p, o: trainer._recurrent_epochs(
        lambda *_: 0.0, p, o, normalizer, rollout, batch, jax.random.PRNGKey(4)))
    before = loss(params)
    for _ in range(50):
        params, opt_state = fit(params, opt_state)
    assert loss(params) < 0.6 * before  # measured: 30 -> 12
    run = {"env_id": ENV_ID, "obs_mode": "features", "seed": 0, "n_timesteps": 48,
           "wall_time_s": 0.0, "difficulty": "paper", "env_kwargs": KWARGS,
           "settings": settings._asdict(), "curve": []}
    compiled.export(params, normalizer.part(0, trainer.obs_size), tmp_path / "policy", run)
    cpu = gym.make(ENV_ID, obs_mode="features", difficulty="paper").unwrapped
    model = load_policy_agent(tmp_path / "policy", cpu)._model
    widths = {p.shape[-1] for p in model.policy.parameters()}
    assert trainer.privileged_size not in widths  # nothing of the head's shape travels
    with pytest.raises(ConfigError, match="state_prediction_coef"):  # it needs a memory
        compiled.Trainer(env, settings._replace(lstm_hidden_size=0))


# ---------------------------------------------------------------- distillation
def test_the_truth_teacher_labels_the_true_position():
    """Acting with the truth teacher's labels (its share 1 at the first iteration), the
    acoustic estimate's error is zero up to float32: the labels are the true positions,
    in the frame and box the action is taken in."""
    settings = SETTINGS._replace(teacher="truth", teacher_fraction=1.0)
    env = compiled.make_env("auv_envs/AcousticTracking-v2", "measurements",
                            {"difficulty": "hard", "time_limit": 2.0}, detection_fixes=True,
                            privileged=True)
    trainer = compiled.Trainer(env, settings, total_iterations=10)
    params, _, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    assert set(params) == {"lstm", "pi", "log_std"}  # no critic
    _, _, steps = jax.jit(trainer.collect)(params, normalizer, rollout, key)
    rewards = np.asarray(steps.reward)
    assert rewards.min() > -1e-3  # the reward is the negative clipped error, scaled
    # the student's own untrained estimates are far off
    mean = trainer.sequence_heads(params, normalizer, rollout, *steps[:3])[0]
    assert float(jnp.abs(mean - steps.action).mean()) > 0.05


def test_distillation_fits_the_student_to_the_teacher():
    """The mission's homing teacher labels a rollout; epochs of the distillation loss on it
    bring the recurrent student's actions towards the labels."""
    settings = SETTINGS._replace(teacher="homing-pd", n_epochs=1, learning_rate=3e-3)
    env = compiled.make_env("auv_envs/DockingMission-v0", "nav_features", "paper",
                            privileged=True)
    trainer = compiled.Trainer(env, settings, total_iterations=10)
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    _, _, steps = jax.jit(trainer.collect)(params, normalizer, rollout, key)
    obs, privileged, starts, labels = steps.obs, steps.privileged, steps.starts, steps.action
    assert float(jnp.abs(labels).max()) > 0.3  # the teacher acts

    def loss(params):
        mean = trainer.sequence_heads(params, normalizer, rollout, obs, privileged, starts)[0]
        return float(trainer._distillation_loss(params, mean, None, labels))

    fit = jax.jit(lambda p, o: trainer._recurrent_epochs(
        trainer._distillation_loss, p, o, normalizer, rollout,
        (obs, privileged, starts, labels), jax.random.PRNGKey(2)))
    before = loss(params)
    for _ in range(30):
        params, opt_state = fit(params, opt_state)
    assert loss(params) < 0.5 * before


def test_teachers_refuse_envs_they_cannot_teach():
    env = compiled.make_env(ENV_ID, "features", KWARGS, privileged=True)
    for teacher in ("homing-pd", "homing-pd-corridor", "truth"):
        with pytest.raises(ConfigError, match="teach"):
            compiled.Trainer(env, SETTINGS._replace(teacher=teacher))
    mission = compiled.make_env("auv_envs/DockingMission-v0", "nav_features", "paper",
                                privileged=True)
    with pytest.raises(ConfigError, match="the pd teacher teaches"):
        compiled.Trainer(mission, SETTINGS._replace(teacher="pd"))
    with pytest.raises(ConfigError, match="unknown teacher"):
        compiled.Trainer(env, SETTINGS._replace(teacher="oracle"))


def test_the_corridor_teacher_is_the_homing_law_with_a_state_hand_over():
    """Its labels are homing_action's on NumPy with the latch replaced by in_corridor, on
    states inside and outside the corridor."""
    from baselines.docking.control.homing import HomingGains, homing_action, in_corridor
    from baselines.docking.control.pd import read_state
    from baselines.rl.teachers import make_teacher

    env = compiled.make_env("auv_envs/DockingMission-v0", "nav_features", "paper",
                            privileged=True)
    teacher = make_teacher("homing-pd-corridor", env)
    gains = HomingGains.from_calibration(env.calibration)
    rng = np.random.default_rng(5)
    states = np.zeros((40, 16), np.float32)
    states[:, 0] = gains.staging_point[0] + rng.uniform(-3.0, 11.0, 40)
    states[:, 1:3] = np.asarray(gains.staging_point)[1:] + rng.normal(0.0, 2.0, (40, 2))
    yaw = rng.uniform(-0.8, 0.8, 40)
    states[:, 5], states[:, 6] = np.cos(yaw), np.sin(yaw)
    states[:, 7:10] = rng.normal(0, 0.3, (40, 3))
    states[:, 12] = rng.normal(0, 0.1, 40)
    got, memory = teacher.act(teacher.init(40), jnp.asarray(states), jnp.ones(40, bool))
    corridor = []
    for k, obs in enumerate(states.astype(np.float64)):
        position, heading, _, _ = read_state(obs, np)
        corridor.append(bool(in_corridor(gains, position, heading, teacher.CORRIDOR_WIDTH, np)))
        want, _ = homing_action(gains, obs, corridor[-1], np)
        np.testing.assert_allclose(np.asarray(got[k]), want, atol=1e-5)
    assert 5 < sum(corridor) < 35 and memory is None  # both laws were checked


def test_the_pd_teacher_docks_the_batched_station_as_pd_state_docks_the_cpu_one():
    """Executing its own labels (its share 1 at the first iteration), the ``pd`` teacher
    docks the batched stations of a rollout at ``paper``, as ``pd-state`` docks the CPU
    env (430-570 steps on seeds 0-2): the teacher reads the privileged state in the frame
    and units the law expects. Every episode that ends within the rollout docks."""
    settings = SETTINGS._replace(lstm_hidden_size=0, teacher="pd", teacher_fraction=1.0,
                                 n_steps=700)
    env = compiled.make_env(ENV_ID, "features", "paper", privileged=True)
    trainer = compiled.Trainer(env, settings, total_iterations=10)
    params, _, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    _, _, steps = jax.jit(trainer.collect)(params, normalizer, rollout, key)
    done, success = np.asarray(steps.done) > 0, np.asarray(steps.success)
    ended = done.any(axis=0)
    assert ended.sum() >= 3, ended
    first_end = done.argmax(axis=0)
    assert success[first_end, np.arange(done.shape[1])][ended].all()
