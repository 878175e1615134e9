"""Pytrees declared where their classes are defined (:mod:`auv_envs.core.pytree`): the CPU
environments never import JAX, the batched tasks find every declared class registered, a
class declared after JAX is loaded is registered at once, and each flattens and rebuilds
as itself."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import textwrap

import numpy as np
import pytest

jax = pytest.importorskip("jax")

from auv_envs.core.pytree import attribute_pytree, dataclass_pytree  # noqa: E402


def test_the_cpu_envs_leave_jax_unloaded_and_the_batched_tasks_register_the_declared():
    """In a fresh process: the LARS and acoustic envs step without importing JAX, their
    classes wait; loading the batched tasks registers every one of them."""
    code = textwrap.dedent("""
        import sys
        import gymnasium as gym
        import numpy as np
        import auv_envs
        from auv_envs.core import pytree
        for env_id in ("auv_envs/LARSCapture-v0", "auv_envs/AcousticTracking-v2"):
            env = gym.make(env_id, difficulty="hard")
            env.reset(seed=0)
            env.step(env.action_space.sample())
        assert "jax" not in sys.modules, "a CPU env imported JAX"
        waiting = {cls.__name__ for cls, _ in pytree._WAITING}
        print(sorted(waiting))
        import auv_envs.tasks.lars.jax_task, auv_envs.tasks.acoustic.jax_task
        from jax.tree_util import tree_flatten
        assert not pytree._WAITING
        from auv_envs.core.acoustics import Measurements
        from auv_envs.core.sea import WashOver
        m = Measurements(values=np.ones((2, 3)), mask=np.ones(2, bool),
                         origin=np.zeros(2, int), dropped=np.zeros(1, bool))
        leaves, tree = tree_flatten(m)
        assert len(leaves) == 4 and tree.unflatten(leaves) == m
        w = WashOver(period=4.0, duration=1.0, phase=0.5, sweep=2.0, overtop=0.1,
                     half_size=(1.0, 1.0, 0.2))
        leaves, tree = tree_flatten(w)
        assert leaves == [4.0, 1.0, 0.5], leaves  # the meta fields are static
        assert tree.unflatten(leaves) == w
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    waiting = eval(done.stdout.strip().splitlines()[-1])
    assert {"AUVMotion", "EpisodeSea", "GlintField", "WashOver", "FloatingAnalog",
            "WaveRealisation", "HarmonicSeries", "Measurements"} <= set(waiting)


def test_a_class_declared_once_jax_is_loaded_is_a_pytree_at_once():
    @dataclass_pytree(meta=("name",))
    @dataclasses.dataclass(frozen=True)
    class Draws:
        gain: object
        name: str

    @attribute_pytree(("values",), ("size",))
    class Buffer:
        def __init__(self, values):
            raise AssertionError("rebuilt without its constructor")

    draws = Draws(gain=np.arange(3.0), name="a")
    doubled = jax.tree_util.tree_map(lambda leaf: 2 * leaf, draws)
    assert isinstance(doubled, Draws) and doubled.name == "a"
    np.testing.assert_array_equal(doubled.gain, [0.0, 2.0, 4.0])
    buffer = object.__new__(Buffer)
    buffer.values, buffer.size = np.ones(2), 2
    leaves, tree = jax.tree_util.tree_flatten(buffer)
    assert len(leaves) == 1
    rebuilt = tree.unflatten([np.zeros(2)])
    assert isinstance(rebuilt, Buffer) and rebuilt.size == 2
    np.testing.assert_array_equal(rebuilt.values, [0.0, 0.0])


def test_a_static_field_that_does_not_exist_is_refused():
    with pytest.raises(TypeError, match="no fields"):
        @dataclass_pytree(meta=("missing",))
        @dataclasses.dataclass(frozen=True)
        class Draws:
            gain: float
