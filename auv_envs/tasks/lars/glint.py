"""Sun glint as the LARS capture head's cameras see it (``difficulty="hard"``).

:class:`GlintCamera` turns the episode's :class:`~auv_envs.tasks.lars.sea.GlintField`
(the glint density of the sea surface, Cox & Munk 1954, Longuet-Higgins
1960) into what one frame shows: in ``features``, which marker corners a
glint moves or hides; in ``stereo``, the saturated spots on the rendered
water. The draws come from the episode's generator, passed in.
"""

from __future__ import annotations

import math

import numpy as np

from auv_envs.core.camera import CameraIntrinsics
from auv_envs.core.ops import FLOATS
from auv_envs.tasks.lars.sea import GlintField, SunGlint

#: A rendered pixel shows the water when its range is within this of the water plane's
#: along its ray, m (the depth buffer resolves ~1e-6 m at 1 m).
GLINT_WATER_TOLERANCE = 0.005


class GlintCamera:
    """The glint draws of one camera model: the detector's disc, the bloom, the pixel rays.

    Args:
        glint: the glint model (detector radius and bloom, px).
        intrinsics: both cameras' intrinsics (the head is level; the two
            cameras look along the same rays).
        hull_half: half the length of the hull's straight part, m.
        waterline_half_width: half-width of the hull's footprint on the water, m.
        images: precompute each pixel's ray, for :meth:`on_pair` (``stereo``).
    """

    def __init__(self, glint: SunGlint, intrinsics: CameraIntrinsics, hull_half: float,
                 waterline_half_width: float, images: bool):
        self.glint = glint
        self._intrinsics = intrinsics
        self._hull_half = hull_half
        self._waterline = waterline_half_width
        r = glint.detector_radius
        n = math.ceil(r)
        du, dv = np.meshgrid(np.arange(-n, n + 1.0), np.arange(-n, n + 1.0))
        inside = du**2 + dv**2 <= r * r
        self._disc = np.stack((du[inside], dv[inside]), axis=-1)
        b = glint.bloom
        self._bloom = [(i, j) for i in range(-b, b + 1) for j in range(-b, b + 1)
                       if i * i + j * j <= b * b]
        if images:
            # Each pixel's camera-frame ray (x, y, 1) over its length L, as x / L, y / L, 1 / L.
            x = ((np.arange(intrinsics.width) + 0.5 - intrinsics.cx) / intrinsics.fx)[None, :]
            y = ((np.arange(intrinsics.height) + 0.5 - intrinsics.cy) / intrinsics.fy)[:, None]
            length = np.sqrt(1.0 + x**2 + y**2)
            self._ray_length = length.astype(np.float32)
            self._view = tuple((v / length).astype(np.float32) for v in (x, y, 1.0))

    @staticmethod
    def rays(slew: float, x, y, z, ops) -> np.ndarray:
        """World directions of camera-frame rays ``(x, y, z)`` of the level head slewed by
        ``slew`` (rad)."""
        xp = ops.xp
        c, s = ops.cos(slew), ops.sin(slew)
        x, y, z = xp.broadcast_arrays(x, y, z)
        return xp.stack((c * x + s * y, s * x - c * y, -z), axis=-1)

    def on_corners(self, field: GlintField, truth: dict, seen: list,
                   rng: np.random.Generator, ops) -> tuple[list, list, dict]:
        """``features``: which corners a glint takes this frame (4 uniforms a corner, always).

        A corner's mean glint count is that of the water within
        ``detector_radius`` px of it (the hull's waterline footprint and the
        image's border cut the disc). A glint there is drawn with that
        probability, placed by the means; the corner is then lost if the
        glint's bloom covers it, otherwise reported at the glint.

        Args:
            field: the episode's glint field.
            truth: the task's truth (``q``, ``pixels``, ``level``, ``position``,
                ``hull_axis``, ``cameras``).
            seen: the corners visible (left A1-A3, right A1-A3).
            rng: the episode's generator.
            ops: the backend of :mod:`auv_envs.core.ops` (Python floats and NumPy, or
                JAX: then every corner's glint is worked out and selected).

        Returns:
            ``(pixels, seen, frame)``: the 12 pixel coordinates to report (true
            or glint), the corners still seen, and the frame's outcome
            (``glint_corners``: 0 clear, 1 moved, 2 hidden; ``glint_probability``).
        """
        xp = ops.xp
        draws = rng.random((6, 4))
        intr = self._intrinsics
        true_pixels = xp.asarray(truth["pixels"]).reshape(6, 2)
        points = true_pixels[:, None, :] + self._disc  # (6, M, 2)
        rays = self.rays(truth["q"][0], (points[..., 0] - intr.cx) / intr.fx,
                         (points[..., 1] - intr.cy) / intr.fy, 1.0, ops)
        level = truth["level"]
        (px, py, _), (ax, ay, _) = truth["position"], truth["hull_axis"]
        norm = ops.hypot(ax, ay)
        ax, ay = ax / norm, ay / norm
        half = self._hull_half
        blocks = []
        for k, camera in enumerate(truth["cameras"]):
            camera_rays = rays[3 * k:3 * k + 3]
            height = camera[2] - level
            means = field.pixel_means(camera_rays, height, intr.fx, xp)
            # Where each ray meets the water: outside the hull's footprint?
            dx = camera[0] + height * camera_rays[..., 0] - px
            dy = camera[1] + height * camera_rays[..., 1] - py
            along = xp.clip(dx * ax + dy * ay, -half, half)
            blocks.append(means * (xp.hypot(dx - along * ax, dy - along * ay) > self._waterline))
        means = xp.concatenate(blocks) * (
            (points[..., 0] >= 0.0) & (points[..., 0] < intr.width)
            & (points[..., 1] >= 0.0) & (points[..., 1] < intr.height))
        means = xp.where(xp.asarray(seen)[:, None], means, 0.0)
        total = means.sum(axis=1)
        probability = -xp.expm1(-total)
        state = [0] * 6
        pixels = list(truth["pixels"])
        seen = list(seen)
        reach = self.glint.bloom + 0.5
        glinted = draws[:, 0] < probability
        for k in range(6):
            if ops is FLOATS and not glinted[k]:
                continue  # numbers known: only a glinted corner is worked out
            cumulative = xp.cumsum(means[k])
            pick = xp.minimum(xp.searchsorted(cumulative, draws[k, 1] * cumulative[-1],
                                              side="right"), cumulative.shape[0] - 1)
            u, v = ops.unpack(points[k, pick] + draws[k, 2:] - 0.5)
            hidden = ops.hypot(u - pixels[2 * k], v - pixels[2 * k + 1]) <= reach
            moved = glinted[k] & ops.logical_not(hidden)
            state[k] = ops.where(glinted[k], ops.where(hidden, 2, 1), 0)
            seen[k] = seen[k] & ops.logical_not(glinted[k] & hidden)
            pixels[2 * k] = ops.where(moved, u, pixels[2 * k])
            pixels[2 * k + 1] = ops.where(moved, v, pixels[2 * k + 1])
        frame = {
            "glint_corners": xp.asarray(state, dtype=xp.int8).reshape(2, 3),
            "glint_probability": probability.reshape(2, 3),
        }
        return pixels, seen, frame

    def on_pair(self, field: GlintField, truth: dict, pair: np.ndarray, ranges: np.ndarray,
                rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        """``stereo``: the rendered pair (modified in place) with the frame's glints
        saturated on the water, and the frame's outcome.

        Each pixel that shows the water (its rendered range ``ranges`` is the
        water plane's) holds a glint with probability ``1 - exp(-mean)``
        (``GlintField.pixel_means``; one uniform a pixel); a glint saturates
        the pixels within ``bloom`` px of it.
        """
        h, w = self._ray_length.shape
        level = truth["level"]
        state = np.zeros((2, 3), dtype=np.int8)
        spots_in_view, expected = [0, 0], [0.0, 0.0]
        radius2 = self.glint.detector_radius ** 2
        # The head is level: both cameras look along the same rays from the same height;
        # a pixel's footprint on the water is (height / f)^2 (GlintField.pixel_means,
        # d_z = -1), and the density wants the unit direction back towards the camera.
        height = truth["cameras"][0][2] - level
        rays = self.rays(truth["q"][0], *self._view, FLOATS)
        means_both = field.density(-rays[..., 0], -rays[..., 1], -rays[..., 2], np)
        means_both *= (height / self._intrinsics.fx) ** 2
        water_range = height * self._ray_length
        for k in range(2):
            water = np.abs(ranges[:, k * w:(k + 1) * w] - water_range) < GLINT_WATER_TOLERANCE
            means = means_both * water
            glints = rng.random((h, w), dtype=np.float32) < -np.expm1(-means)
            saturated = np.zeros((h, w), dtype=bool)
            for i, j in self._bloom:  # the bloom: each glint shifted by (i, j)
                saturated[max(i, 0):h + min(i, 0), max(j, 0):w + min(j, 0)] |= (
                    glints[max(-i, 0):h - max(i, 0), max(-j, 0):w - max(j, 0)])
            pair[:, k * w:(k + 1) * w][saturated] = 255
            rows, cols = np.nonzero(glints)
            spots_in_view[k], expected[k] = int(rows.size), float(means.sum())
            for j, seen in enumerate(truth["visible"][k]):
                if not seen:
                    continue
                u, v = truth["pixels"][6 * k + 2 * j:6 * k + 2 * j + 2]
                if saturated[int(v), int(u)]:
                    state[k, j] = 2
                elif np.any((cols + 0.5 - u) ** 2 + (rows + 0.5 - v) ** 2 <= radius2):
                    state[k, j] = 1
        frame = {
            "glint_corners": state,
            "glints_in_view": np.array(spots_in_view),
            "glint_expected": np.array(expected),
        }
        return pair, frame
