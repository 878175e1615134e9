"""CasADi functions as machine code (:mod:`auv_envs.core.native`): the same numbers as
CasADi's virtual machine, and the virtual machine wherever machine code cannot be had."""

import warnings

import casadi
import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401  (registers the envs)
from auv_envs.core import native
from auv_envs.core.plant import CompiledFunction

needs_compiler = pytest.mark.skipif(native.compiler() is None, reason="no C compiler")


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    """A cache of this test's own, and nothing loaded yet in this process."""
    monkeypatch.setenv("AUV_ENVS_CACHE", str(tmp_path))
    monkeypatch.setenv("AUV_ENVS_NATIVE", "1")
    monkeypatch.setattr(native, "_loaded", {})
    return tmp_path


def _function(name="native_check"):
    """Arithmetic, elementary functions and a comparison, as the shipped functions use."""
    x = casadi.SX.sym("x", 4)
    out = casadi.vertcat(x[0] * x[1] + x[2], casadi.atan2(x[1], x[0]),
                         casadi.sqrt(x[0] * x[0] + x[3] * x[3]),
                         casadi.sin(x[2]) * casadi.cos(x[3]),
                         casadi.if_else(x[0] < x[1], x[2], x[3]), x[0] / x[3])
    return casadi.Function(name, [x], [out], {"cse": True})


def _episode(env_id, monkeypatch, on, steps=60, **kwargs):
    """Observations, rewards and infos' numbers of a seeded episode with machine code on/off."""
    monkeypatch.setenv("AUV_ENVS_NATIVE", "1" if on else "0")
    env = gym.make(env_id, **kwargs)
    obs, _ = env.reset(seed=11)
    rng = np.random.default_rng(3)
    out = [obs]
    for _ in range(steps):
        action = rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, {k: v for k, v in info.items() if isinstance(v, float)}))
        if terminated or truncated:
            break
    env.close()
    return out


@needs_compiler
def test_machine_code_gives_the_virtual_machines_bits(own_cache):
    function = _function()
    code = native.machine_code(function)
    assert code is not function  # machine code, loaded
    assert list(own_cache.glob("native/*/native_check-*.so"))
    theirs = _bound(code)
    vm = _bound(function)
    rng = np.random.default_rng(0)
    for _ in range(200):
        vm.inputs[0][:] = theirs.inputs[0][:] = rng.standard_normal(4) * 10.0
        assert np.array_equal(vm()[0], theirs()[0], equal_nan=True)


def _bound(function):
    """A :class:`CompiledFunction` evaluating exactly ``function`` (no machine code)."""
    call = CompiledFunction.__new__(CompiledFunction)
    call.function = function
    call.inputs = tuple(np.zeros(function.nnz_in(i)) for i in range(function.n_in()))
    call.outputs = tuple(np.zeros(function.nnz_out(i)) for i in range(function.n_out()))
    buffer, call._evaluate = function.buffer()
    for i, array in enumerate(call.inputs):
        buffer.set_arg(i, memoryview(array))
    for i, array in enumerate(call.outputs):
        buffer.set_res(i, memoryview(array))
    call._buffer = buffer
    return call


@needs_compiler
@pytest.mark.parametrize("env_id, kwargs", [
    ("auv_envs/DockingStation-v2", {"obs_mode": "state"}),
    ("auv_envs/LampArrayDocking-v2", {"obs_mode": "features", "difficulty": "hard"}),
    ("auv_envs/LARSCapture-v0", {"obs_mode": "features"}),
])
def test_envs_step_the_same_bits_with_and_without_machine_code(env_id, kwargs, own_cache,
                                                                monkeypatch):
    on = _episode(env_id, monkeypatch, True, **kwargs)
    assert list(own_cache.glob("native/*/*.so"))  # the env's functions did run as machine code
    off = _episode(env_id, monkeypatch, False, **kwargs)
    assert len(on) == len(off)
    for a, b in zip(on, off, strict=True):
        np.testing.assert_equal(a, b)


