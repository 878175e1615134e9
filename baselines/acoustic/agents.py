"""[GMPHD]'s tracking agents for ``auv_envs/AcousticTracking-v2``.

* ``gmphd-gci``: fused TDOA-DOA fixes -> one GM-PHD filter per sub-band with
  DBSCAN adaptive birth -> GCI of the Q mixtures (omega_q = 1/Q) -> labelled
  extraction above T_prune ([GMPHD] §1.3, §2.2, §2.3, §3.1).
* ``gmphd-single``: the same pipeline on one band (the band with the smallest
  angle noise at the work-area centre, from the calibration's noise model).
* ``ls-kf``: fused fixes of all bands -> a single Kalman filter on the same
  constant-velocity model, updated with the nearest fix inside a chi-square
  gate (nearest-neighbour association); re-initialised from the median-nearest
  fix after ``max_misses`` steps without a gated fix.

**Action rule** (both GM-PHD agents): the mean position of the heaviest
extracted component; when none is extracted, the last estimate extrapolated
with its velocity; before the first estimate, the centre of the work area.
The action is clipped to the tank.

**Clock calibration** (all three agents, on by default; our addition to seed
004): every agent corrects the TDOAs of its own bands with an online estimate
of the nodes' clock offsets
(:class:`~baselines.acoustic.perception.positioning.ClockOffsetEstimator`).
The offsets bias every fix of an episode alike, so without it the shared bias, not the
per-band noise that GCI averages out, dominates the error.
``clock_calibration=False`` runs the paper's pipeline on the raw TDOAs.

**Node dropouts** (all three agents): when the observation has a
``node_mask`` (the env's dropout model is on), every fix and the clock
calibration use only the working nodes' angles and TDOAs
(``LeastSquaresPositioner.solve(..., nodes=...)``); while node 1, the TDOA
reference, is out the fixes come from the angles alone.

Agents read only the ``measurements`` observation and the documented
calibration (never ``info``).
"""

from __future__ import annotations

import numpy as np

from baselines.acoustic.estimation.gci import (
    GeneralizedCovarianceIntersection,
    LabelledExtractor,
)
from baselines.acoustic.estimation.gmphd import (
    POSITION_H,
    AdaptiveBirth,
    ConstantVelocityModel,
    GaussianMixturePHDBank,
    MixtureReducer,
)
from baselines.acoustic.perception.positioning import (
    ClockOffsetEstimator,
    LeastSquaresPositioner,
    work_area_centre,
)
from baselines.kalman import joseph_covariance, kalman_gain

ENV_IDS = ("auv_envs/AcousticTracking-v2",)
OBS_KEYS = ("tdoa", "azimuth", "elevation", "mask")
#: Floor added to each fix covariance's diagonal (m^2): the clock offsets (or,
#: with the clock calibration, the error left in their estimates) bias all
#: fixes of an episode alike, which the per-fix LS covariance ignores.
FIX_VARIANCE_FLOOR = 1e-4
#: ``ls-kf``'s defaults: sigma_q of the constant-velocity model (m/s^2), the chi-square gate
#: on the innovation (3 dof, 99.7 %) and the steps without a gated fix before it restarts.
LSKF_ACCEL_STD, LSKF_GATE, LSKF_MAX_MISSES = 1.0, 14.16, 20


def _check_env(env, name: str):
    if getattr(env, "obs_mode", None) != "measurements":
        raise ValueError(f"{name} needs obs_mode='measurements', got "
                         f"{getattr(env, 'obs_mode', None)!r}")
    if not hasattr(env, "calibration"):
        raise ValueError(f"{name} needs an AcousticTracking env (with .calibration)")
    return env.calibration


def _estimate_bounds(env, cal):
    """The fallback estimate (work-area centre) and the env's action bounds (the tank)."""
    space = env.action_space
    return work_area_centre(cal), space.low.astype(np.float64), space.high.astype(np.float64)


def _check_observation(observation) -> None:
    if not isinstance(observation, dict) or any(k not in observation for k in OBS_KEYS):
        raise ValueError(f"expected the 'measurements' observation dict with keys {OBS_KEYS}")


