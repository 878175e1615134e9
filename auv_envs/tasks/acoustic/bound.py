"""Posterior Cramér–Rao bound (PCRB) of an acoustic tracking episode [PCRB].

[PCRB]: P. Tichavský, C. H. Muravchik and A. Nehorai, "Posterior Cramér–Rao
bounds for discrete-time nonlinear filtering", IEEE Trans. Signal Processing
46(5), 1998.

**The recursion.** For a Markov state ``x_k`` with transition density
``p(x_{k+1} | x_k)`` and measurements ``z_k`` with likelihood ``p(z_k | x_k)``,
the Fisher information ``J_k`` of the filtering problem obeys ([PCRB])::

    J_{k+1} = D22 - D21 (J_k + D11)^-1 D12,
    D11 = E[-Δ_{x_k}^{x_k} log p(x_{k+1}|x_k)],
    D12 = E[-Δ_{x_k}^{x_{k+1}} log p(x_{k+1}|x_k)] = D21^T,
    D22 = E[-Δ_{x_{k+1}}^{x_{k+1}} log p(x_{k+1}|x_k)]
          + E[-Δ_{x_{k+1}}^{x_{k+1}} log p(z_{k+1}|x_{k+1})],

and every estimator of ``x_k`` from ``z_0 .. z_k`` has a mean squared error
matrix ``E[(x̂_k - x_k)(x̂_k - x_k)^T] >= J_k^-1``. With linear-Gaussian motion
``x_{k+1} = F x_k + u_k + w_k``, ``w_k ~ N(0, Q)`` (``u_k`` a known input), the
blocks are ``D11 = F^T Q^-1 F``, ``D12 = -F^T Q^-1``, ``D22 = Q^-1 + J_z`` and,
by the matrix inversion lemma, ``J_{k+1} = (Q + F J_k^-1 F^T)^-1 + J_z(k+1)``,
``J_z = E[H^T R^-1 H]`` at the true state: the Kalman filter's covariance
recursion in information form. This form needs no ``Q^-1``, so a motion without
noise and static parameters (``Q = 0``) enter as they are. :func:`pcrb`
computes it (on a linear-Gaussian model, the Kalman filter's covariance).

**The motion** (:class:`MotionPrior`). The environment draws nothing per
step for the motion: the route, the arm's sweep and the current are drawn at
reset and the physics is deterministic. Its own motion model is therefore
``x_{k+1} = x_k + u_k`` with no process noise, ``u_k`` the displacement the
reset draws fix. The bound (the default, ``MotionPrior()``) gives the
estimator these displacements, the whole path but for where it starts:
information no tracker has, so the bound stays below every tracker whatever
its motion model. The price is that it is loose: a tracker must also learn
the motion. ``MotionPrior(jerk_scale=s)`` instead assumes a
nearly-constant-acceleration (white-jerk) model (Bar-Shalom, Li & Kirubarajan
2001, §6.2.3) whose intensity follows the episode's realised jerk ``j_k``
(third differences of the true positions), ``q_k = s |j_k|^2 dt / 3`` per axis:
an estimator told when and how hard the end effector manoeuvres but not in
which direction. That bound is tighter, but it is a model, not the
environment's law (its smooth stretches move more predictably than a white
jerk says), so a tracker could in principle go below it: it is for
comparison, not a guaranteed limit.

**The start** (the prior at k = 0): the position N(x_0, ``START_POSITION_STD``^2)
per axis, as if the estimator were told where the source started to within
10 cm (more than any tracker knows). That makes the bound of the episode's
own path the bound of a problem whose start is random over 10 cm, over
which the measurement information changes by less than 2 % (to first order,
which averages out; the bound along the true path differs from the average
by the square, below 1e-3). With the white jerk, also the velocity (the
source starts at rest: ``START_VELOCITY_STD``) and the acceleration
(``START_ACCELERATION_STD``).

**The per-episode errors that every band shares** are unknowns with the
priors the environment draws them from (exactly, neither more nor less
information), each in units of its prior standard deviation: the clock
offsets of nodes 2-N (constant, N(0, ``clock_offset_std``^2); node 1 is the
reference), the water's sound speed (constant, N(nominal,
``sound_speed_error_std``^2) when that is > 0; the environment's clip at 5 % lies
beyond 25 standard deviations) and the nodes' unit travel-time wander
(first-order Gauss-Markov, the environment's ``unit_gauss_markov``, when
``fluctuation_intensity`` > 0).

**The measurement information** (:func:`measurement_information`), from the
environment's own model (:mod:`auv_envs.core.acoustics`, through the array's
own noise and detection functions): every band ``q`` and path ``p`` (the
direct one and, with multipath, the surface and bottom ghosts: a ghost is a
full measurement of the source's mirror image, so it carries information
too) contributes ``p_D(q, p) H_p^T R_{q,p}^-1 H_p``, ``H_p`` the Jacobian of the
path's TDOAs, azimuths and elevations (analytic) and ``R_{q,p}`` their
covariance (TDOAs correlated through node 1). Weighting by ``p_D`` without
any loss for clutter is the information-reduction bound as if every
detection's origin were known (Niu, Willett & Bar-Shalom, IEEE Trans. AES
37(1), 2001: with clutter the reduction factor is at most ``p_D``); putting the
expected information into the recursion gives a bound no larger than
enumerating the detection sequences (Hernandez, Ristic, Farina & Timmoneri,
IEEE Trans. SP 52(9), 2004; the recursion's map is matrix-concave in ``J``).
Also as if received: the detections dropped when a band has more than
``max_detections``. As if known: the episode's realised band fades and node
outages (conditioning on them can only add information) and, with
propagation delay, the emission position each node heard (each measurement's
Jacobian is taken there). Left out: the information in the noise level's and
the detection probability's dependence on the range (the Gaussian's
``tr(R^-1 ∂R R^-1 ∂R) / 2`` and the detection indicator's Bernoulli
information), below 1e-5 of the information kept at every level.

Every choice above gives the estimator at least the information it has, but
for that omission and the start's second-order term, so ``mean_k
trace(P_k)`` (:func:`position_bounds`, ``P_k`` the position block of
``J_k^-1``) bounds the expected mean squared error of every tracker over an
episode's steps, averaged over episodes, to within 1e-3 of itself. Its square
root is comparable with the environment's ``rmse`` episode metric (the
inequality itself holds for the mean squared errors).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from auv_envs.core.acoustics import HydrophoneArray

#: Standard deviations of the prior at k = 0 (module docstring): the position (m, per axis),
#: and for the white jerk the velocity (m/s; the source starts at rest) and acceleration
#: (m/s^2).
START_POSITION_STD = 0.1
START_VELOCITY_STD = 1e-3
START_ACCELERATION_STD = 1.0
#: Floor on the white-jerk intensity (m^2/s^5), keeping the transition covariance positive.
JERK_INTENSITY_FLOOR = 1e-12
#: Steps whose Jacobians and information are built at once (bounds the memory).
CHUNK = 500


@dataclasses.dataclass(frozen=True)
class EpisodeRecord:
    """What the bound needs of an episode: its truth and the nuisance it realised.

    Attributes:
      positions: (T, 3) the source's true positions at the scored steps (tank frame, m).
      dt: the sample period, s.
      sound_speed: the water's true sound speed, m/s.
      current_speed: (T,) the current's speed per step, m/s (flow noise).
      heard: (T, N, 3) per step and node the emission position the node heard (node 1's
        also for every TDOA); None without propagation delay (then ``positions``).
      fading: (T, Q, N) the realised band fades, dB; None without fading.
      working: (T, N) bool, which nodes worked; None without dropouts.
    """

    positions: np.ndarray
    dt: float
    sound_speed: float
    current_speed: np.ndarray
    heard: np.ndarray | None = None
    fading: np.ndarray | None = None
    working: np.ndarray | None = None


@dataclasses.dataclass(frozen=True)
class MotionPrior:
    """The motion model the bound assumes (module docstring).

    Attributes:
      jerk_scale: None (the default): the known motion, every step's displacement given;
        a number ``s``: a white jerk of ``s`` times the realised intensity.
    """

    jerk_scale: float | None = None

    def kinematics(self, positions: np.ndarray, dt: float):
        """The kinematic block ``(F (s, s), Q (T-1, s, s), prior variances (s,))``: s = 3
        (known motion: the position) or 9 (white jerk: position, velocity, acceleration)."""
        steps = len(positions)
        start = np.full(3, START_POSITION_STD**2)
        if self.jerk_scale is None:
            return np.eye(3), np.zeros((max(steps - 1, 0), 3, 3)), start
        f1, q1 = white_jerk_model(dt)
        noise = self.intensities(positions, dt)[:, None, None] * np.kron(q1, np.eye(3))
        start = np.concatenate([start, np.full(3, START_VELOCITY_STD**2),
                                np.full(3, START_ACCELERATION_STD**2)])
        return np.kron(f1, np.eye(3)), noise, start

    def intensities(self, positions: np.ndarray, dt: float) -> np.ndarray:
        """(T-1,) white-jerk intensities q_k (m^2/s^5 per axis) of the transitions k -> k+1."""
        steps = len(positions)
        if steps < 4:
            return np.full(max(steps - 1, 0), JERK_INTENSITY_FLOOR)
        jerk = np.diff(positions, 3, axis=0) / dt**3  # (T-3, 3): jerk i spans k = i..i+3
        power = np.sum(jerk**2, axis=1) * dt / 3.0
        # The transition k -> k+1 lies in the spans of jerks k-2..k: their mean.
        padded = np.concatenate([np.full(2, power[0]), power, np.full(2, power[-1])])
        q = np.lib.stride_tricks.sliding_window_view(padded, 3).mean(axis=1)[: steps - 1]
        return np.maximum(self.jerk_scale * q, JERK_INTENSITY_FLOOR)


def white_jerk_model(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One axis of the nearly-constant-acceleration model (Bar-Shalom et al. 2001, §6.2.3):
    transition ``F`` of (position, velocity, acceleration) and the covariance ``Q`` of a
    unit-intensity white jerk over ``dt``."""
    f = np.array([[1.0, dt, dt**2 / 2.0], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    q = np.array([[dt**5 / 20.0, dt**4 / 8.0, dt**3 / 6.0],
                  [dt**4 / 8.0, dt**3 / 3.0, dt**2 / 2.0],
                  [dt**3 / 6.0, dt**2 / 2.0, dt]])
    return f, q


def pcrb(transition: np.ndarray, noise: np.ndarray, prior_information: np.ndarray,
         measurement_info: np.ndarray) -> np.ndarray:
    """The PCRB recursion for linear-Gaussian motion (module docstring):
    ``J_0 = J_prior + J_z(0)``, ``J_{k+1} = (Q_k + F_k J_k^-1 F_k^T)^-1 + J_z(k+1)``.

    Args:
      transition: (d, d) F, or (T-1, d, d) one per transition.
      noise: (d, d) Q, or (T-1, d, d); may be singular (no noise, static parameters).
      prior_information: (d, d) J_prior, the information of the prior on x_0.
      measurement_info: (T, d, d) the expected measurement information J_z(k).

    Returns:
      (T, d, d) the bounds J_k^-1 on the error covariance of x_k given z_0 .. z_k.
    """
    steps, d = measurement_info.shape[:2]
    transition = np.broadcast_to(transition, (max(steps - 1, 0), d, d))
    noise = np.broadcast_to(noise, (max(steps - 1, 0), d, d))
    out = np.empty((steps, d, d))
    information = prior_information + measurement_info[0]
    for k in range(steps):
        if k:
            f = transition[k - 1]
            information = _inverse(f @ out[k - 1] @ f.T + noise[k - 1]) + measurement_info[k]
        out[k] = _inverse(information)
    return out


def _inverse(matrix: np.ndarray) -> np.ndarray:
    """The inverse of a symmetric positive-definite matrix, symmetrised."""
    inverse = np.linalg.inv(matrix)
    return 0.5 * (inverse + inverse.T)


@dataclasses.dataclass(frozen=True)
class _Nuisance:
    """Where each shared error sits among the nuisance unknowns (module docstring)."""

    n_nodes: int
    sound_speed: bool
    wander: bool

    @property
    def clock(self) -> slice:
        return slice(0, self.n_nodes - 1)

    @property
    def speed(self) -> int:
        return self.n_nodes - 1

    @property
    def wander_slice(self) -> slice:
        start = self.n_nodes - 1 + int(self.sound_speed)
        return slice(start, start + self.n_nodes * int(self.wander))

    @property
    def size(self) -> int:
        return self.wander_slice.stop


def _nuisance(array: HydrophoneArray) -> _Nuisance:
    c = array.config
    return _Nuisance(array.n_nodes, c.sound_speed_error_std > 0, c.fluctuation_intensity > 0)


def _through(mirror: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """Gradients (T, P, ..., 3) with respect to each path's image source, taken back to
    the source through the images' Jacobians ``mirror`` (P, 3, 3)."""
    return np.einsum("pij,tp...j->tp...i", mirror, gradient)


def measurement_information(array: HydrophoneArray, record: EpisodeRecord,
                            steps: slice | None = None) -> np.ndarray:
    """The expected information ``sum_{q,p} p_D H_p^T R_{q,p}^-1 H_p`` per step (module
    docstring) of the measured unknowns: the position (3), then the nuisances (the clock
    offsets of nodes 2-N, the sound speed if its error is on, the nodes' unit wander if
    on), each in units of its prior standard deviation.

    Returns:
      (T, 3 + n, 3 + n) for the steps ``steps`` of ``record`` (all by default).
    """
    steps = steps or slice(0, len(record.positions))
    c = array.config
    nuisance = _nuisance(array)
    n, m = array.n_nodes, 3 + nuisance.size
    paths = 3 if c.multipath else 1
    if record.heard is None:
        heard = np.repeat(record.positions[steps, None, :], n, axis=1)
    else:
        heard = record.heard[steps]
    t = len(heard)
    # Image sources are affine in the source: image = source @ mirror + shift.
    origin = array.image_sources(np.zeros((1, 3)), np)[:paths]  # (P, 3)
    mirror = (array.image_sources(np.eye(3)[:, None], np)[:, :paths] - origin).transpose(1, 0, 2)
    speed = record.sound_speed

    # TDOAs: every node at node 1's emission position (as measure() aligns them).
    first = array.image_sources(heard[:, 0, None, :], np)[:, :paths]  # (T, P, 3)
    d = first[:, :, None, :] - array.positions  # (T, P, N, 3)
    ranges = np.linalg.norm(d, axis=-1)
    unit = d / ranges[..., None]
    tdoa = np.zeros((t, paths, n - 1, m))
    tdoa[..., :3] = _through(mirror, (unit[:, :, 1:] - unit[:, :, :1]) / speed)
    tdoa[..., 3 + nuisance.clock.start:3 + nuisance.clock.stop] = \
        c.clock_offset_std * np.eye(n - 1)
    if nuisance.sound_speed:
        tdoa[..., 3 + nuisance.speed] = -(ranges[..., 1:] - ranges[..., :1]) / speed**2 * \
            c.sound_speed_error_std
    if nuisance.wander:
        scale = array.wander_std(ranges[:, 0], np)  # (T, N): every path wanders as the direct one
        block = np.zeros((t, n - 1, n))
        block[:, :, 0] = -scale[:, :1]
        block[:, np.arange(n - 1), np.arange(1, n)] = scale[:, 1:]
        w = nuisance.wander_slice
        tdoa[..., 3 + w.start:3 + w.stop] = block[:, None]

    # Angles: node i sees its own emission position.
    own = array.image_sources(heard[:, :, None, :], np)[:, :, :paths]  # (T, N, P, 3)
    a = (own - array.positions[None, :, None, :]).transpose(0, 2, 1, 3)  # (T, P, N, 3)
    horizontal2 = a[..., 0] ** 2 + a[..., 1] ** 2
    horizontal = np.sqrt(horizontal2)
    range2 = horizontal2 + a[..., 2] ** 2
    azimuth_grad = np.stack([-a[..., 1], a[..., 0], np.zeros_like(horizontal)], -1) / \
        horizontal2[..., None]
    elevation_grad = np.stack([a[..., 0] * a[..., 2] / horizontal,
                               a[..., 1] * a[..., 2] / horizontal, -horizontal], -1) / \
        range2[..., None]
    elevation = np.arctan2(horizontal, a[..., 2])
    azimuth_pos = _through(mirror, azimuth_grad)  # (T, P, N, 3)
    elevation_pos = _through(mirror, elevation_grad)

    # The noise model of measure(): SNRs at node 1's emission ranges, the azimuth noise at
    # each node's own elevation.
    path_loss = np.array([0.0, c.surface_loss, c.bottom_loss])[:paths, None]
    rise = array.flow_noise_rise(record.current_speed[steps], np)  # (T, Q)
    snr = array.snr_db(ranges[:, None], path_loss, rise, xp=np)  # (T, Q, P, N)
    if record.fading is not None:
        snr = snr + record.fading[steps][:, :, None, :]
    timing, sigma_az, sigma_el = array.noise_std(snr, elevation[:, None], np)
    if record.working is None:
        pd = array.detection_probability(snr, xp=np)  # (T, Q, P)
        on = np.ones((t, 1, 1, n))
    else:
        working = record.working[steps]
        pd = array.detection_probability(snr, working[:, None, None], xp=np)
        on = working[:, None, None, :].astype(np.float64)

    # TDOA precision (diag(s_i^2) + s_1^2)^-1 by Sherman-Morrison; an out node's TDOA
    # has zero precision, and without node 1 there is no TDOA at all.
    precision = on[..., 1:] / timing[..., 1:] ** 2  # (T, Q, P, N-1)
    s1 = timing[..., 0] ** 2
    tdoa_weight = precision[..., :, None] * np.eye(n - 1) - (
        s1 / (1.0 + s1 * precision.sum(-1)))[..., None, None] * \
        precision[..., :, None] * precision[..., None, :]
    tdoa_weight = np.sum((pd * on[..., 0])[..., None, None] * tdoa_weight, axis=1)
    azimuth_weight = np.sum(pd[..., None] * on / sigma_az**2, axis=1)  # (T, P, N)
    elevation_weight = np.sum(pd[..., None] * on / sigma_el**2, axis=1)

    info = np.sum(np.swapaxes(tdoa, -1, -2) @ (tdoa_weight @ tdoa), axis=1)
    for gradient, weight in ((azimuth_pos, azimuth_weight), (elevation_pos, elevation_weight)):
        info[:, :3, :3] += np.sum(np.swapaxes(gradient, -1, -2) @ (weight[..., None] * gradient),
                                  axis=1)
    return info


def position_bounds(array: HydrophoneArray, record: EpisodeRecord,
                    prior: MotionPrior | None = None) -> np.ndarray:
    """Per step, the PCRB on the source position's mean squared error (m^2): the trace of
    the position block of ``J_k^-1`` (module docstring).

    Returns:
      (T,) bounds; their mean bounds an episode's mean squared error.
    """
    prior = prior or MotionPrior()
    c = array.config
    nuisance = _nuisance(array)
    positions = np.asarray(record.positions, dtype=np.float64)
    t = len(positions)
    kin_f, kin_q, kin_start = prior.kinematics(positions, record.dt)
    kin = len(kin_start)
    d = kin + nuisance.size  # the kinematics, then the nuisances
    transition = np.eye(d)
    transition[:kin, :kin] = kin_f
    noise = np.zeros((max(t - 1, 0), d, d))
    noise[:, :kin, :kin] = kin_q
    if nuisance.wander:
        a = math.exp(-record.dt / c.fluctuation_time)
        w = slice(kin + nuisance.wander_slice.start, kin + nuisance.wander_slice.stop)
        transition[w, w] = a * np.eye(array.n_nodes)
        noise[:, w, w] = (1.0 - a * a) * np.eye(array.n_nodes)
    prior_information = np.diag(1.0 / np.concatenate([kin_start, np.ones(nuisance.size)]))

    measured = np.concatenate([np.arange(3), np.arange(kin, d)])  # position, nuisances
    info = np.zeros((t, d, d))
    for begin in range(0, t, CHUNK):
        chunk = slice(begin, min(t, begin + CHUNK))
        info[chunk, measured[:, None], measured] = measurement_information(array, record, chunk)
    bounds = pcrb(transition, noise, prior_information, info)
    return np.trace(bounds[:, :3, :3], axis1=1, axis2=2)


def bound_rmse(array: HydrophoneArray, record: EpisodeRecord,
               prior: MotionPrior | None = None) -> float:
    """The bound on an episode's RMSE (m), ``sqrt(mean_k trace(P_k))``: the counterpart of
    the environment's ``rmse`` episode metric over the same steps."""
    return float(np.sqrt(np.mean(position_bounds(array, record, prior))))
