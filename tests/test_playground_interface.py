"""Every batched env has MuJoCo Playground's ``MjxEnv`` interface: it is one (a virtual
subclass, once ``auv_envs.batched.load`` has run where Playground is installed), its
``xml_path`` loads as its ``mj_model``, its time steps agree and ``render`` draws a
rollout, as Playground's ``MjxEnv.render`` does."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("mujoco_playground")
import mujoco  # noqa: E402
from mujoco_playground._src.mjx_env import MjxEnv  # noqa: E402

import auv_envs.batched  # noqa: E402
from tests.conftest import JAX_TASKS as SHELLS  # noqa: E402


def same_model(a: mujoco.MjModel, b: mujoco.MjModel) -> list[str]:
    """The array fields in which two models differ."""
    return [name for name in dir(a) if not name.startswith("_")
            and isinstance(getattr(a, name), np.ndarray)
            and not (getattr(a, name).shape == getattr(b, name).shape
                     and np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True))]


@pytest.mark.parametrize("env_id", SHELLS)
def test_the_batched_env_is_playgrounds_mjx_env(env_id, tmp_path, monkeypatch):
    monkeypatch.setenv("AUV_ENVS_CACHE", str(tmp_path))
    env = auv_envs.batched.load(env_id)
    assert isinstance(env, MjxEnv)
    path = env.xml_path
    assert path.startswith(str(tmp_path / "models"))
    assert same_model(mujoco.MjModel.from_xml_path(path), env.mj_model) == []
    assert env.xml_path == path  # written once
    assert set(env.model_assets) <= {p.name for p in (tmp_path / "models").rglob("*")}
    assert env.n_substeps * env.sim_dt == pytest.approx(env.dt)
    assert env.unwrapped is env and env.mjx_model.physics is None

    reset, step = jax.jit(env.reset), jax.jit(env.step)
    states = [reset(jax.random.PRNGKey(0))]
    action = np.linspace(1.0, -1.0, env.action_size).astype(np.float32)
    for _ in range(25):
        states.append(step(states[-1], action))
    frames = env.render([states[0], states[-1]], height=60, width=80)
    assert len(frames) == 2 and all(f.shape == (60, 80, 3) and f.dtype == np.uint8
                                    for f in frames)
    assert np.abs(frames[0].astype(int) - frames[1].astype(int)).max() > 0  # it moved
    assert env.render(states[-1], height=60, width=80).shape == (60, 80, 3)
    batch = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(1), 2))
    with pytest.raises(ValueError, match="unbatched"):
        env.render(batch)