class _FixSource:
    """Position fixes of one observation, with safe placeholders for invalid ones.

    With ``clock_calibration`` the TDOAs are corrected by a
    :class:`ClockOffsetEstimator` fed with this source's own bands only. Only
    the nodes the observation's ``node_mask`` marks working (all without one)
    are used.
    """

    def __init__(self, calibration, bands, clock_calibration: bool):
        self.positioner = LeastSquaresPositioner(calibration, "fused")
        self.clock = ClockOffsetEstimator(calibration) if clock_calibration else None
        self.bands = np.asarray(bands)
        self._in_bands = np.zeros((len(calibration.band_centres), 1), bool)
        self._in_bands[self.bands] = True
        self._floor = FIX_VARIANCE_FLOOR * np.eye(3)
        self._eye = np.eye(3)

    def reset(self) -> None:
        if self.clock is not None:
            self.clock.reset()

    def __call__(self, observation):
        _check_observation(observation)
        tdoa, azimuth, elevation = (observation[k] for k in ("tdoa", "azimuth", "elevation"))
        clock = None if self.clock is None else self.clock.clock
        nodes = observation.get("node_mask")
        fixes = self.positioner.solve(tdoa, azimuth, elevation, observation["mask"], clock,
                                      nodes)
        if self.clock is not None:
            self.clock.update(tdoa, azimuth, elevation, fixes.valid & self._in_bands, nodes)
        z = fixes.position[self.bands]
        R = fixes.covariance[self.bands] + self._floor
        valid = fixes.valid[self.bands]
        z = np.where(valid[..., None], z, 0.0)
        R = np.where(valid[..., None, None], R, self._eye)
        return z, R, valid


class GMPHDGCIAgent:
    """Multi-band GM-PHD tracking with GCI fusion ([GMPHD] §2).

    Args:
      env: an unwrapped ``AcousticTracking`` env with ``obs_mode="measurements"``.
      bands: indices of the sub-bands to track (default: all Q).
      gci_weights: omega_q over ``bands`` (default equal, 1/Q).
      accel_std: sigma_q of the constant-velocity model (m/s^2).
      p_survival: p_S (0.99); p_detect: detection probability of a valid fix.
      prune_threshold: T_prune (1e-5), also the extraction threshold.
      max_components: per-band and fused component cap.
      clock_calibration: correct the TDOAs with online clock-offset estimates
        (:class:`~baselines.acoustic.perception.positioning.ClockOffsetEstimator`,
        our addition to [GMPHD]); False feeds the raw TDOAs as the paper does.
    """

    def __init__(self, env, bands=None, gci_weights=None, accel_std: float = 1.0,
                 p_survival: float = 0.99, p_detect: float = 0.9,
                 prune_threshold: float = 1e-5, max_components: int = 8,
                 clock_calibration: bool = True):
        cal = _check_env(env, type(self).__name__)
        q_all = len(cal.band_centres)
        bands = tuple(range(q_all)) if bands is None else tuple(int(b) for b in bands)
        if not bands or any(not 0 <= b < q_all for b in bands):
            raise ValueError(f"bands must be indices in [0, {q_all}), got {bands}")
        q = len(bands)
        self.bands = bands
        self._fixes = _FixSource(cal, bands, clock_calibration)
        self._dt = 1.0 / cal.sample_rate
        volume = cal.tank_size[0] * cal.tank_size[1] * cal.tank_depth
        self.bank = GaussianMixturePHDBank(
            q,
            ConstantVelocityModel(self._dt, accel_std),
            AdaptiveBirth(min_samples=min(3, q), n_sources=q),
            MixtureReducer(prune_threshold, max_components=max_components),
            p_survival=p_survival,
            p_detect=p_detect,
            # Uniform clutter over the tank at the configured false-alarm rate per
            # band: an upper bound on the false fixes that survive the LS gates.
            clutter_density=max(cal.config.clutter_rate, 0.1) / volume,
        )
        weights = np.full(q, 1.0 / q) if gci_weights is None else gci_weights
        self.fusion = GeneralizedCovarianceIntersection(weights, max_components=max_components)
        self.extractor = LabelledExtractor(prune_threshold)
        self._default, self._low, self._high = _estimate_bounds(env, cal)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        del seed  # deterministic
        self._fixes.reset()
        self.bank.reset()
        self.extractor.reset()
        self._last = None  # (6,) last extracted state
        self.last_label = -1
        self.fused = None

    def act(self, observation, info: dict) -> np.ndarray:
        z, R, valid = self._fixes(observation)
        mixtures = self.bank.step(z, R, valid)
        self.fused = self.fusion(mixtures)
        _, states, labels = self.extractor(self.fused)
        if len(states):
            self._last = states[0].copy()
            self.last_label = int(labels[0])
        elif self._last is not None:
            self._last[:3] += self._dt * self._last[3:]
            self.last_label = -1
        position = self._default if self._last is None else self._last[:3]
        return np.clip(position, self._low, self._high).astype(np.float32)


