"""Independent RK4 reference integrator of the 6-DOF AUV equations of motion.

Written from the textbook, Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*
(2nd ed., 2021), eq. 10.1, with the body frame forward-left-up at the CG and the world frame
z-up (the equations keep their form in any right-handed pair of frames)::

    M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau

with ``nu_r = nu - nu_c`` and ``nu_c = (R^T v_c, 0, 0, 0)`` for a constant, irrotational current
``v_c`` given in the world frame. Both Coriolis matrices are built in full from their inertia
matrices with Fossen's ``m2c`` (Python Vehicle Simulator, ``gnc.m2c``; MSS ``m2c.m``).

This module is deliberately independent of :mod:`auv_envs.core.hydrodynamics`: it reads only
parameter values from :class:`auv_envs.core.vehicle.VehicleParams` and ``GRAVITY`` from
:mod:`auv_envs.core.frames`, so that it can serve as a check of the package's plant.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np


@dataclasses.dataclass
class ReferenceTrajectory:
    """Samples of a reference run, one row per command boundary (``K + 1`` rows).

    Attributes:
        times: sample times ``0 .. K * period``, s.
        position: CG position in the world frame, m.
        euler: ZYX Euler angles (roll, pitch, yaw), rad; ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
        velocity: body velocity relative to ground ``(u, v, w, p, q, r)``.
        quaternion: attitude ``(w, x, y, z)`` (MuJoCo order), body -> world.
    """

    times: np.ndarray
    position: np.ndarray
    euler: np.ndarray
    velocity: np.ndarray
    quaternion: np.ndarray


def skew(a: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``S(a)`` with ``S(a) b = a x b``."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` of two 3-vectors (``np.cross`` is slow on single vectors)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def m2c(mass_matrix: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Coriolis-centripetal matrix ``C(nu)`` of a 6x6 inertia matrix (Fossen's ``gnc.m2c``).

    ``C = [[0, -S(M11 nu1 + M12 nu2)], [-S(M11 nu1 + M12 nu2), -S(M21 nu1 + M22 nu2)]]``
    with ``M`` symmetrised first; ``C`` is skew-symmetric, so it does no work.
    """
    m = 0.5 * (mass_matrix + mass_matrix.T)
    nu1, nu2 = nu[:3], nu[3:]
    s1 = skew(m[:3, :3] @ nu1 + m[:3, 3:] @ nu2)
    s2 = skew(m[3:, :3] @ nu1 + m[3:, 3:] @ nu2)
    c = np.zeros((6, 6))
    c[:3, 3:] = -s1
    c[3:, :3] = -s1
    c[3:, 3:] = -s2
    return c


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a (x) b`` of quaternions ``(w, x, y, z)``."""
    aw, av, bw, bv = a[0], a[1:], b[0], b[1:]
    return np.concatenate(([aw * bw - av @ bv], aw * bv + bw * av + cross(av, bv)))


def rotation_from_quat(q: np.ndarray) -> np.ndarray:
    """Body-to-world rotation matrix of a quaternion ``(w, x, y, z)`` (normalised here)."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion ``(w, x, y, z)`` of ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    qz = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    qy = np.array([math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0])
    qx = np.array([math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0])
    return quat_multiply(quat_multiply(qz, qy), qx)


def euler_from_quat(q: np.ndarray) -> np.ndarray:
    """ZYX Euler angles ``(roll, pitch, yaw)`` of a quaternion, rad."""
    r = rotation_from_quat(q)
    pitch = -math.asin(min(1.0, max(-1.0, r[2, 0])))
    return np.array([math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])])


@functools.lru_cache(maxsize=8)
def _matrices(params) -> tuple[np.ndarray, ...]:
    """``M_RB`` (origin at the CG, principal axes), ``M_A``, ``(M_RB + M_A)^-1``, the damping
    diagonals and ``r_b``, cached per parameter set."""
    m_rb = np.diag([params.mass] * 3 + list(params.inertia))
    m_a = np.diag(params.added_mass)
    return (
        m_rb,
        m_a,
        np.linalg.inv(m_rb + m_a),
        np.asarray(params.linear_damping, dtype=float),
        np.asarray(params.quadratic_damping, dtype=float),
        np.asarray(params.cb_offset, dtype=float),
    )


