"""Vehicle parameter sets (frozen dataclasses), with their sources.

Every dynamic quantity of a vehicle lives in one :class:`VehicleParams`. The
MuJoCo plant takes its mass and inertia from here, the hydrodynamic forces in
:mod:`auv_envs.core.hydrodynamics` take the rest, and the controllers' nominal
model is built from the same object (optionally perturbed by
:func:`with_damping_mismatch`).

Sign convention: added masses and damping coefficients are stored as
*positive* magnitudes (``added_mass[0] = -X_udot`` in Fossen's notation).
Damping and added-mass matrices are taken diagonal (the off-diagonal couplings
of a slender body are neglected; documented simplification).
"""

from __future__ import annotations

import dataclasses
import functools
import math

from auv_envs.core.frames import GRAVITY

SEAWATER_DENSITY = 1025.0  # kg/m^3


def prolate_spheroid_added_mass(a: float, b: float, rho: float) -> tuple[float, ...]:
    """Added-mass diagonal of a prolate spheroid from Lamb's k-factors.

    Imlay (1961), as given in Fossen, *Handbook of Marine Craft Hydrodynamics
    and Motion Control* (2nd ed., 2021), section 8.4.2.

    Args:
        a: semi-axis along the body x axis (half length), m.
        b: semi-axis across (half diameter), m; ``b < a``.
        rho: water density, kg/m^3.

    Returns:
        ``(A_x, A_y, A_z, A_p, A_q, A_r)`` as positive magnitudes
        (kg and kg m^2). ``A_p`` is zero for a body of revolution.
    """
    if not 0.0 < b < a:
        raise ValueError(f"need 0 < b < a for a prolate spheroid, got a={a}, b={b}")
    e = math.sqrt(1.0 - (b / a) ** 2)
    log_term = math.log((1.0 + e) / (1.0 - e))
    alpha0 = 2.0 * (1.0 - e**2) / e**3 * (0.5 * log_term - e)
    beta0 = 1.0 / e**2 - (1.0 - e**2) / (2.0 * e**3) * log_term
    mass = 4.0 / 3.0 * math.pi * rho * a * b**2
    a_x = alpha0 / (2.0 - alpha0) * mass
    a_y = beta0 / (2.0 - beta0) * mass
    a_rot = (
        0.2
        * (b**2 - a**2) ** 2
        * (alpha0 - beta0)
        / (2.0 * (b**2 - a**2) + (b**2 + a**2) * (beta0 - alpha0))
        * mass
    )
    return (a_x, a_y, a_y, 0.0, a_rot, a_rot)


@dataclasses.dataclass(frozen=True)
class VehicleParams:
    """Rigid-body and hydrodynamic parameters of one vehicle (body frame FLU).

    Attributes:
        name: short identifier.
        source: where the numbers come from.
        length: hull length, m (prolate-spheroid hull).
        diameter: hull diameter, m.
        mass: dry mass m, kg.
        inertia: principal moments of inertia about the CG, kg m^2.
        cb_offset: centre of buoyancy relative to the CG, body frame, m.
            A positive z (CB above CG) gives the righting moment.
        added_mass: positive added-mass diagonal (surge, sway, heave, roll,
            pitch, yaw).
        linear_damping: positive linear damping diagonal (N s/m, N m s/rad).
        quadratic_damping: positive quadratic damping diagonal.
        net_buoyancy: B - W in N (positive floats up).
        thrust_limits: magnitude limits of the commanded generalized force
            (X, Y, Z in N; N in N m).
        rho: water density, kg/m^3.
    """

    name: str
    source: str
    length: float
    diameter: float
    mass: float
    inertia: tuple[float, float, float]
    cb_offset: tuple[float, float, float]
    added_mass: tuple[float, float, float, float, float, float]
    linear_damping: tuple[float, float, float, float, float, float]
    quadratic_damping: tuple[float, float, float, float, float, float]
    net_buoyancy: float
    thrust_limits: tuple[float, float, float, float]
    rho: float = SEAWATER_DENSITY

    # Cached: the plant reads both at every integrator stage (a frozen dataclass
    # keeps them valid; dataclasses.replace builds a new instance).
    @functools.cached_property
    def weight(self) -> float:
        """W = m g, N."""
        return self.mass * GRAVITY

    @functools.cached_property
    def buoyancy(self) -> float:
        """B = W + (B - W), N."""
        return self.weight + self.net_buoyancy

    @property
    def inertia_with_added_mass(self) -> tuple[float, float, float, float, float, float]:
        """Diagonal of ``M_RB + M_A`` at the CG: ``(m + A_x, m + A_y, m + A_z, I_x + A_p,
        I_y + A_q, I_z + A_r)`` (kg, kg m^2); the plant and the nominal model divide by it."""
        m, (ax, ay, az, ap, aq, ar) = self.mass, self.added_mass
        ix, iy, iz = self.inertia
        return (m + ax, m + ay, m + az, ix + ap, iy + aq, iz + ar)


