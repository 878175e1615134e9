"""AcousticTracking-v2's route: drawn per segment by the same code on NumPy and JAX.

v2 changes only how the carrier's route is drawn (``transition.draw_route``: every draw
made up front, the segments evaluated in closed form); the tests check that the closed
form is the route's own integral, that the routes are v1's model in distribution, and
that the JAX evaluation of the same code gives the same route.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from auv_envs.core.ops import FLOATS
from auv_envs.tasks.acoustic import transition

N, DT = 6001, 0.01


def _route(seed: int) -> transition.Route:
    return transition.draw_route(np.random.default_rng(seed), N, DT, FLOATS)


@pytest.mark.parametrize("seed", [4101, 4102, 4103])
def test_closed_form_is_the_integral_of_the_rates(seed):
    """Each period's reference position is the start plus the sum of the rates before it
    (the v1 planner's cumulative sum), wherever the route stays inside its limits."""
    route = _route(seed)
    reference, rate = route.at(np.arange(N), DT, np)
    summed = reference[0, :3] + np.concatenate(
        [np.zeros((1, 3)), np.cumsum(rate[:-1, :3] * DT, axis=0)])
    inside = np.all((summed[:, :2] > transition.ROUTE_XY[0])
                    & (summed[:, :2] < transition.ROUTE_XY[1]), axis=1)
    assert inside.mean() > 0.9
    np.testing.assert_allclose(reference[inside, :3], summed[inside], atol=1e-9)
    # The yaw reference is the integral of its rate, but where a segment near the edges
    # turns back towards the centre (at its first period).
    differs = np.abs(np.diff(reference[:, 3]) - rate[:-1, 3] * DT) > 1e-12
    assert set(np.nonzero(differs)[0] + 1) <= set(np.asarray(route.start).tolist())


def test_routes_are_v1s_model_in_distribution():
    """Over 200 seeds each, v2's routes and v1's (``plan_route``) have the same path
    length, share of time paused and turning over the first 40 s (v1 squeezes its last
    curve into the periods left; v2 cuts it at the horizon, hence not the last 20 s),
    within four standard errors of their difference."""
    stats = {"v1": [], "v2": []}
    first = 4000
    for seed in range(5000, 5200):
        routes = {"v1": transition.TabulatedRoute(*transition.plan_route(
            np.random.default_rng(seed), N, DT)), "v2": _route(seed)}
        for name, route in routes.items():
            reference, rate = route.at(np.arange(N), DT, np)
            assert np.all(reference[:, :2] >= transition.ROUTE_XY[0])
            assert np.all(reference[:, :2] <= transition.ROUTE_XY[1])
            assert np.all((reference[:, 2] >= transition.ROUTE_Z[0])
                          & (reference[:, 2] <= transition.ROUTE_Z[1]))
            path = np.linalg.norm(np.diff(reference[:first, :3], axis=0), axis=1).sum()
            paused = np.mean(rate[:first, :2] == 0.0)
            turning = np.abs(rate[:first, 3]).sum() * DT
            stats[name].append((path, paused, turning))
    v1, v2 = np.array(stats["v1"]), np.array(stats["v2"])
    error = np.sqrt(v1.var(axis=0) / len(v1) + v2.var(axis=0) / len(v2))
    assert np.all(np.abs(v1.mean(axis=0) - v2.mean(axis=0)) < 4 * error), (
        v1.mean(axis=0), v2.mean(axis=0), error)


def test_the_same_code_draws_on_jax():
    """``draw_route`` under ``jit`` (JAX's draws) gives a route whose float32 evaluation
    is the float64 NumPy evaluation of its own segments, within 0.1 mm over 60 s."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    from auv_envs.batched.functional import KeyDraws
    from auv_envs.core.ops import jax_ops

    draw = jax.jit(jax.vmap(lambda key: transition.draw_route(KeyDraws(key), N, DT,
                                                              jax_ops())))
    routes = draw(jax.random.split(jax.random.key(4104), 4))
    rows = jnp.arange(N)
    for i in range(4):
        route = jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], routes)
        on_jax = np.asarray(jnp.concatenate(route.at(rows, DT, jnp), -1))
        on_numpy = np.concatenate(transition.Route(*(
            np.asarray(leaf).astype(np.float64 if np.asarray(leaf).dtype.kind == "f"
                                    else np.int64) for leaf in route)).at(
            np.arange(N), DT, np), -1)
        np.testing.assert_allclose(on_jax, on_numpy, atol=1e-4)
        assert int(route.start[0]) == 0 and np.all(np.diff(np.asarray(route.start)) >= 1)


def test_superseded_planner_ids():
    """v1 and v0 draw the tabulated route; v2 the segments; the keyword is checked."""
    for env_id, planner in (("auv_envs/AcousticTracking-v2", "segments"),
                            ("auv_envs/AcousticTracking-v1", "tabulated"),
                            ("auv_envs/AcousticTracking-v0", "tabulated")):
        env = gym.make(env_id, obs_mode="state")
        assert env.unwrapped.params.planner == planner
        env.close()
    with pytest.raises(ValueError, match="planner"):
        gym.make("auv_envs/AcousticTracking-v2", planner="straight")