def derivatives(params, state13, tau6, current_world=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Right-hand side of the state ``(p, q, nu)`` (3 + 4 + 6 numbers).

    Solves Fossen (2021) eq. 10.1 for ``nu_dot``::

        (M_RB + M_A) nu_dot = tau - C_RB(nu) nu - C_A(nu_r) nu_r - D(nu_r) nu_r - g(eta)
                              + M_A nu_c_dot,   nu_c_dot = (-w x (R^T v_c), 0, 0, 0)

    Args:
        params: a :class:`auv_envs.core.vehicle.VehicleParams`.
        state13: world CG position, quaternion ``(w, x, y, z)``, body velocity ``nu``.
        tau6: body-frame generalized force ``(X, Y, Z, K, M, N)``.
        current_world: constant uniform current ``v_c`` in the world frame, m/s.

    Returns:
        ``(p_dot, q_dot, nu_dot)`` as one 13-vector.
    """
    state = np.asarray(state13, dtype=float)
    q, nu = state[3:7], state[7:]
    rot = rotation_from_quat(q)
    omega = nu[3:]
    current_body = rot.T @ np.asarray(current_world, dtype=float)
    nu_r = nu - np.concatenate((current_body, np.zeros(3)))
    nu_c_dot = np.concatenate((-cross(omega, current_body), np.zeros(3)))

    m_rb, m_a, m_inv, d_lin, d_quad, r_b = _matrices(params)
    damping = np.diag(d_lin + d_quad * np.abs(nu_r))
    f_g = rot.T @ np.array([0.0, 0.0, -params.weight])  # weight acts at the CG (r_g = 0)
    f_b = rot.T @ np.array([0.0, 0.0, params.buoyancy])  # buoyancy acts at r_b
    restoring = -np.concatenate((f_g + f_b, cross(r_b, f_b)))

    rhs = (
        np.asarray(tau6, dtype=float)
        - m2c(m_rb, nu) @ nu
        - m2c(m_a, nu_r) @ nu_r
        - damping @ nu_r
        - restoring
        + m_a @ nu_c_dot
    )
    nu_dot = m_inv @ rhs
    q_dot = 0.5 * quat_multiply(q, np.concatenate(([0.0], omega)))
    return np.concatenate((rot @ nu[:3], q_dot, nu_dot))


def simulate(
    params,
    position,
    euler,
    body_velocity,
    commands,
    period,
    current_world=(0.0, 0.0, 0.0),
    step=0.002,
) -> ReferenceTrajectory:
    """Classical RK4 with fixed ``step`` under zero-order-hold commands.

    Args:
        params: a :class:`auv_envs.core.vehicle.VehicleParams`.
        position: initial CG position, world, m.
        euler: initial ZYX ``(roll, pitch, yaw)``, rad.
        body_velocity: initial ``nu`` (relative to ground), body frame.
        commands: ``(K, 6)`` body generalized forces; row ``k`` holds on
            ``[k period, (k + 1) period)``.
        period: command period, s; an integer multiple of ``step``.
        current_world: constant uniform current in the world frame, m/s.
        step: RK4 step, s.

    Returns:
        The trajectory sampled at the ``K + 1`` command boundaries.

    Raises:
        ValueError: ``period / step`` is not an integer, or ``commands`` is not ``(K, 6)``.
    """
    substeps = round(period / step)
    if substeps < 1 or abs(substeps * step - period) > 1e-9 * period:
        raise ValueError(f"period {period} is not an integer multiple of step {step}")
    commands = np.asarray(commands, dtype=float)
    if commands.ndim != 2 or commands.shape[1] != 6:
        raise ValueError(f"commands must be (K, 6), got {commands.shape}")
    state = np.concatenate(
        (np.asarray(position, float), quat_from_euler(*euler), np.asarray(body_velocity, float))
    )
    states = [state.copy()]
    for tau in commands:
        for _ in range(substeps):
            k1 = derivatives(params, state, tau, current_world)
            k2 = derivatives(params, state + 0.5 * step * k1, tau, current_world)
            k3 = derivatives(params, state + 0.5 * step * k2, tau, current_world)
            k4 = derivatives(params, state + step * k3, tau, current_world)
            state = state + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            state[3:7] /= np.linalg.norm(state[3:7])
        states.append(state.copy())
    states = np.array(states)
    return ReferenceTrajectory(
        times=np.arange(len(states)) * period,
        position=states[:, :3],
        euler=np.array([euler_from_quat(q) for q in states[:, 3:7]]),
        velocity=states[:, 7:],
        quaternion=states[:, 3:7],
    )


def smooth_commands(rng: np.random.Generator, duration, period, limits) -> np.ndarray:
    """Smooth full-range commands: surge X, sway Y, heave Z and yaw N (roll, pitch moments 0).

    Each channel is a sum of 2-3 sinusoids (frequencies 0.05-0.4 Hz, random phases) scaled
    so that its peak equals the channel's limit, clipped to ``+-limit`` and sampled at the
    period midpoints.

    Args:
        rng: the random generator (the result is deterministic given its state).
        duration: total time, s; an integer multiple of ``period``.
        period: command period, s.
        limits: maximum magnitudes ``(X, Y, Z, N)``.

    Returns:
        A ``(K, 6)`` array, ``K = duration / period``.
    """
    count = round(duration / period)
    if abs(count * period - duration) > 1e-9 * duration:
        raise ValueError(f"duration {duration} is not an integer multiple of period {period}")
    t = (np.arange(count) + 0.5) * period
    commands = np.zeros((count, 6))
    for column, limit in zip((0, 1, 2, 5), limits, strict=True):
        n = int(rng.integers(2, 4))
        freq = rng.uniform(0.05, 0.4, n)
        phase = rng.uniform(0.0, 2.0 * math.pi, n)
        weight = rng.uniform(0.5, 1.0, n)
        signal = (weight * np.sin(2.0 * math.pi * freq * t[:, None] + phase)).sum(axis=1)
        commands[:, column] = np.clip(signal * limit / np.abs(signal).max(), -limit, limit)
    return commands


#: The converged-physics limits a plant keeps over 10 s of full-range commands:
#: CG position (m), attitude (degrees), any body-velocity component (m/s, rad/s).
LIMITS = {"position_m": 0.02, "attitude_deg": 0.5, "velocity": 0.01}


@dataclasses.dataclass
class PlantError:
    """The largest deviations of an env's plant from the reference over one run.

    Attributes:
        position: max CG position error, m.
        attitude_deg: max attitude error (angle of ``R_ref^T R_env``), degrees.
        velocity: max error of any body-velocity component, m/s or rad/s.
        final_position: CG position error at the end of the run, m.
        travel: largest distance of the env's CG from its start, m.
        steps: env steps compared (fewer than asked if the episode ended).
    """

    position: float
    attitude_deg: float
    velocity: float
    final_position: float
    travel: float
    steps: int


def _rotation_from_euler(roll, pitch, yaw) -> np.ndarray:
    return rotation_from_quat(quat_from_euler(roll, pitch, yaw))


def env_plant_error(env, seed: int, command_seed: int, duration: float = 10.0) -> PlantError:
    """Run ``env`` (a docking env) and the reference from the env's own reset state.

    Only the public API is used: the start state and current from ``info``
    after ``reset``, the vehicle's parameters from ``env.unwrapped.vehicle`` (read
    after ``reset``), the
    control period from ``env.unwrapped.dt``. Commands are
    :func:`smooth_commands` over surge, sway, heave and yaw, sent as normalised
    actions; the reference integrates the generalized forces those actions
    give.

    Args:
        env: a docking env (``obs_mode`` any), e.g. from ``gymnasium.make``.
        seed: the env's reset seed.
        command_seed: seed of the command generator.
        duration: seconds to compare.
    """
    base = env.unwrapped
    _, info = env.reset(seed=seed)
    # After reset: an episode may simulate a perturbed vehicle (DockingDisturbances.plant).
    params, period = base.vehicle, base.dt
    limits = np.array(params.thrust_limits, dtype=float)
    commands = smooth_commands(np.random.default_rng(command_seed), duration, period, limits)
    actions = (commands[:, (0, 1, 2, 5)] / limits).astype(np.float32)
    applied = np.zeros_like(commands)
    applied[:, (0, 1, 2, 5)] = actions.astype(float) * limits
    start = (info["true_position"].copy(), info["true_euler"].copy(), info["true_velocity"].copy())
    current = info["current"].copy()
    rows = []
    for action in actions:
        _, _, terminated, truncated, info = env.step(action)
        rows.append((info["true_position"], info["true_euler"], info["true_velocity"]))
        if terminated or truncated:
            break
    reference = simulate(params, *start, applied[: len(rows)], period, current_world=current)
    position = np.array([r[0] for r in rows])
    velocity = np.array([r[2] for r in rows])
    pos_err = np.linalg.norm(position - reference.position[1:], axis=1)
    angles = []
    for (_, euler, _), ref_euler in zip(rows, reference.euler[1:], strict=True):
        relative = _rotation_from_euler(*ref_euler).T @ _rotation_from_euler(*euler)
        angles.append(math.acos(min(1.0, max(-1.0, (np.trace(relative) - 1.0) / 2.0))))
    return PlantError(
        position=float(pos_err.max()),
        attitude_deg=math.degrees(max(angles)),
        velocity=float(np.abs(velocity - reference.velocity[1:]).max()),
        final_position=float(pos_err[-1]),
        travel=float(np.linalg.norm(position - start[0], axis=1).max()),
        steps=len(rows),
    )


def acoustic_truth(disturbance: str, seed: int, duration: float,
                   refinement: int = 1) -> np.ndarray:
    """The acoustic end effector's true positions over one episode (``info`` only), with
    ``refinement`` times the shipped physics steps a sample period.

    Its plant is MuJoCo's own fluid model, for which this module has no
    independent reference: it is compared with finer steps of itself.
    """
    import inspect

    import gymnasium as gym

    from auv_envs.tasks.acoustic.env import AcousticTrackingTask

    shipped = inspect.signature(AcousticTrackingTask).parameters["physics_substeps"].default
    env = gym.make("auv_envs/AcousticTracking-v2", obs_mode="state", disturbance=disturbance,
                   time_limit=duration, physics_substeps=refinement * shipped)
    try:
        _, info = env.reset(seed=seed)
        rows = [info["true_position"].copy()]
        while True:
            # The action is the agent's estimate; it does not act on the physics.
            _, _, terminated, truncated, info = env.step(rows[-1].astype(np.float32))
            rows.append(info["true_position"].copy())
            if terminated or truncated:
                return np.array(rows)
    finally:
        env.close()