def with_damping_mismatch(params: VehicleParams, scale: tuple[float, ...]) -> VehicleParams:
    """The same vehicle with both damping diagonals scaled elementwise.

    This is the explicit model mismatch between plant and nominal model (seed
    003 compares the D diagonals of plant and prediction model).
    """
    if len(scale) != 6:
        raise ValueError(f"damping scale needs 6 entries, got {len(scale)}")
    return dataclasses.replace(
        params,
        name=f"{params.name}-nominal",
        linear_damping=tuple(d * s for d, s in zip(params.linear_damping, scale, strict=True)),
        quadratic_damping=tuple(
            d * s for d, s in zip(params.quadratic_damping, scale, strict=True)
        ),
    )


@dataclasses.dataclass(frozen=True)
class PlantPerturbation:
    """How far the simulated vehicle may deviate from its nominal parameters, per episode.

    Hydrodynamic coefficients identified for a real vehicle are uncertain by
    tens of per cent ([OFNMPC] tests its controllers against exactly such a
    mismatch of the damping diagonals), and its trim drifts with payload and
    water density. Each episode draws, from its own generator:

    * one mass factor in ``[1 - mass, 1 + mass]``, applied to the mass and the
      rigid-body inertia (added mass, a property of the hull's shape, stays);
    * one factor per coefficient in ``[1 - damping, 1 + damping]`` for each of
      the 12 linear and quadratic damping coefficients;
    * an offset in ``[-net_buoyancy, net_buoyancy]`` N added to B - W.

    All uniform. Zero everywhere (the default) leaves the vehicle as it is and
    draws nothing.

    Attributes:
        mass: relative half-range of the mass factor (0 to 0.5).
        damping: relative half-range of the damping factors (0 to 0.9).
        net_buoyancy: half-range of the net-buoyancy offset, N.
    """

    mass: float = 0.0
    damping: float = 0.0
    net_buoyancy: float = 0.0

    def __post_init__(self):
        for name, high in (("mass", 0.5), ("damping", 0.9), ("net_buoyancy", math.inf)):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0.0 <= value <= high):
                raise ValueError(f"{name} must be a number in [0, {high}], got {value!r}")

    @property
    def active(self) -> bool:
        return self.mass > 0 or self.damping > 0 or self.net_buoyancy > 0

    def draw_factors(self, rng) -> tuple | None:
        """The episode's draws ``(mass factor, 12 damping factors, net-buoyancy offset N)``
        from ``rng`` (NumPy's ``Generator``, or a JAX key's draws); None when inactive."""
        if not self.active:
            return None
        return (rng.uniform(1.0 - self.mass, 1.0 + self.mass),
                rng.uniform(1.0 - self.damping, 1.0 + self.damping, 12),
                rng.uniform(-self.net_buoyancy, self.net_buoyancy))

    def draw(self, params: VehicleParams, rng) -> tuple[VehicleParams, dict]:
        """``(perturbed parameters, the draws)``; ``params`` and no draw when inactive."""
        factors = self.draw_factors(rng)
        if factors is None:
            return params, {}
        mass_scale, damping_scale, buoyancy_offset = (
            float(factors[0]), factors[1].tolist(), float(factors[2]))
        perturbed = self.apply(params, mass_scale, damping_scale, buoyancy_offset)
        draws = {"mass_scale": mass_scale, "linear_damping_scale": damping_scale[:6],
                 "quadratic_damping_scale": damping_scale[6:],
                 "net_buoyancy_offset": buoyancy_offset}
        return perturbed, draws

    @staticmethod
    def apply(params: VehicleParams, mass_scale, damping_scale, buoyancy_offset) -> VehicleParams:
        """``params`` perturbed by given draws (:meth:`draw`'s): the mass factor, the 12
        damping factors (linear, then quadratic) and the net-buoyancy offset, N. Scalars
        of any kind: floats, or JAX arrays in a batched plant."""
        return dataclasses.replace(
            params,
            name=f"{params.name}-perturbed",
            mass=params.mass * mass_scale,
            inertia=tuple(i * mass_scale for i in params.inertia),
            linear_damping=tuple(d * damping_scale[k]
                                 for k, d in enumerate(params.linear_damping)),
            quadratic_damping=tuple(d * damping_scale[6 + k]
                                    for k, d in enumerate(params.quadratic_damping)),
            net_buoyancy=params.net_buoyancy + buoyancy_offset,
        )


def thruster_lag_gain(time_constant: float, dt: float) -> float:
    """Gain ``g`` of a first-order thruster lag sampled every ``dt`` seconds.

    A thruster's force follows its command ``u`` as ``T df/dt = u - f``
    (the first-order thruster model of Yoerger, Cooke and Slotine 1990, "The
    influence of thruster dynamics on underwater vehicle behavior", IEEE J.
    Oceanic Eng. 15(3)). Held over each period,
    ``f[k] = f[k-1] + g (u[k] - f[k-1])`` with ``g = 1 - exp(-dt / T)``;
    ``T = 0`` is an ideal thruster (``g = 1``).
    """
    if not (math.isfinite(time_constant) and time_constant >= 0):
        raise ValueError(f"thruster time constant must be >= 0 s, got {time_constant!r}")
    return 1.0 if time_constant == 0 else 1.0 - math.exp(-dt / time_constant)


