"""The hydrophone array's measurement model on JAX (:mod:`auv_envs.core.acoustics` with
``xp=jax.numpy``): the same formulas as on NumPy, and the fixed-shape draw of the
detection sets (``noise_draws="fixed"``) the same model as NumPy's ``"kept"`` draw."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from auv_envs.batched.functional import KeyDraws
from auv_envs.core.acoustics import (
    ORIGIN_CLUTTER,
    ORIGIN_EMPTY,
    ORIGIN_TARGET,
    HydrophoneArray,
    Measurements,
    _wrap,
    two_state_markov,
    unit_gauss_markov,
)
from auv_envs.core.env import TaskEnv
from auv_envs.tasks.acoustic.env import AcousticTrackingTask

#: Environments of one period each in a ``jit(vmap(measure))`` call, and the sample
#: periods of each side of the comparisons in distribution (calls of ``BATCH``).
BATCH = 256
PERIODS = 16 * BATCH
#: Tolerance of those comparisons in standard errors: the sampling error of the
#: difference (two samples) or of one sample's estimate against the model's value.
SIGMAS = 5.0
#: A source in the tank (m) where every band and its surface ghost are sometimes
#: detected, and the draws' other inputs: clock offsets (s), current speed (m/s), the
#: water's true sound speed (m/s).
SOURCE = np.array([110.0, 90.0, -12.0])
CLOCKS = np.array([0.0, 1e-5, -2e-5, 3e-5, 0.0, -1e-5, 2e-5, 5e-6])
CURRENT = 0.3
SOUND_SPEED = 1503.0


def _array(level: str):
    return TaskEnv(AcousticTrackingTask,
                   obs_mode="measurements", difficulty=level).calibration.array


@pytest.fixture(scope="module")
def hard():
    """Multipath, clutter, band fading, node dropouts, flow noise, propagation delay."""
    return _array("hard")


def _track(count: int = 64) -> np.ndarray:
    """A source moving at about 1.5 m/s, one row per 10 ms period."""
    t = 0.01 * np.arange(count)[:, None]
    return SOURCE + np.array([1.2, -0.8, 0.1]) * t + 0.3 * np.sin(2.0 * t)


def _sources(array) -> np.ndarray:
    """(S, P, 3) image sources of points over the work area, corners included."""
    rng = np.random.default_rng(3)
    points = np.concatenate([rng.uniform((40, 40, -25), (295, 295, -5), (40, 3)),
                             [[40, 40, -25], [295, 295, -5], [150, 150, -15]]])
    return array.image_sources(points[:, None, :], np)


def _deterministic(array, xp, sources, track, speeds, angles):
    """Every deterministic piece of the model, evaluated with ``xp``."""
    tdoa, azimuth, elevation = array.noise_free(sources, xp)
    ranges = array.geometry(sources, xp)[0]
    rise = array.flow_noise_rise(speeds, xp)
    snr = array.snr_db(ranges[:3, None], array._path_loss, rise, xp=xp)  # (3, Q, P, N)
    working = np.arange(array.n_nodes) % 3 != 1
    timing, sigma_az, sigma_el = array.noise_std(snr, elevation[:3, None], xp)
    return {
        "tdoa": tdoa, "azimuth": azimuth, "elevation": elevation, "snr": snr,
        "detection_probability": array.detection_probability(snr, xp=xp),
        "detection_probability_working": array.detection_probability(snr, working, xp=xp),
        "arrival_std": timing, "azimuth_std": sigma_az, "elevation_std": sigma_el,
        "wander_std": array.wander_std(ranges, xp),
        "emission": array.emission_positions(track, 20, 0.01, SOUND_SPEED, xp=xp),
        "wrap": _wrap(angles, xp),
    }


def test_deterministic_parts_match_numpy(hard):
    """In float64 every deterministic piece equals NumPy's to 1e-9 (relative); in float32
    the TDOAs to 1 mm of range (TDOA x c), the angles to 1e-5 rad (1 mm at 100 m), the
    emission positions to 1 mm, the SNRs to 1e-3 dB, the probabilities to 1e-5."""
    inputs = (_sources(hard), _track(), np.array([0.0, 0.2, 0.5]), np.linspace(-20, 20, 101))
    reference = _deterministic(hard, np, *inputs)
    def on_jax(*arrays):  # a jit per precision: JAX's trace cache ignores enable_x64
        return jax.jit(lambda *arrays: _deterministic(hard, jnp, *arrays))(*arrays)

    with jax.enable_x64(True):
        exact = on_jax(*inputs)
        for name, value in exact.items():
            assert value.dtype == jnp.float64, name
            np.testing.assert_allclose(value, reference[name], rtol=1e-9, atol=1e-15,
                                       err_msg=name)
    single = on_jax(*(jnp.asarray(x, jnp.float32) for x in inputs))
    assert single["tdoa"].dtype == jnp.float32
    c = hard.config.sound_speed
    np.testing.assert_allclose(single["tdoa"] * c, reference["tdoa"] * c, rtol=0, atol=1e-3)
    for name in ("azimuth", "elevation"):
        np.testing.assert_allclose(single[name], reference[name], rtol=0, atol=1e-5)
    np.testing.assert_allclose(single["emission"], reference["emission"], rtol=0, atol=1e-3)
    np.testing.assert_allclose(single["snr"], reference["snr"], rtol=0, atol=1e-3)
    for name in ("detection_probability", "detection_probability_working"):
        np.testing.assert_allclose(single[name], reference[name], rtol=0, atol=1e-5)


class _Record:
    """A NumPy generator's draws, recorded in ``draws`` (for :class:`_Replay`)."""

    def __init__(self, rng: np.random.Generator):
        self.rng, self.draws = rng, []

    def _draw(self, method: str, *args):
        self.draws.append(getattr(self.rng, method)(*args))
        return self.draws[-1]

    def random(self, size=None):
        return self._draw("random", size)

    def standard_normal(self, size=None):
        return self._draw("standard_normal", size)

    def normal(self, loc=0.0, scale=1.0, size=None):
        return self._draw("normal", loc, scale, size)


