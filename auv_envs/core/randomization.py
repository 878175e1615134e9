"""What the families' domain randomisers share (JAX is imported by the functions only).

A randomiser is MuJoCo Playground's ``randomization_fn``: ``fn(world, keys) -> (worlds,
in_axes)``, one world per key about the env's :class:`~auv_envs.batched.functional.World`.
The families' own: :mod:`auv_envs.tasks.docking.randomization`,
:mod:`auv_envs.tasks.lars.randomization`, :mod:`auv_envs.tasks.acoustic.randomization`.
"""

from __future__ import annotations

import dataclasses
import math


def check_fractions(owner: str, **values) -> None:
    """``ValueError`` for a relative half-range that is not a number in [0, 0.9]."""
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value) or not 0.0 <= value <= 0.9:
            raise ValueError(f"{owner}.{name} must be a number in [0, 0.9], got {value!r}")


def uniform_factors(key, shape, half):
    """Factors uniform in ``[1 - half, 1 + half]`` (float32) of ``shape``."""
    import jax

    return jax.random.uniform(key, shape, minval=1.0 - half, maxval=1.0 + half)


def scaled_links(model, key, half) -> dict:
    """``body_mass`` and ``body_inertia`` of the MJX ``model`` with each moving body's (one
    with a joint) scaled by one factor in ``[1 - half, 1 + half]``."""
    import jax.numpy as jnp

    scale = jnp.where(jnp.asarray(model.body_jntnum > 0),
                      uniform_factors(key, (model.nbody,), half), 1.0)
    return {"body_mass": model.body_mass * scale,
            "body_inertia": model.body_inertia * scale[:, None]}


def model_worlds(world, rng, draw):
    """``(worlds, in_axes)`` whose MJX models have the fields ``draw(key) -> {field:
    value}`` gives, one world per key of ``rng`` ((N, 2)), the rest of ``world``'s model
    shared."""
    import jax

    from auv_envs.batched.functional import World

    fields = jax.vmap(draw)(rng)
    in_axes = jax.tree.map(lambda _: None, world.mjx).tree_replace(
        {name: 0 for name in fields})
    return World(world.mjx.tree_replace(fields)), World(in_axes)


@dataclasses.dataclass(frozen=True)
class BodyRandomization:
    """A randomiser of a MuJoCo model's moving bodies and actuators (LARS's arm, the
    acoustic rig): one factor per moving body in ``[1 - link_mass, 1 + link_mass]`` on its
    mass and rotational inertia (:func:`scaled_links`), and whatever
    :meth:`actuator_fields` draws for the actuators. Its fields are relative
    half-ranges in [0, 0.9]."""

    link_mass: float = 0.2

    def __post_init__(self):
        check_fractions(type(self).__name__, **dataclasses.asdict(self))

    def actuator_fields(self, model, key) -> dict:
        """The actuators' fields of the MJX ``model`` drawn from ``key``."""
        raise NotImplementedError

    def __call__(self, model, rng):
        """MuJoCo Playground's ``randomization_fn``: ``(worlds, in_axes)``, one world per
        key of ``rng`` ((N, 2) keys) about ``model`` (the env's
        :class:`~auv_envs.batched.functional.World`): its MJX model's ``body_mass``,
        ``body_inertia`` and actuator fields drawn per world."""
        import jax

        mjx_model = model.mjx

        def draw(key):
            links, actuators = jax.random.split(key)
            return {**scaled_links(mjx_model, links, self.link_mass),
                    **self.actuator_fields(mjx_model, actuators)}

        return model_worlds(model, rng, draw)