def lagged_thrust(previous, command, gain):
    """The force one period later under :func:`thruster_lag_gain`'s ``gain``:
    ``f[k-1] + g (u[k] - f[k-1])`` (floats, or arrays elementwise)."""
    return previous + gain * (command - previous)


def _spheroid_vehicle(
    name: str,
    source: str,
    length: float,
    diameter: float,
    bg: float,
    net_buoyancy: float,
    linear_damping: tuple[float, ...],
    drag_coefficients: tuple[float, ...],
    thrust_limits: tuple[float, float, float, float],
    rho: float = SEAWATER_DENSITY,
) -> VehicleParams:
    """A neutrally-sized spheroid hull: mass from displacement minus net buoyancy.

    Quadratic damping follows 0.5 rho C_d A for translation with the frontal
    (pi b^2) and lateral (pi a b) areas; rotational entries of
    ``drag_coefficients`` are used as given (N m s^2/rad^2).
    """
    a, b = length / 2.0, diameter / 2.0
    volume = 4.0 / 3.0 * math.pi * a * b**2
    mass = (rho * GRAVITY * volume - net_buoyancy) / GRAVITY
    ix = 0.4 * mass * b**2
    iyz = 0.2 * mass * (a**2 + b**2)
    frontal, lateral = math.pi * b**2, math.pi * a * b
    cx, cy, cz, kp, mq, nr = drag_coefficients
    quadratic = (
        0.5 * rho * cx * frontal,
        0.5 * rho * cy * lateral,
        0.5 * rho * cz * lateral,
        kp,
        mq,
        nr,
    )
    return VehicleParams(
        name=name,
        source=source,
        length=length,
        diameter=diameter,
        mass=mass,
        inertia=(ix, iyz, iyz),
        cb_offset=(0.0, 0.0, bg),
        added_mass=prolate_spheroid_added_mass(a, b, rho),
        linear_damping=tuple(linear_damping),
        quadratic_damping=quadratic,
        net_buoyancy=net_buoyancy,
        thrust_limits=thrust_limits,
        rho=rho,
    )


def hovering_auv() -> VehicleParams:
    """The fully actuated hovering AUV of the docking tasks.

    A 1.8 m x 0.44 m prolate-spheroid hull (the size class of [OFNMPC]'s
    multi-thruster trench AUV, whose parameters we do not have). Mass from
    displacement with 10 N net positive buoyancy (the buoyancy [OFNMPC]'s
    observers estimate); inertia of a homogeneous spheroid; added mass from
    Lamb's k-factors (Fossen 2021, section 8.4.2); quadratic drag from
    0.5 rho C_d A with C_d = 0.3 axially and 1.0 across; BG = 0.15 m, large
    enough for passive roll/pitch stability against the Munk moment up to
    full surge speed. Linear damping and thrust limits are design choices
    documented here.
    """
    return _spheroid_vehicle(
        name="hovering-auv",
        source="spheroid hull sized after [OFNMPC]'s fully actuated AUV; "
        "added mass: Imlay (1961) / Fossen (2021) section 8.4.2",
        length=1.8,
        diameter=0.44,
        bg=0.15,
        net_buoyancy=10.0,
        linear_damping=(20.0, 60.0, 60.0, 15.0, 40.0, 40.0),
        drag_coefficients=(0.3, 1.0, 1.0, 5.0, 60.0, 60.0),
        thrust_limits=(80.0, 80.0, 80.0, 40.0),
    )


def remus100() -> VehicleParams:
    """REMUS 100-sized spheroid (L = 1.6 m, D = 0.19 m, BG = 0.02 m).

    Dimensions and BG from Fossen's Python Vehicle Simulator (``remus100.py``);
    neutral buoyancy; damping values are this package's choice. Used as a
    cross-check of the added-mass formula (REMUS 100 added-mass diagonal
    0.839, 29.44, 29.44 kg; 3.43 kg m^2 about pitch and yaw).
    """
    return _spheroid_vehicle(
        name="remus100",
        source="Fossen, Python Vehicle Simulator, remus100.py (geometry)",
        length=1.6,
        diameter=0.19,
        bg=0.02,
        net_buoyancy=0.0,
        linear_damping=(5.0, 20.0, 20.0, 2.0, 5.0, 5.0),
        drag_coefficients=(0.2, 1.0, 1.0, 1.0, 10.0, 10.0),
        thrust_limits=(50.0, 0.0, 0.0, 10.0),
        rho=1026.0,
    )
