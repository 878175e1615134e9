"""Domain randomisation of the docking worlds (the batched envs, on JAX).

A world is one environment of a batch for its whole life, as in MuJoCo Playground's
domain randomisation: :class:`DockingRandomization` draws each world's physics once, and
the world keeps it across its episodes. It is the plant that changes, never what the
task is: the reward, the termination, the sensors and the observation are the task's,
and the state observation does not see the drawn quantities.

    import functools, jax
    import auv_envs.batched
    from mujoco_playground import wrapper

    env = auv_envs.batched.load("auv_envs/DockingStation-v2", obs_mode="features")
    keys = jax.random.split(jax.random.PRNGKey(0), 256)
    train_env = wrapper.wrap_for_brax_training(
        env, episode_length=env.episode_length,
        randomization_fn=functools.partial(env.randomize, rng=keys))

``brax.training.agents.ppo.train(..., randomization_fn=env.randomize)`` does the same,
and ``gym.make_vec("auv_envs/DockingStationMJX-v2", num_envs=N, randomize=True)`` draws
its worlds from the seed given to ``reset``.
"""

from __future__ import annotations

import dataclasses
import math

from auv_envs.core.randomization import check_fractions, uniform_factors
from auv_envs.core.vehicle import PlantPerturbation
from auv_envs.tasks.docking.env import PAPER_DISTURBANCES

#: The names of a docking world's drawn physics (:class:`DockingRandomization`).
PHYSICS = ("mass_scale", "damping_scale", "buoyancy_offset", "thrust_scale", "current")


@dataclasses.dataclass(frozen=True)
class DockingRandomization:
    """The ranges each docking world is drawn from, uniformly.

    * **The simulated vehicle** (``vehicle``): a mass factor on the mass and the rigid-body
      inertia, a factor on each of the 12 linear and quadratic damping coefficients and an
      offset on the net buoyancy, as :class:`~auv_envs.core.vehicle.PlantPerturbation`
      draws them per episode at the ``paper`` and ``hard`` levels; here per world (the
      default: ``paper``'s ranges, [OFNMPC]'s damping mismatch). Where the level perturbs
      the vehicle too, the two compose: the factors multiply, the offsets add.
    * **The thrusters' gain** (``thrust``): one factor in ``[1 - thrust, 1 + thrust]`` on
      every commanded force and moment (a thruster's thrust coefficient moves with its
      supply voltage, wear and inflow; our choice of range).
    * **An unmodelled current** (``current``): horizontal, its speed uniform in
      ``[0, current]`` m/s and its direction uniform, added to the level's current in the
      plant alone (the ``state`` observation's current does not include it; our choice).

    Zero ranges draw a factor of 1 or an offset of 0: the nominal world.

    Attributes:
        vehicle: the vehicle's ranges.
        thrust: relative half-range of the thrusters' gain (0 to 0.9).
        current: the unmodelled current's largest speed, m/s.
    """

    vehicle: PlantPerturbation = PAPER_DISTURBANCES.plant
    thrust: float = 0.15
    current: float = 0.1

    def __post_init__(self):
        if not isinstance(self.vehicle, PlantPerturbation):
            raise TypeError(f"vehicle must be a PlantPerturbation, got {self.vehicle!r}")
        check_fractions("DockingRandomization", thrust=self.thrust)
        if isinstance(self.current, bool) or not isinstance(self.current, int | float) \
                or not 0.0 <= self.current < math.inf:
            raise ValueError(f"current must be a finite number >= 0, got {self.current!r}")

    def draw(self, key) -> dict:
        """One world's physics (:data:`PHYSICS`, float32 arrays) from a JAX ``key``."""
        import jax
        import jax.numpy as jnp

        from auv_envs.batched.functional import KeyDraws

        vehicle, thrust, current = jax.random.split(key, 3)
        # The vehicle as the level's per-episode perturbation draws it (nothing when off).
        factors = self.vehicle.draw_factors(KeyDraws(vehicle)) or (1.0, jnp.ones(12), 0.0)
        speed, angle = jax.random.uniform(current, (2,)) * jnp.array(
            [self.current, 2.0 * math.pi])
        return {
            "mass_scale": jnp.asarray(factors[0], jnp.float32),
            "damping_scale": jnp.asarray(factors[1], jnp.float32),
            "buoyancy_offset": jnp.asarray(factors[2], jnp.float32),
            "thrust_scale": uniform_factors(thrust, (), self.thrust),
            "current": jnp.stack([speed * jnp.cos(angle), speed * jnp.sin(angle),
                                  jnp.zeros(())]),
        }

    def __call__(self, model, rng):
        """MuJoCo Playground's ``randomization_fn``: ``(worlds, in_axes)``, one world per
        key of ``rng`` ((N, 2) keys) about ``model`` (the env's
        :class:`~auv_envs.batched.functional.World`; its MJX model is shared)."""
        import jax

        from auv_envs.batched.functional import World

        physics = jax.vmap(self.draw)(rng)
        return World(model.mjx, physics), World(None, {name: 0 for name in physics})