class _Replay:
    """Recorded draws given back in their order (JAX arrays: the arguments of a jitted
    call), so that the NumPy and JAX paths see the very same numbers."""

    def __init__(self, draws: list):
        self.draws = list(draws)

    def _next(self, *_):
        return self.draws.pop(0)

    random = standard_normal = normal = _next


def _episode_block(array, draws, xp, count: int = 5):
    """Draw what one block of an episode draws (the per-episode draws, the Markov
    chains, continued once) and measure it with the fixed-shape draw."""
    offsets = array.draw_clock_offsets(draws, xp)
    speed = array.draw_sound_speed(draws, xp)
    track = xp.asarray(_track())
    heard = array.emission_positions(track, count, 0.01, speed, xp=xp)
    wander = array.draw_wander(draws, count, array.draw_wander(draws, 1, xp=xp)[-1], xp=xp)
    fading = array.draw_fading(draws, count, array.draw_fading(draws, 1, xp=xp)[-1], xp=xp)
    nodes = array.draw_node_states(draws, count, xp=xp)
    nodes = array.draw_node_states(draws, count, nodes[-1], xp=xp)
    # Node 4 out in every period and node 1 in the last: their columns zeroed.
    working = nodes & (xp.arange(array.n_nodes) != 3)
    working = xp.where((xp.arange(count) == count - 1)[:, None]
                       & (xp.arange(array.n_nodes) == 0), False, working)
    measured = array.measure(draws, heard, offsets, xp.full(count, CURRENT), speed, wander,
                             fading, working, noise_draws="fixed", xp=xp)
    return (offsets, speed, heard, wander, fading, nodes, *_fields(measured))


