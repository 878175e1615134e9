"""Domain randomisation of the LARS worlds (the batched env, on JAX).

A world is one environment of a batch for its whole life (MuJoCo Playground's domain
randomisation): :class:`LARSRandomization` draws each world's arm once, in its MuJoCo
model, which the batched plant then simulates; the task (the scene's motion, the camera,
the reward) is unchanged. Usage as for docking (:mod:`auv_envs.tasks.docking.randomization`):
``wrap_for_brax_training(env, randomization_fn=functools.partial(env.randomize,
rng=keys))``, ``ppo.train(..., randomization_fn=env.randomize)`` or
``gym.make_vec("auv_envs/LARSCaptureMJX-v0", num_envs=N, randomize=True)``.
"""

from __future__ import annotations

import dataclasses

from auv_envs.core.randomization import BodyRandomization, uniform_factors


@dataclasses.dataclass(frozen=True)
class LARSRandomization(BodyRandomization):
    """The ranges each LARS world's arm is drawn from, uniformly.

    * **The links** (``link_mass``): one factor per moving body (turret, boom, jib) in
      ``[1 - link_mass, 1 + link_mass]`` on its mass and its rotational inertia: the
      capture head's load, cables and fittings differ from the drawings (our choice).
    * **The motors** (``motor``): one factor per actuator in ``[1 - motor, 1 + motor]`` on
      its gear, the torque a unit command gives (hydraulic supply pressure, valve gain;
      our choice).

    Zero ranges draw factors of 1: the nominal arm.

    Attributes:
        link_mass: relative half-range of the links' mass factors (0 to 0.9).
        motor: relative half-range of the motors' torque factors (0 to 0.9).
    """

    link_mass: float = 0.2
    motor: float = 0.1

    def actuator_fields(self, model, key) -> dict:
        """``actuator_gear`` with each motor's gear ratio scaled."""
        gear = uniform_factors(key, (model.nu,), self.motor)
        return {"actuator_gear": model.actuator_gear.at[:, 0].multiply(gear)}