@needs_compiler
def test_a_host_with_other_cpu_features_builds_its_own_library(own_cache, monkeypatch):
    """Nodes sharing a cache (faked here: a second host's CPU features) never load each
    other's libraries: each kind of host builds and keeps its own, and a host of the
    same kind finds the one already built."""
    from auv_envs.core import cache

    function = _function("host_check")
    assert native.machine_code(function) is not function
    here = native.library(function, native.compiler())[0]
    assert here.exists() and here.parent == own_cache / "native" / cache.host_key()

    features = cache.cpu_features()
    monkeypatch.setattr(cache, "cpu_features", lambda: features + " avx512f_fake")
    monkeypatch.setattr(native, "_loaded", {})
    there = native.library(function, native.compiler())[0]
    assert there.parent != here.parent and not there.exists()
    stamp = here.stat().st_mtime_ns
    assert native.machine_code(function) is not function
    assert there.exists() and str(there) in native._loaded and str(here) not in native._loaded
    assert here.stat().st_mtime_ns == stamp  # the first host's library is untouched

    monkeypatch.setattr(cache, "cpu_features", lambda: features)
    monkeypatch.setattr(native, "_loaded", {})
    assert native.machine_code(function) is not function
    assert list(native._loaded) == [str(here)]  # the same kind of host: the same library


def test_every_cache_is_kept_per_kind_of_host(tmp_path, monkeypatch):
    """The compiled C steps, the compiled solvers and JAX's programs each live under
    ``<user cache>/<kind>/<host key>``, and a second host's identity moves all three."""
    from auv_envs.core import cache
    from baselines.docking.control import ofnmpc

    monkeypatch.setenv("AUV_ENVS_CACHE", str(tmp_path))
    here = {"native": native.cache_dir(), "casadi": ofnmpc.cache_dir()}
    for kind, path in here.items():
        assert path == tmp_path / kind / cache.host_key()
    monkeypatch.delenv("AUV_ENVS_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert native.cache_dir() == tmp_path / "xdg" / "auv_envs" / "native" / cache.host_key()
    monkeypatch.setenv("AUV_ENVS_CACHE", str(tmp_path))
    features = cache.cpu_features()
    monkeypatch.setattr(cache, "cpu_features", lambda: features + " sve_fake")
    assert native.cache_dir() != here["native"] and ofnmpc.cache_dir() != here["casadi"]
    assert native.cache_dir().parent == here["native"].parent


def test_no_compiler_leaves_the_virtual_machine(own_cache, monkeypatch):
    monkeypatch.setenv("CC", "no-such-compiler-anywhere")
    function = _function()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing to warn about: the same numbers
        assert native.machine_code(function) is function
    assert not list(own_cache.iterdir())


def test_switched_off_leaves_the_virtual_machine(own_cache, monkeypatch):
    monkeypatch.setenv("AUV_ENVS_NATIVE", "0")
    function = _function()
    assert native.machine_code(function) is function


def test_a_failing_compiler_warns_and_leaves_the_virtual_machine(own_cache, monkeypatch):
    monkeypatch.setenv("CC", "false")  # exits 1 whatever it is given
    if native.compiler() is None:
        pytest.skip("no `false` on the path")
    function = _function()
    with pytest.warns(RuntimeWarning, match="no machine code"):
        assert native.machine_code(function) is function


@needs_compiler
def test_a_damaged_library_is_built_again(own_cache):
    function = _function("damaged_check")
    path, _ = native.library(function, native.compiler())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"not a shared library")  # e.g. a build cut short elsewhere
    code = native.machine_code(function)
    assert code is not function
    assert path.read_bytes()[:4] == b"\x7fELF"


@needs_compiler
def test_machine_code_with_other_numbers_is_refused(own_cache, monkeypatch):
    # Fused multiply-adds round once where the virtual machine rounds twice: a library
    # built so differs in the last bit, and the check must catch it.
    monkeypatch.setattr(native, "FLAGS", ("-O2", "-fPIC", "-shared", "-ffp-contract=fast",
                                          "-march=native"))
    x = casadi.SX.sym("x", 3)
    function = casadi.Function("fma_check", [x], [x[0] * x[1] + x[2]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = native.machine_code(function)
    fused = any("differ" in str(w.message) for w in caught)
    if not fused:  # a CPU without fused multiply-adds: the library is the same numbers
        assert code is not function
        pytest.skip("this CPU has no fused multiply-add: nothing differs")
    assert code is function