class LSKalmanAgent:
    """Fused LS fixes + one Kalman filter with nearest-neighbour gating (comparator).

    Args:
      env: an unwrapped ``AcousticTracking`` env with ``obs_mode="measurements"``.
      accel_std: sigma_q of the constant-velocity model (m/s^2).
      gate: chi-square gate on the innovation (3 dof; 14.16 = 99.7 %).
      max_misses: consecutive steps without a gated fix before re-initialising.
      clock_calibration: as for :class:`GMPHDGCIAgent`.
    """

    def __init__(self, env, accel_std: float = LSKF_ACCEL_STD, gate: float = LSKF_GATE,
                 max_misses: int = LSKF_MAX_MISSES, clock_calibration: bool = True):
        cal = _check_env(env, type(self).__name__)
        self._fixes = _FixSource(cal, range(len(cal.band_centres)), clock_calibration)
        self._motion = ConstantVelocityModel(1.0 / cal.sample_rate, accel_std)
        self.gate, self.max_misses = float(gate), int(max_misses)
        self._default, self._low, self._high = _estimate_bounds(env, cal)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        del seed
        self._fixes.reset()
        self._x = None
        self._P = None
        self._misses = 0

    def _initialise(self, z, R) -> None:
        centre = np.median(z, axis=0)
        i = int(np.argmin(np.sum((z - centre) ** 2, axis=1)))
        self._x = np.concatenate([z[i], np.zeros(3)])
        self._P = np.diag(np.concatenate([np.diag(R[i]), np.ones(3)]))
        self._misses = 0

    def act(self, observation, info: dict) -> np.ndarray:
        z, R, valid = self._fixes(observation)
        z, R = z[valid], R[valid]
        if self._x is not None:
            self._x, self._P = self._motion.predict(self._x, self._P)
        if self._x is None or self._misses >= self.max_misses:
            if len(z):
                self._initialise(z, R)
        elif len(z):
            S = self._P[:3, :3] + R
            nu = z - self._x[:3]
            d2 = np.einsum("ni,nij,nj->n", nu, np.linalg.inv(S), nu)
            i = int(np.argmin(d2))
            if d2[i] <= self.gate:
                gain = kalman_gain(self._P, POSITION_H, R[i])
                self._x = self._x + gain @ nu[i]
                # Joseph form: P - K H P loses positive definiteness after
                # ~23 s of an episode with centimetre-precise fixes.
                self._P = joseph_covariance(self._P, gain, POSITION_H, R[i])
                self._misses = 0
            else:
                self._misses += 1
        else:
            self._misses += 1
        position = self._default if self._x is None else self._x[:3]
        return np.clip(position, self._low, self._high).astype(np.float32)


def best_single_band(env) -> int:
    """The band with the smallest mean elevation noise at the work-area centre."""
    cal = env.calibration
    return int(np.argmin(cal.array.model(work_area_centre(cal))["elevation_std"].mean(axis=1)))


def single_band_agent(env, **kwargs) -> GMPHDGCIAgent:
    """``gmphd-single``: :class:`GMPHDGCIAgent` on :func:`best_single_band` (kwargs pass on)."""
    _check_env(env, "gmphd-single")
    return GMPHDGCIAgent(env, bands=(best_single_band(env),), **kwargs)
