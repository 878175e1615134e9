"""Water optics of a camera looking at lamps: Jerlov water types, image formation, detection.

One parameter bundle, :class:`WaterOptics`, drives three parts:

* :func:`degrade_image`: the underwater image formation model of Akkaynak &
  Treibitz (2018) applied to a clear-water render and its per-pixel range,
  plus the glow of the lamps (small-angle forward scattering) and sensor noise;
* :func:`detect_lamps`: the same water for lamps reduced to pixel coordinates
  (features): a detection probability that falls with the lamp's received
  contrast, and centroid noise that grows with the glow;
* :class:`LampOutages`: lamps that failed for the whole episode and lamps hidden
  for a while by something passing in front of them.

Every random draw takes the episode's generator as an argument.

References:
    Akkaynak, D. & Treibitz, T. (2018). A revised underwater image formation
    model. CVPR, 6723-6732.
    Akkaynak, D. et al. (2017). What is the space of attenuation coefficients
    in underwater computer vision? CVPR, 568-577.
    Foi, A. et al. (2008). Practical Poissonian-Gaussian noise modeling and
    fitting for single-image raw-data. IEEE Trans. Image Process. 17(10).
    Hou, W. et al. (2008). Comparison and validation of point spread models
    for imaging in natural waters. Optics Express 16(13), 9958-9965.
    Jerlov, N. G. (1976). Marine Optics, 2nd ed. Elsevier.
    Middleton, W. E. K. (1952). Vision through the Atmosphere. Univ. of
    Toronto Press (Allard's law for the visibility of point lights).
    Wells, W. H. (1973). Theory of small angle scattering. AGARD Lecture
    Series 61.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers

import cv2
import numpy as np
from scipy import optimize
from scipy.special import ndtri

from auv_envs.core.ops import FLOATS
from auv_envs.core.plant import CompiledFunction, SymbolicDraws

#: Jerlov water types: oceanic I (clearest) to III, coastal 1C to 9C (most turbid).
JERLOV_TYPES = ("I", "IA", "IB", "II", "III", "1C", "3C", "5C", "7C", "9C")
#: Representative wavelengths of the camera's R, G and B channels, nm.
CHANNEL_WAVELENGTHS = (620.0, 540.0, 460.0)

# Jerlov (1976), Table XXVII (p. 135): the downwelling diffuse attenuation
# coefficient K_d (converted to 1/m) that defines each water type, at the
# table's wavelengths that bracket CHANNEL_WAVELENGTHS.
_TABLE_WAVELENGTHS = (450.0, 475.0, 525.0, 550.0, 600.0, 625.0)
_JERLOV_KD = {
    "I": (0.019, 0.018, 0.043, 0.063, 0.235, 0.305),
    "IA": (0.026, 0.025, 0.048, 0.067, 0.240, 0.310),
    "IB": (0.036, 0.033, 0.054, 0.072, 0.245, 0.315),
    "II": (0.068, 0.062, 0.076, 0.089, 0.260, 0.335),
    "III": (0.135, 0.116, 0.116, 0.120, 0.295, 0.375),
    "1C": (0.25, 0.17, 0.13, 0.12, 0.30, 0.37),
    "3C": (0.39, 0.29, 0.20, 0.19, 0.33, 0.40),
    "5C": (0.56, 0.43, 0.31, 0.30, 0.40, 0.48),
    "7C": (0.89, 0.71, 0.49, 0.46, 0.48, 0.54),
    "9C": (1.60, 1.23, 0.78, 0.63, 0.60, 0.65),
}

#: One grey level: the darkest veiling light a lamp's contrast is measured against.
_GREY_LEVEL = 1.0 / 255.0
#: Ranges are clipped here so that ``0 * range`` stays 0 (no geometry: ``inf``).
_FAR = 1e30


def jerlov_attenuation(water_type: str) -> tuple[float, float, float]:
    """``K_d`` (1/m) of a Jerlov water type at :data:`CHANNEL_WAVELENGTHS` (R, G, B).

    Linear interpolation in Jerlov (1976) Table XXVII between its 25 nm
    columns: 600/625 nm for red (620 nm), 525/550 nm for green (540 nm),
    450/475 nm for blue (460 nm). IB gives (0.301, 0.065, 0.035), 5C
    (0.464, 0.304, 0.508).

    Raises:
        ValueError: an unknown water type.
    """
    if water_type not in _JERLOV_KD:
        raise ValueError(
            f"unknown Jerlov water type {water_type!r}; valid types: {', '.join(JERLOV_TYPES)}")
    table = _JERLOV_KD[water_type]
    return tuple(float(np.interp(w, _TABLE_WAVELENGTHS, table)) for w in CHANNEL_WAVELENGTHS)


@dataclasses.dataclass(frozen=True)
class WaterOptics:
    """The water between the camera and the lamps, and the camera's sensor.

    Build it from a water type with :meth:`jerlov`, or give every value.
    Pixel values are in units of the sensor's full scale (1 = 255 in the
    ``uint8`` image) unless stated.

    Attributes:
        attenuation: attenuation coefficient β of the R, G, B channels, 1/m.
            :meth:`jerlov` takes Jerlov's ``K_d``, the attenuation that
            Akkaynak et al. (2017, Fig. 1) plot as β(λ) of the water types;
            it is the attenuation of the light that reaches the camera
            directly or forward-scattered (the glow keeps the latter). The
            beam attenuation ``c = a + b`` is larger by the scattering.
        veiling_light: backscattered veiling light ``B∞`` of the R, G, B
            channels, 0..1: the colour of open water (a pixel at infinite range).
        water_type: a name for reports (the Jerlov type, or ``"custom"``).
        lamp_radiance: radiance of a lamp's pixels relative to full scale
            (a rendered lamp saturates; the lamp itself is brighter, so it
            still saturates, and glows, through some attenuation). Our
            choice; a guide lamp is a light source seen at an exposure set
            for the dim water.
        glow_rate: share of the received lamp light that forward scattering
            spreads into the glow: ``1 - exp(-glow_rate * τ_s)``, with
            ``τ_s = min(β) d`` the scattering optical depth of range ``d``
            (the clearest channel's optical depth bounds the part of the
            attenuation that is scattering; particle scattering varies little
            across the visible). 1 is Wells' (1973) small-angle model, whose
            unscattered share is ``exp(-b d)``.
        glow_angle: angular width (standard deviation, rad) of the glow per
            unit ``τ_s``. Wells' (1973) modulation transfer function
            ``exp(-d (c - b (1 - exp(-2π θ0 ψ)) / (2π θ0 ψ)))`` (Hou et al.
            2008) falls at low spatial frequency ψ as
            ``exp(-π θ0 b d ψ)``, the transform of a glow of angular scale
            ``θ0 b d / 2``; 0.05 takes a mean forward-scattering angle
            θ0 = 0.1 rad (our choice of the order of the width of ocean
            particles' forward-scattering peak). The glow is drawn as a
            Gaussian of that width.
        shot_noise, read_noise: sensor noise ``a`` (grey levels) and ``b``
            (grey levels squared): each pixel's value ``y`` (0..255) gets
            Gaussian noise of variance ``a y + b`` (Foi et al. 2008). Our
            choice 0.1 and 1.0: a full well of about 2,500 electrons at the
            8-bit scale and a read noise of one grey level.
        lamp_intensity: lamp intensity ``I0`` of the detection model, full
            scale times m²: a lamp at range ``d`` delivers ``I0 exp(-β d) / d²``
            (Allard's law for a point light, Middleton 1952), compared with
            the veiling light ``B∞`` (at least one grey level) in its best
            channel: the contrast ``C``. Our choice 600: with the defaults a
            lamp is detected half the time at about 10 m in 5C water and
            beyond 30 m in IB.
        detection_contrast, detection_slope: detection probability
            ``1 / (1 + (C50 / C)^k)``, logistic in ``log C`` with midpoint
            ``C50 = detection_contrast`` and slope ``k = detection_slope``.
            Our choice 1 and 2.
        centroid_noise, centroid_blur_ratio: standard deviation of a
            detected lamp's centroid, pixels: ``centroid_noise +
            centroid_blur_ratio * glow width in pixels``. Our choice 0.2 px
            and 0.1 (a centroid is a small fraction of a blob's width).
        lamp_failure_probability: probability that a lamp is dark for a
            whole episode, independently per lamp. Our choice 0.02.
        occlusion_rate, occlusion_duration: something passing in front of
            a lamp (a fish, a particle cloud) hides it: per lamp a two-state
            Markov process that becomes hidden at ``occlusion_rate`` (1/s) and
            clears after an exponential time of mean ``occlusion_duration``
            (s); hidden a fraction ``rate T / (1 + rate T)`` of the time. Our
            choice 0.01 /s and 2 s.
    """

    attenuation: tuple[float, float, float]
    veiling_light: tuple[float, float, float]
    water_type: str = "custom"
    lamp_radiance: float = 20.0
    glow_rate: float = 1.0
    glow_angle: float = 0.05
    shot_noise: float = 0.1
    read_noise: float = 1.0
    lamp_intensity: float = 600.0
    detection_contrast: float = 1.0
    detection_slope: float = 2.0
    centroid_noise: float = 0.2
    centroid_blur_ratio: float = 0.1
    lamp_failure_probability: float = 0.02
    occlusion_rate: float = 0.01
    occlusion_duration: float = 2.0

    def __post_init__(self):
        for name in ("attenuation", "veiling_light"):
            values = getattr(self, name)
            try:
                values = tuple(float(v) for v in values)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{name} must be three numbers (R, G, B), got {values!r}") \
                    from exc
            if len(values) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in values):
                raise ValueError(
                    f"{name} must be three finite non-negative numbers (R, G, B), got {values}")
            object.__setattr__(self, name, values)
        if max(self.veiling_light) > 1.0:
            raise ValueError(f"veiling_light must lie in [0, 1], got {self.veiling_light}")
        positive = ("lamp_radiance", "lamp_intensity", "detection_contrast", "detection_slope",
                    "occlusion_duration")
        non_negative = ("glow_rate", "glow_angle", "shot_noise", "read_noise", "centroid_noise",
                        "centroid_blur_ratio", "occlusion_rate")
        for name in positive + non_negative + ("lamp_failure_probability",):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real) \
                    or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
            if name in positive and value <= 0.0:
                raise ValueError(f"{name} must be positive, got {value}")
            if value < 0.0:
                raise ValueError(f"{name} must not be negative, got {value}")
            object.__setattr__(self, name, float(value))
        if self.lamp_failure_probability > 1.0:
            raise ValueError(
                f"lamp_failure_probability must lie in [0, 1], got {self.lamp_failure_probability}")

    @classmethod
    def jerlov(cls, water_type: str, depth: float = 10.0, brightness: float = 0.3,
               **parameters) -> WaterOptics:
        """The optics of a Jerlov water type.

        Args:
            water_type: one of :data:`JERLOV_TYPES`.
            depth: depth of the scene below the surface, m. The veiling
                light is daylight scattered by the water, so its colour is
                that of the downwelling light at that depth,
                ``exp(-K_d depth)`` per channel (the definition of ``K_d``,
                white light at the surface; the backscattering share taken
                equal in the three channels). Default 10 m.
            brightness: the veiling light's brightest channel, 0..1: the
                camera's exposure keeps open water at this grey level
                (default 0.3, our choice).
            **parameters: any other :class:`WaterOptics` field.

        Raises:
            ValueError: an unknown type, or a depth or brightness out of range.
        """
        attenuation = jerlov_attenuation(water_type)
        if not (math.isfinite(depth) and depth >= 0.0):
            raise ValueError(f"depth must be a finite non-negative number of metres, got {depth}")
        if not (math.isfinite(brightness) and 0.0 < brightness <= 1.0):
            raise ValueError(f"brightness must lie in (0, 1], got {brightness}")
        daylight = np.exp(-np.asarray(attenuation) * depth)
        veiling = brightness * daylight / daylight.max()
        return cls(attenuation=attenuation, veiling_light=tuple(veiling.tolist()),
                   water_type=water_type, **parameters)

    # ------------------------------------------------------------------ shared terms
    def scattering_depth(self, distance, xp) -> np.ndarray:
        """``τ_s = min(β) d``: the optical depth that scatters into the glow.

        ``xp`` (here and in the detection model below): the array module,
        ``numpy`` or ``jax.numpy``; None where ``distance`` is one scalar of any arithmetic
        (a float, a CasADi symbol: :class:`CompiledLampDetection`)."""
        return min(self.attenuation) * _as_float(distance, xp)

    def glow_width(self, distance, focal_px: float, xp) -> np.ndarray:
        """Standard deviation of a lamp's glow at range ``distance`` (m), pixels."""
        return focal_px * self.glow_angle * self.scattering_depth(distance, xp)

    def lamp_contrast(self, distance, xp) -> np.ndarray:
        """Received contrast ``C`` of a lamp at range ``distance`` (m), its best channel."""
        d = xp.maximum(_as_float(distance, xp), 1e-3)
        veil = xp.maximum(xp.asarray(self.veiling_light), _GREY_LEVEL)
        return self._relative(d[..., None], xp.asarray(self.attenuation), veil,
                              xp).max(axis=-1) / (d * d)

    def _relative(self, d, attenuation, veil, xp):
        """A lamp's radiance at ``d`` over the veiling light ``veil``, per channel."""
        return self.lamp_intensity * xp.exp(-(d * attenuation)) / veil

    def scalar_contrast(self, distance, ops):
        """:meth:`lamp_contrast` of one ``distance`` in the scalar arithmetic of ``ops``
        (:mod:`auv_envs.core.ops`)."""
        d = ops.maximum(distance, 1e-3)
        best = None
        for attenuation, veil in zip(self.attenuation, self.veiling_light, strict=True):
            channel = self._relative(d, attenuation, max(veil, _GREY_LEVEL), ops)
            best = channel if best is None else ops.maximum(best, channel)
        return best / (d * d)

    def detection_probability(self, distance, xp) -> np.ndarray:
        """Probability that a lamp in view at range ``distance`` (m) is detected."""
        return self.detection_of_contrast(self.lamp_contrast(distance, xp))

    def detection_of_contrast(self, contrast):
        """:meth:`detection_probability` at a received ``contrast`` (any arithmetic)."""
        ratio = self.detection_contrast / contrast
        return 1.0 / (1.0 + ratio ** self.detection_slope)

    def detection_range(self, probability: float = 0.5) -> float:
        """The range (m) at which a lamp in view is detected with ``probability``: the
        root of the detection probability, which falls with range (SciPy's ``brentq`` to
        1 mm, between 1 mm and 10 km)."""
        if not 0.0 < probability < 1.0:
            raise ValueError(f"probability must be in (0, 1), got {probability!r}")
        with np.errstate(over="ignore", divide="ignore"):  # far out the contrast underflows
            return float(optimize.brentq(
                lambda d: float(self.detection_probability(d, np)) - probability, 1e-3, 1e4,
                xtol=1e-3))

    def centroid_std(self, distance, focal_px: float, xp) -> np.ndarray:
        """Standard deviation of a detected lamp's centroid (each axis), pixels."""
        return self.centroid_noise + self.centroid_blur_ratio * self.glow_width(
            distance, focal_px, xp)


def _as_float(values, xp):
    """``values`` as a float array of ``xp`` (NumPy: float64); as they are for None."""
    if xp is None:
        return values
    return np.asarray(values, dtype=float) if xp is np else xp.asarray(values)


# ---------------------------------------------------------------------- images
#: Standard normal quantiles at the centres of 2^16 equal-probability bins,
#: scaled to unit variance: indexing it with uniform 16-bit draws samples the
#: sensor noise at a third of the cost of ``Generator.standard_normal``
#: (tails cut at 4.2 standard deviations).
_NORMAL_QUANTILES = ndtri((np.arange(2 ** 16) + 0.5) / 2 ** 16)
_NORMAL_QUANTILES = (_NORMAL_QUANTILES / _NORMAL_QUANTILES.std()).astype(np.float32)


def degrade_image(image: np.ndarray, distance: np.ndarray, optics: WaterOptics,
                  focal_px: float, rng: np.random.Generator) -> np.ndarray:
    """The clear-water ``image`` as the camera sees it through ``optics``' water.

    Per channel ``I = J exp(-β d) + B∞ (1 - exp(-β d))`` (Akkaynak & Treibitz
    2018, with one coefficient for the direct signal and the backscatter,
    which their revised model separates), ``J`` the clear-water image and
    ``d`` the range; where no geometry was drawn (``d = inf``) a pixel is
    ``B∞``. Pixels saturated in every channel are lamps: their radiance is
    ``lamp_radiance``, of which the share ``1 - exp(-glow_rate τ_s)`` glows:
    each lamp (connected bright region) spreads it as a Gaussian of its own
    size widened by :meth:`WaterOptics.glow_width`. Then sensor noise of
    variance ``a y + b`` (drawn from ``rng``, nothing drawn when both are 0),
    rounding and clipping. OpenCV does the per-pixel arithmetic: on a
    640x480 frame NumPy took several times as long.

    Args:
        image: ``(H, W, 3)`` uint8 clear-water render.
        distance: ``(H, W)`` range along each pixel's ray, m (``inf``: none).
        optics: the water and sensor.
        focal_px: the camera's focal length, pixels (for the glow's width).
        rng: the episode's generator.

    Returns:
        A new ``(H, W, 3)`` uint8 image.
    """
    height = image.shape[0]
    d = cv2.min(np.asarray(distance, dtype=np.float32), _FAR)  # 0 * d stays 0 where d = inf
    transmission = cv2.merge([cv2.exp(d * np.float32(-b)) for b in optics.attenuation])
    # Grey levels (0..255) from here; a 4-tuple is OpenCV's per-channel scalar.
    veil = (*(255.0 * v for v in optics.veiling_light), 0.0)
    out = cv2.add(cv2.multiply(cv2.subtract(image.astype(np.float32), veil), transmission), veil)
    lamps = cv2.inRange(image, (255, 255, 255), (255, 255, 255))
    if cv2.countNonZero(lamps):
        out = _add_lamps(out, lamps, d, transmission, veil[:3], optics, focal_px)
    flat = out.reshape(height, -1)  # one channel: OpenCV's scalars apply to every value
    if optics.shot_noise > 0.0 or optics.read_noise > 0.0:
        flat = cv2.min(flat, 255.0)  # the sensor saturates before its noise
        std = cv2.sqrt(cv2.add(cv2.multiply(flat, optics.shot_noise), optics.read_noise))
        normal = _NORMAL_QUANTILES[rng.integers(0, 2 ** 16, flat.shape, dtype=np.uint16)]
        flat = cv2.add(flat, cv2.multiply(std, normal))
    # Rounded to the nearest grey level and saturated to 0..255.
    return cv2.add(flat, 0.0, dtype=cv2.CV_8U).reshape(image.shape)


def _add_lamps(out: np.ndarray, lamps: np.ndarray, d: np.ndarray, transmission: np.ndarray,
               veil: tuple[float, float, float], optics: WaterOptics,
               focal_px: float) -> np.ndarray:
    """Lamp pixels: the unscattered share in place, the glow as one Gaussian per lamp."""
    rows, cols = np.nonzero(lamps)
    lamp_d = d[rows, cols]
    lamp_t = transmission[rows, cols]  # (N, 3)
    glow_share = 1.0 - np.exp(-optics.glow_rate * optics.scattering_depth(lamp_d, np))
    received = (255.0 * optics.lamp_radiance) * lamp_t
    out[rows, cols] = np.asarray(veil) * (1.0 - lamp_t) + received * (1.0 - glow_share)[:, None]
    glow = received * glow_share[:, None]
    if not glow.any():
        return out
    n_blobs, labels = cv2.connectedComponents(lamps, connectivity=8)
    label = labels[rows, cols]
    count = np.bincount(label, minlength=n_blobs)[1:]
    mean_x = np.bincount(label, cols, n_blobs)[1:] / count
    mean_y = np.bincount(label, rows, n_blobs)[1:] / count
    var_x = np.bincount(label, cols * cols, n_blobs)[1:] / count - mean_x ** 2
    var_y = np.bincount(label, rows * rows, n_blobs)[1:] / count - mean_y ** 2
    blob_d = np.bincount(label, lamp_d, n_blobs)[1:] / count
    flux = np.stack([np.bincount(label, glow[:, c], n_blobs)[1:] for c in range(3)], axis=1)
    # A pixel is a unit square (variance 1/12); the glow widens the blob.
    sigma2 = optics.glow_width(blob_d, focal_px, np) ** 2 + 1.0 / 12.0
    height, width = lamps.shape
    gx = _gaussian_rows(np.arange(width), mean_x, sigma2 + var_x)  # (K, W)
    # (H, K), C-ordered: BLAS is an order of magnitude slower on the transposed view.
    gy = np.ascontiguousarray(_gaussian_rows(np.arange(height), mean_y, sigma2 + var_y).T)
    halo = [(gy * flux[:, c].astype(np.float32)) @ gx for c in range(3)]
    return cv2.add(out, cv2.merge(halo))


def _gaussian_rows(grid: np.ndarray, centres: np.ndarray, variances: np.ndarray) -> np.ndarray:
    """Row k: a unit-area Gaussian (centre k, variance k) sampled on ``grid``, float32."""
    variances = np.maximum(variances, 0.25)  # at sigma >= 0.5 px the samples sum to 1
    offsets = grid[None, :] - centres[:, None]
    rows = np.exp(-0.5 * offsets ** 2 / variances[:, None])
    rows /= np.sqrt(2 * np.pi * variances)[:, None]
    return rows.astype(np.float32)


# ---------------------------------------------------------------------- features
@dataclasses.dataclass(frozen=True, eq=False)
class LampOutages:
    """Which lamps are out: failed for the episode, or hidden by an occluder now.

    Attributes:
        failed: (n,) bool, drawn once per episode.
        occluded: (n,) bool, a two-state Markov process per lamp.
    """

    failed: np.ndarray
    occluded: np.ndarray

    @classmethod
    def start(cls, optics: WaterOptics, n_lamps: int, rng: np.random.Generator) -> LampOutages:
        """An episode's outages: failures, and occlusions from their stationary distribution."""
        return cls(*cls.draw_start(optics, n_lamps, rng))

    @classmethod
    def draw_start(cls, optics: WaterOptics, n_lamps: int, rng) -> tuple:
        """:meth:`start`'s ``(failed, occluded)`` per lamp, from ``rng`` (NumPy's
        ``Generator``, or a JAX key's draws)."""
        failed = rng.random(n_lamps) < optics.lamp_failure_probability
        occluded = rng.random(n_lamps) < cls.occluded_share(optics)
        return failed, occluded

    @staticmethod
    def occluded_share(optics: WaterOptics) -> float:
        """The stationary probability that a lamp is hidden by an occluder."""
        rate_time = optics.occlusion_rate * optics.occlusion_duration
        return rate_time / (1.0 + rate_time)

    def advance(self, optics: WaterOptics, dt: float, rng: np.random.Generator) -> LampOutages:
        """The outages ``dt`` seconds later (exact transition probabilities of the process)."""
        return LampOutages(self.failed, self.occlusions_drawn(self.occluded, optics, dt, rng, np))

    @classmethod
    def occlusions_drawn(cls, occluded, optics: WaterOptics, dt: float, rng, xp):
        """:meth:`occlusions_after` with its uniform draws from ``rng`` (one per lamp)."""
        return cls.occlusions_after(occluded, optics, dt, rng.random(occluded.shape[0]), xp)

    @staticmethod
    def transition_probabilities(optics: WaterOptics, dt: float) -> tuple[float, float]:
        """``(appear, clear)``: the probabilities that a clear lamp is hidden, and a hidden
        one cleared, within ``dt`` seconds."""
        return (-math.expm1(-optics.occlusion_rate * dt),
                -math.expm1(-dt / optics.occlusion_duration))

    @classmethod
    def occlusions_after(cls, occluded, optics: WaterOptics, dt: float, u, xp):
        """The occlusions ``dt`` seconds after ``occluded`` given one uniform draw per lamp."""
        return cls.occlusion_rule(occluded, u, *cls.transition_probabilities(optics, dt),
                                  xp.where)

    @staticmethod
    def occlusion_rule(occluded, u, appear, clear, where):
        """A lamp hidden after a step given its uniform draw ``u``: a hidden one stays so
        unless cleared (``u < clear``), a clear one is hidden when ``u < appear``; ``where``
        selects (``xp.where`` for arrays, :data:`~auv_envs.core.ops.FLOATS`' for one lamp)."""
        return where(occluded, u >= clear, u < appear)

    @property
    def out(self) -> np.ndarray:
        """(n,) bool: the lamps that cannot be seen now."""
        return self.failed | self.occluded


def detect_lamps(pixels: np.ndarray, visible: np.ndarray, distance: np.ndarray,
                 outages, optics: WaterOptics, focal_px: float,
                 rng: np.random.Generator, xp) -> tuple[np.ndarray, np.ndarray]:
    """Which lamps in view the camera detects through the water, and where.

    A lamp in view (``visible``), not failed and not occluded, is detected with
    :meth:`WaterOptics.detection_probability` at its range; a detected lamp's
    pixels get Gaussian noise of :meth:`WaterOptics.centroid_std`. The draws
    (one uniform and two normals per lamp) are made for every lamp, so their
    number does not depend on the state.

    Args:
        pixels: (n, 2) pixel coordinates of the lamps.
        visible: (n,) bool, the lamps geometrically in view.
        distance: (n,) range from the camera centre to each lamp, m.
        outages: the lamps out now (anything with ``out``, (n,) bool: a
            :class:`LampOutages`, a transition's episode state).
        optics: the water.
        focal_px: the camera's focal length, pixels.
        rng: the episode's draws (NumPy's ``Generator``, or a JAX key's).
        xp: the array module.

    Returns:
        ``(pixels, detected)``: new (n, 2) pixels, zero where not detected,
        and the (n,) bool detection mask.
    """
    n = visible.shape[0]
    u = rng.random(n)
    noise = rng.standard_normal((n, 2))
    return lamp_detections(pixels, visible, distance, outages.out, optics, focal_px, u, noise,
                           xp)


def lamp_detections(pixels, visible, distance, out, optics: WaterOptics, focal_px: float,
                    u, noise, xp):
    """:func:`detect_lamps` given its draws: ``u`` (n,) uniform and ``noise`` (n, 2)
    standard normal, with ``out`` the lamps failed or hidden; ``xp`` the array module."""
    detected = visible & ~out & (u < optics.detection_probability(distance, xp))
    noisy = pixels + noise * optics.centroid_std(distance, focal_px, xp)[:, None]
    return xp.where(detected[:, None], noisy, 0.0), detected


class CompiledLampDetection:
    """The lights of a ``features`` observation through the water as one compiled call on
    the CPU (the docking tasks' ``sensors="compiled"``): the pixel noise, masked and
    clipped, then :func:`detect_lamps` at each lamp's range and the clip again, as
    :func:`auv_envs.tasks.docking.transition.observe` does in NumPy; where no navigation
    suite reads the motion, the DVL/INS readings before them
    (:meth:`~auv_envs.tasks.docking.rules.DockingRules.sensor_readings`); the same draws
    from the episode's generator. Built from the same models on CasADi symbols
    (:meth:`WaterOptics.scalar_contrast`); the numbers equal NumPy's at round-off (NumPy's
    vectorised ``exp`` is not the C library's).

    Args:
        light_positions: (n, 3) the lamps in the world, m.
        optics: the water.
        pixel_std: the pixel noise's standard deviation (0: none drawn).
        pixel_bounds: ``(low, high)``, each (n, 2): the observation's pixel bounds.
        focal_px: the camera's focal length, pixels.
        dt: the control period, s (the occlusions' step, :meth:`occlusions`).
        readings: the readings' noise ``(velocity, yaw rate, attitude)`` standard
            deviations (none drawn where the velocity's is 0); None: no readings.
    """

    def __init__(self, light_positions, optics: WaterOptics, pixel_std: float, pixel_bounds,
                 focal_px: float, dt: float, readings: tuple | None = None):
        low, high = (tuple(np.asarray(bound, dtype=float).ravel().tolist())
                     for bound in pixel_bounds)
        lights = tuple(tuple(p) for p in np.asarray(light_positions, dtype=float).tolist())
        if readings is not None:
            readings = tuple(float(std) for std in readings)
        function, draws = _lamp_function(lights, optics, float(pixel_std), low, high,
                                         float(focal_px), readings)
        self._call = CompiledFunction(function)
        self._views = draws.views(self._call.inputs[2])
        self._n = len(lights)
        #: Whether the call makes the DVL/INS readings too (``velocity``, ``attitude``).
        self.reads = readings is not None
        self._arguments = (light_positions, optics, pixel_std, pixel_bounds, focal_px, dt,
                           readings)
        self._uniforms = np.empty(self._n)
        self._appear, self._clear = LampOutages.transition_probabilities(optics, dt)

    def occlusions(self, occluded: np.ndarray, rng) -> np.ndarray:
        """:meth:`LampOutages.occlusions_drawn` (the same draws and comparisons), in
        Python floats: for a handful of lamps NumPy's per-call cost exceeds the work."""
        rng.random(out=self._uniforms)
        rule, appear, clear = LampOutages.occlusion_rule, self._appear, self._clear
        return np.array([rule(hidden, u, appear, clear, FLOATS.where)
                         for hidden, u in zip(occluded.tolist(), self._uniforms.tolist(),
                                              strict=True)], dtype=bool)

    def __reduce__(self):  # built again: the draws' views alias the call's inputs
        return type(self), self._arguments

    def __call__(self, truth: dict, out, rng) -> dict:
        """The observation's ``pixels`` ((n, 2) float32) and ``visible`` ((n,) int8, the
        lamps detected), with :attr:`reads` its ``velocity`` (4) and ``attitude`` (3)
        float32, at ``truth`` (with its ``visible_pixels``, ``visible``,
        ``camera_position``, ``velocity`` and ``euler``), ``out`` (n,) the lamps failed or
        hidden, drawing from ``rng``."""
        n, call = self._n, self._call
        call.inputs[0][:] = truth["visible_pixels"].reshape(-1)
        flags = call.inputs[1]
        flags[:n], flags[n:2 * n] = truth["visible"], out
        if self.reads:
            flags[2 * n:] = (*truth["camera_position"], *truth["velocity"], *truth["euler"])
        else:
            flags[2 * n:] = truth["camera_position"]
        SymbolicDraws.draw(self._views, rng)
        result = call()[0]
        obs = {"pixels": result[:2 * n].reshape(n, 2).astype(np.float32),
               "visible": result[2 * n:3 * n].astype(np.int8)}
        if self.reads:
            obs["velocity"] = result[3 * n:3 * n + 4].astype(np.float32)
            obs["attitude"] = result[3 * n + 4:].astype(np.float32)
        return obs


@functools.lru_cache(maxsize=16)
def _lamp_function(lights: tuple, optics: WaterOptics, pixel_std: float, low: tuple,
                   high: tuple, focal_px: float, readings: tuple | None):
    """:class:`CompiledLampDetection`'s CasADi function ``(pixels[2n], flags, draws) ->
    [pixels 2n, detected n (1.0 or 0.0), with readings their 7]`` (flags: in view n, out n,
    the camera's position 3, with readings the body velocity 6 and the Euler angles 3) and
    its draws' layout; built once per scene (a CasADi function is immutable)."""
    import casadi

    from auv_envs.core.ops import casadi_ops
    from auv_envs.tasks.docking.rules import DockingRules

    ops = casadi_ops()
    n = len(lights)
    pixels = casadi.SX.sym("pixels", 2 * n)
    flags = casadi.SX.sym("flags", 2 * n + 3 + (9 if readings is not None else 0))
    draws = SymbolicDraws("lamps")
    sensed = []
    if readings is not None:  # drawn first, as transition.observe reads before the lamps
        noise = draws.standard_normal(7) if readings[0] > 0 else None
        motion = {"velocity": [flags[2 * n + 3 + k] for k in range(6)],
                  "euler": [flags[2 * n + 9 + k] for k in range(3)]}
        velocity, attitude = DockingRules.sensor_readings(
            motion, None if noise is None else [noise[k] for k in range(7)], readings,
            ops.mod)
        sensed = [*velocity, *attitude]
    noise = draws.standard_normal(2 * n) if pixel_std > 0 else None
    hits, jitter = draws.random(n), draws.standard_normal(2 * n)
    camera = [flags[2 * n + k] for k in range(3)]
    values, detections = [], []
    for i, light in enumerate(lights):
        in_view = flags[i] > 0.5
        coordinates = [pixels[2 * i + k] for k in range(2)]
        if noise is not None:  # as add_pixel_noise, masked, clipped
            coordinates = [ops.clip(ops.where(in_view, c + pixel_std * noise[2 * i + k], 0.0),
                                    low[2 * i + k], high[2 * i + k])
                           for k, c in enumerate(coordinates)]
        distance = ops.sqrt(sum((light[k] - camera[k]) ** 2 for k in range(3)))
        probability = optics.detection_of_contrast(optics.scalar_contrast(distance, ops))
        detected = ops.logical_and(ops.logical_and(in_view, ops.logical_not(flags[n + i] > 0.5)),
                                   hits[i] < probability)
        spread = optics.centroid_std(distance, focal_px, None)
        values += [ops.clip(ops.where(detected, c + jitter[2 * i + k] * spread, 0.0),
                            low[2 * i + k], high[2 * i + k]) for k, c in enumerate(coordinates)]
        detections.append(ops.where(detected, 1.0, 0.0))
    function = casadi.Function("lamp_detection", [pixels, flags, draws.column()],
                               [casadi.vertcat(*values, *detections, *sensed)], {"cse": True})
    return function, draws
