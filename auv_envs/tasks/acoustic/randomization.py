"""Domain randomisation of the acoustic tracking worlds (the batched env, on JAX).

A world is one environment of a batch for its whole life (MuJoCo Playground's domain
randomisation): :class:`AcousticRandomization` draws each world's rig once, in its MuJoCo
model, which the batched plant then simulates; the source's plan, the water and the
hydrophones are the task's. Usage as for docking (:mod:`auv_envs.tasks.docking.randomization`):
``wrap_for_brax_training(env, randomization_fn=functools.partial(env.randomize,
rng=keys))``, ``ppo.train(..., randomization_fn=env.randomize)`` or
``gym.make_vec("auv_envs/AcousticTrackingMJX-v2", num_envs=N, randomize=True)``.
"""

from __future__ import annotations

import dataclasses

from auv_envs.core.randomization import BodyRandomization, uniform_factors


@dataclasses.dataclass(frozen=True)
class AcousticRandomization(BodyRandomization):
    """The ranges each acoustic world's rig is drawn from, uniformly.

    * **The bodies** (``link_mass``): one factor per moving body (the carrier and the arm's
      links) in ``[1 - link_mass, 1 + link_mass]`` on its mass and its rotational inertia
      (payload, flooded volumes; our choice).
    * **The servos** (``servo``): one factor per servo in ``[1 - servo, 1 + servo]`` on its
      stiffness and its damping alike (``kp`` and ``kv`` of MuJoCo's position actuator:
      how hard the carrier and the arm follow the plan; our choice).

    Zero ranges draw factors of 1: the nominal rig. The source's plan is unchanged; how
    the rig follows it, in the water's current, is what changes.

    Attributes:
        link_mass: relative half-range of the bodies' mass factors (0 to 0.9).
        servo: relative half-range of the servos' gain factors (0 to 0.9).
    """

    link_mass: float = 0.2
    servo: float = 0.2

    def actuator_fields(self, model, key) -> dict:
        """``actuator_gainprm`` and ``actuator_biasprm`` with each servo's ``kp`` and ``kv``
        scaled alike."""
        gain = uniform_factors(key, (model.nu,), self.servo)
        return {"actuator_gainprm": model.actuator_gainprm.at[:, 0].multiply(gain),
                "actuator_biasprm": model.actuator_biasprm.at[:, 1:3].multiply(gain[:, None])}