def test_fixed_draw_on_jax_is_numpy_fixed_draw(hard):
    """Fed the same draws, the JAX path (float64) gives what the NumPy path gives: the
    chains, the per-episode draws and the fixed-shape detection sets, to 1e-9."""
    draws = _Record(np.random.default_rng(11))
    reference = _episode_block(hard, draws, np)
    assert reference[-4].shape == (5, 10, 8, 23) and reference[-3].any()
    with jax.enable_x64(True):
        ours = jax.jit(lambda recorded: _episode_block(hard, _Replay(recorded), jnp))(
            draws.draws)
    for name, a, b in zip(("offsets", "speed", "heard", "wander", "fading", "nodes",
                           "values", "mask", "origin", "dropped"), ours, reference,
                          strict=True):
        _assert_close(a, b, name)
    # The chains alone, from their stationary start and continued.
    rng = _Record(np.random.default_rng(5))
    previous = np.array([True, False, True, False])
    expected = (unit_gauss_markov(rng, 6, (2, 3), 0.2, xp=np),
                two_state_markov(rng, 6, (4,), 0.3, 0.4, xp=np),
                two_state_markov(rng, 3, (4,), 0.3, 0.4, previous, xp=np))
    with jax.enable_x64(True):
        replay = _Replay(jnp.asarray(draw) for draw in rng.draws)
        chains = (unit_gauss_markov(replay, 6, (2, 3), 0.2, xp=jnp),
                  two_state_markov(replay, 6, (4,), 0.3, 0.4, xp=jnp),
                  two_state_markov(replay, 3, (4,), 0.3, 0.4, jnp.asarray(previous), xp=jnp))
    for a, b in zip(chains, expected, strict=True):
        _assert_close(a, b, "chain")


def _assert_close(ours, reference, name: str) -> None:
    """Equal dtypes' kinds; floats to 1e-9 (relative), the rest exactly."""
    ours, reference = np.asarray(ours), np.asarray(reference)
    assert ours.dtype.kind == reference.dtype.kind, name
    if ours.dtype.kind == "f":
        np.testing.assert_allclose(ours, reference, rtol=1e-9, atol=1e-15, err_msg=name)
    else:
        np.testing.assert_array_equal(ours, reference, err_msg=name)


def _fields(m: Measurements) -> tuple:
    """A :class:`Measurements`' arrays (the batched environment registers the class as a
    pytree; this test leaves JAX's registry alone)."""
    return tuple(getattr(m, f.name) for f in dataclasses.fields(Measurements))


def _measure_one(array, key, position, working) -> tuple:
    """One environment's period (count 1), as the batched environment draws it."""
    return _fields(array.measure(KeyDraws(key), position, jnp.asarray(CLOCKS),
                                 jnp.full(1, CURRENT), jnp.float32(SOUND_SPEED),
                                 working=working, noise_draws="fixed", xp=jnp))


@pytest.fixture(scope="module")
def jax_draw(hard):
    """``jit(vmap(measure))`` over keys (one compilation for every test here), giving
    :class:`Measurements` of (environments, 1, ...) arrays."""
    draw = jax.jit(jax.vmap(lambda key, position, working:
                            _measure_one(hard, key, position, working), in_axes=(0, None, None)))
    return lambda *args: Measurements(*draw(*args))


def _draw_both(array, jax_draw, working: np.ndarray, seed: int):
    """``PERIODS`` periods of a static source by NumPy's ``"kept"`` draw and by JAX's
    fixed-shape draw (environments of one period each): (numpy, jax) Measurements, the
    JAX arrays as NumPy (PERIODS, Q, K, ...)."""
    rows = np.broadcast_to(working, (PERIODS, array.n_nodes))
    cpu = array.measure(np.random.default_rng(seed), np.broadcast_to(SOURCE, (PERIODS, 3)),
                        CLOCKS, CURRENT, SOUND_SPEED, working=rows, xp=np)
    keys = jax.random.split(jax.random.key(seed), (PERIODS // BATCH, BATCH))
    calls = [jax_draw(batch, jnp.asarray(SOURCE[None], jnp.float32), jnp.asarray(working[None]))
             for batch in keys]
    return cpu, Measurements(*(np.concatenate(field)[:, 0]
                               for field in zip(*map(_fields, calls), strict=True)))


def _z(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The difference of two samples' means in standard errors (per trailing entry)."""
    error = np.sqrt(a.var(axis=0) / len(a) + b.var(axis=0) / len(b))
    return np.abs(a.mean(axis=0) - b.mean(axis=0)) / np.maximum(error, 1e-12)


def test_fixed_draw_is_the_numpy_model_in_distribution(hard, jax_draw):
    """With node 4 out: per band, how often each path is detected and kept, the false
    alarms kept, the candidates (kept + dropped: the detection probabilities plus the
    expected min(Poisson, K) false alarms) and the dropped counts agree with NumPy's within
    ``SIGMAS`` standard errors of the difference (of the model's value for the candidates);
    the direct path's TDOA errors, in units of the model's TDOA deviation, have mean 0
    and deviation 1 within ``SIGMAS`` standard errors (``1/sqrt(m)`` and ``1/sqrt(2m)``,
    ``m`` the detections: conservative, the TDOAs of one detection share node 1's
    noise)."""
    working = np.arange(hard.n_nodes) != 3
    cpu, ours = _draw_both(hard, jax_draw, working, seed=1)
    for origin in (ORIGIN_TARGET, 1, 2, ORIGIN_CLUTTER):
        counts = [np.sum(m.origin == origin, axis=-1) for m in (cpu, ours)]  # (T, Q)
        assert counts[0].mean() > 0.01, origin
        assert np.all(_z(*counts) < SIGMAS), (origin, _z(*counts))
    assert np.all(_z(cpu.dropped, ours.dropped) < SIGMAS)
    assert ours.dropped.any()

    ranges = hard.geometry(hard.image_sources(SOURCE, np), np)[0]  # (P, N)
    rise = hard.flow_noise_rise(CURRENT, np)  # (Q,)
    snr = hard.snr_db(ranges, hard._path_loss, rise, xp=np)  # (Q, P, N)
    pd = hard.detection_probability(snr, working, xp=np).sum(axis=-1)  # (Q,)
    expected = pd + np.sum(1.0 - hard._clutter_cdf)  # + E[min(Poisson, K)]
    for m in (cpu, ours):
        candidates = m.mask.sum(axis=-1) + m.dropped
        error = candidates.std(axis=0) / np.sqrt(PERIODS)
        assert np.all(np.abs(candidates.mean(axis=0) - expected) < SIGMAS * error)

    truth = hard.noise_free(hard.image_sources(SOURCE, np)[0], np)[0] * (
        hard.config.sound_speed / SOUND_SPEED) + CLOCKS[1:] - CLOCKS[0]
    tdoa_std = hard.model(SOURCE, CURRENT)["tdoa_std"]  # (Q, N - 1)
    for m in (cpu, ours):
        direct = m.origin == ORIGIN_TARGET  # (T, Q, K)
        for q in range(hard.config.n_bands):
            errors = (m.tdoa[:, q][direct[:, q]][:, working[1:]] - truth[working[1:]]) \
                / tdoa_std[q, working[1:]]
            count = len(errors)
            assert count > 50, q
            assert abs(errors.mean()) < SIGMAS / np.sqrt(count), (q, errors.mean())
            assert abs(errors.std() - 1.0) < SIGMAS / np.sqrt(2 * count), (q, errors.std())


def test_fixed_draw_crowds_bands_as_numpy(hard):
    """Where bands often hold more candidates than slots (6 false alarms a band on average
    fill its 3 slots in most periods, and the paths come on top), the fixed-shape draw
    (here on NumPy, which the JAX path equals) keeps each path and the false alarms as
    often as the ``"kept"`` draw and drops as many: the same shuffle, the first K kept.
    Within ``SIGMAS`` standard errors of the difference."""
    config = dataclasses.replace(hard.config, clutter_rate=6.0, max_detections=3)
    crowded = HydrophoneArray(hard.positions, hard.surface_z, hard.bottom_z, config)
    working = np.broadcast_to(np.arange(hard.n_nodes) != 3, (2 * PERIODS, hard.n_nodes))
    sources = np.broadcast_to(SOURCE, (len(working), 3))
    draws = [crowded.measure(np.random.default_rng(seed), sources, CLOCKS, CURRENT, SOUND_SPEED,
                             working=working, noise_draws=order, xp=np)
             for seed, order in ((6, "kept"), (7, "fixed"))]
    for origin in (ORIGIN_TARGET, 1, 2, ORIGIN_CLUTTER):
        counts = [np.sum(m.origin == origin, axis=-1) for m in draws]
        assert np.all(_z(*counts) < SIGMAS), (origin, _z(*counts))
    assert np.all(_z(draws[0].dropped, draws[1].dropped) < SIGMAS)
    assert draws[1].dropped.mean() > 0.2


def _check_conventions(array, m, working: np.ndarray) -> None:
    """NumPy's conventions of a (T, Q, K, ...) draw: the mask is where an origin is, a
    prefix of the K slots, full wherever something was dropped; empty slots are zero; an
    out node's columns (every TDOA without node 1) are zero; false alarms lie in the
    measurement space."""
    n = array.n_nodes
    assert set(np.unique(m.origin)) <= {ORIGIN_EMPTY, 0, 1, 2, ORIGIN_CLUTTER}
    np.testing.assert_array_equal(m.mask, m.origin != ORIGIN_EMPTY)
    assert np.all(m.mask[..., 1:] <= m.mask[..., :-1])
    assert np.all(m.mask[m.dropped > 0])
    assert not np.any(m.values[~m.mask])
    columns = np.concatenate([working[1:] & working[0], working, working])
    assert not np.any(m.values[..., ~columns])
    clutter = m.values[m.origin == ORIGIN_CLUTTER]
    slack = 1.0 + 1e-6  # float32's pi and TDOA bounds round up
    assert np.all(np.abs(clutter[:, : n - 1]) <= array.max_tdoa * slack)
    assert np.all(np.abs(clutter[:, n - 1 : 2 * n - 1]) <= np.pi * slack)
    assert np.all((clutter[:, 2 * n - 1 :] >= 0) & (clutter[:, 2 * n - 1 :] <= np.pi * slack))


@pytest.mark.parametrize("out", [(3,), (0, 5), tuple(range(8))])
def test_fixed_draw_shapes_and_conventions(hard, jax_draw, out):
    """Fixed shapes and dtypes under ``jit(vmap(...))`` (float32 values, bool mask, int8
    origin, int32 dropped) and NumPy's conventions, which its ``"kept"`` draw and its
    ``"fixed"`` draw on NumPy follow too; no node working: no detection at all."""
    working = ~np.isin(np.arange(hard.n_nodes), out)
    keys = jax.random.split(jax.random.key(2), BATCH)
    m = jax_draw(keys, jnp.asarray(SOURCE[None], jnp.float32), jnp.asarray(working[None]))
    q, k, n = hard.config.n_bands, hard.config.max_detections, hard.n_nodes
    assert m.values.shape == (BATCH, 1, q, k, 3 * n - 1) and m.values.dtype == jnp.float32
    assert m.mask.shape == m.origin.shape == (BATCH, 1, q, k) and m.mask.dtype == jnp.bool_
    assert m.origin.dtype == jnp.int8
    assert m.dropped.shape == (BATCH, 1, q) and m.dropped.dtype == jnp.int32
    rows = np.broadcast_to(working, (BATCH, n))
    draws = [Measurements(*(np.asarray(field)[:, 0] for field in _fields(m)))]
    for noise_draws in ("kept", "fixed"):
        draws.append(hard.measure(np.random.default_rng(4), np.broadcast_to(SOURCE, (BATCH, 3)),
                                  CLOCKS, CURRENT, SOUND_SPEED, working=rows,
                                  noise_draws=noise_draws, xp=np))
    for draw in draws:
        _check_conventions(hard, draw, working)
        assert draw.mask.any() == working.any()


def test_single_period_and_refusals(hard):
    """A (3,) position gives one period without the leading axis (traced, as under
    ``jit``); the draws of varying size are NumPy's only."""
    values, mask, origin, dropped = jax.eval_shape(
        lambda key: _fields(hard.measure(KeyDraws(key), jnp.asarray(SOURCE), CLOCKS, CURRENT,
                                         noise_draws="fixed", xp=jnp)),
        jax.random.key(0))
    assert values.shape == (10, 8, 23) and mask.shape == origin.shape == (10, 8)
    assert dropped.shape == (10,)
    for noise_draws in ("kept", "all"):
        with pytest.raises(ValueError, match="NumPy only"):
            hard.measure(KeyDraws(jax.random.key(0)), jnp.asarray(SOURCE), CLOCKS, CURRENT,
                         noise_draws=noise_draws, xp=jnp)
