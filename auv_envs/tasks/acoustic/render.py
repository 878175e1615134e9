"""A readable picture of the acoustic tracking tank (``AcousticTrackingTask.render_frame``).

:class:`TankPlot` draws one RGB frame with matplotlib's object API on an Agg
canvas (no pyplot, no window, no global state): a top view (x-y) of the tank
above a side view (x-z, depth stretched) with the eight hydrophone nodes, the
work area, the end effector's recent path, the agent's estimate and the
current sample period's real detections, each a 3-D ray from its node along
its azimuth and elevation, drawn until it leaves the water and coloured by
origin; and a close-up of the last seconds around the end effector at the
scale of the tracking error. The figure and its artists are built once;
each frame only updates their data and redraws them over a cached background
(blitting). The few changing numbers are pasted from glyphs rendered once
(:class:`_GlyphStamp`), since matplotlib's text drawing would cost more than
the rest of the frame.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Rectangle
from matplotlib.transforms import IdentityTransform

from auv_envs.core.acoustics import (
    ORIGIN_BOTTOM,
    ORIGIN_CLUTTER,
    ORIGIN_SURFACE,
    ORIGIN_TARGET,
)

#: Colours of the detection rays by ``detection_origin`` code, and their legend labels.
ORIGIN_STYLE = {
    ORIGIN_TARGET: ("#1a9e3f", "source (direct path)"),
    ORIGIN_SURFACE: ("#3d7fd9", "surface ghost"),
    ORIGIN_BOTTOM: ("#d9822b", "bottom ghost"),
    ORIGIN_CLUTTER: ("#9a9a9a", "false alarm"),
}
TRUTH_COLOUR = "#111111"
ESTIMATE_COLOUR = "#d62728"
NODE_COLOUR = "#5b2a86"
#: The layout is drawn for this frame size; other sizes scale it (fonts and lines too).
REFERENCE_SIZE = (640, 480)
#: The smallest scale drawn directly; smaller frames are drawn at it and shrunk.
MIN_SCALE = 0.25


def _rgba(colour: str, alpha: float) -> np.ndarray:
    colour = colour.lstrip("#")
    return np.array([int(colour[i : i + 2], 16) / 255.0 for i in (0, 2, 4)] + [alpha])


class _GlyphStamp:
    """Text in a monospace font, pasted into frames from glyphs that Agg rendered once.

    Matplotlib lays out and rasterises every glyph of a ``Text`` on each draw; the
    numbers of a frame would cost more than its plot. The printable ASCII glyphs are
    drawn once on a scratch canvas at the frame's dpi, kept as coverage masks and
    alpha-blended with NumPy. At integer pixel positions a string looks as matplotlib
    would draw it.
    """

    _CHARS = "".join(chr(i) for i in range(32, 127))

    def __init__(self, dpi: float, size: float, weight: str = "normal"):
        prop = FontProperties(family="monospace", size=size, weight=weight)
        scratch = Figure(dpi=dpi)
        canvas = FigureCanvasAgg(scratch)
        width, height, descent = canvas.get_renderer().get_text_width_height_descent(
            "0" * 20, prop, ismath=False)
        self.advance = width / 20.0
        pad = 2
        self._pad = pad
        cell_w = int(math.ceil(self.advance)) + 2 * pad
        cell_h = int(math.ceil(height)) + 2 * pad
        baseline = pad + int(math.ceil(descent))  # pixels above the cell's bottom
        n = len(self._CHARS)
        scratch.set_size_inches((n + 1) * cell_w / dpi, (cell_h + 1) / dpi)
        for i, char in enumerate(self._CHARS):
            scratch.text(i * cell_w + pad, baseline, char, fontproperties=prop,
                         color="black", va="baseline", transform=IdentityTransform())
        canvas.draw()
        grey = np.asarray(canvas.buffer_rgba())[..., 0].astype(np.float32)
        rows = grey.shape[0]
        coverage = 1.0 - grey[rows - cell_h :] / 255.0  # the bottom cell_h rows
        self._masks = np.stack([coverage[:, i * cell_w : (i + 1) * cell_w] for i in range(n)])
        self._baseline_row = cell_h - baseline  # the baseline's row within a cell
        self._index = {char: i for i, char in enumerate(self._CHARS)}
        scratch.clear()

    def paste(self, frame: np.ndarray, text: str, x: float, baseline: float, colour,
              align: str = "left") -> None:
        """Blend ``text`` into ``frame`` (H, W, 3 uint8) with its baseline at row ``baseline``.

        ``x`` is the left end (``align="left"``) or the right end (``"right"``),
        in pixels; what falls outside the frame is cut off.
        """
        if not text:
            return
        masks, pad = self._masks, self._pad
        cell_h, cell_w = masks.shape[1:]
        offsets = [round(k * self.advance) for k in range(len(text))]
        coverage = np.zeros((cell_h, offsets[-1] + cell_w), dtype=np.float32)
        for offset, char in zip(offsets, text, strict=True):
            cell = coverage[:, offset : offset + cell_w]
            np.maximum(cell, masks[self._index.get(char, self._index["?"])], out=cell)
        left = round(x) - pad - (round(len(text) * self.advance) if align == "right" else 0)
        top = round(baseline) - self._baseline_row
        y0, x0 = max(top, 0), max(left, 0)
        y1 = min(top + cell_h, frame.shape[0])
        x1 = min(left + coverage.shape[1], frame.shape[1])
        if y1 <= y0 or x1 <= x0:
            return
        alpha = coverage[y0 - top : y1 - top, x0 - left : x1 - left, None]
        region = frame[y0:y1, x0:x1]
        region[...] = (region * (1.0 - alpha) + np.asarray(colour) * alpha + 0.5).astype(np.uint8)


class TankPlot:
    """Draws the acoustic tank as an RGB frame; build once, call :meth:`frame` per step.

    Args:
      calibration: the env's :class:`~auv_envs.tasks.acoustic.env.AcousticCalibration`
        (node positions, tank size and depth, work area).
      size: (width, height) of the frames in pixels.
      ray_length: the longest ray (m) drawn from a node (default: the tank's
        diagonal); a ray also ends where it leaves the water (wall, surface,
        bottom), so the source's rays meet at it and a ghost's ray ends at its
        reflection point.
      track_gate: radius (m) of the circle drawn around the source in the close-up.
      closeup_half_width: half the side (m) of the close-up window.
      trail_seconds, closeup_seconds: what the labels say the trails cover (the
        caller chooses what it passes to :meth:`frame`).
    """

    def __init__(self, calibration, size=REFERENCE_SIZE, ray_length: float | None = None,
                 track_gate: float = 1.0, closeup_half_width: float = 5.0,
                 trail_seconds: float = 10.0, closeup_seconds: float = 2.0):
        self.width, self.height = (int(v) for v in size)
        # Frames smaller than MIN_SCALE of the reference are drawn at that scale and
        # shrunk (FreeType cannot draw fonts a pixel or two high).
        ref_w, ref_h = REFERENCE_SIZE
        grow = max(1.0, MIN_SCALE / min(self.width / ref_w, self.height / ref_h))
        self._draw_size = (math.ceil(self.width * grow), math.ceil(self.height * grow))
        self.closeup = float(closeup_half_width)
        self.trail_seconds = float(trail_seconds)
        self.closeup_seconds = float(closeup_seconds)
        size_x, size_y = calibration.tank_size
        if ray_length is None:  # across the whole tank, so that the source's rays meet
            ray_length = float(np.linalg.norm([size_x, size_y, calibration.tank_depth]))
        self.ray_length = float(ray_length)
        self._nodes = np.asarray(calibration.hydrophone_positions, dtype=np.float64)
        self._tank = (float(size_x), float(size_y), float(calibration.tank_depth))
        self._box_low = np.array([0.0, 0.0, -self._tank[2]])
        self._box_high = np.array([self._tank[0], self._tank[1], 0.0])
        colours = np.zeros((5, 4))  # index origin + 1: padding (transparent), then the codes
        for code, (colour, _) in ORIGIN_STYLE.items():
            colours[code + 1] = _rgba(colour, 0.45)
        self._origin_colours = colours
        self._build(calibration.work_area, track_gate)

    # ------------------------------------------------------------------ layout
    def _build(self, work_area, track_gate: float) -> None:
        ref_w, ref_h = REFERENCE_SIZE
        draw_w, draw_h = self._draw_size
        scale = min(draw_w / ref_w, draw_h / ref_h)
        dpi = 100.0 * scale
        fig = Figure(figsize=(draw_w / dpi, draw_h / dpi), dpi=dpi, facecolor="white")
        self.figure = fig
        self.canvas = canvas = FigureCanvasAgg(fig)
        # Layout in reference pixels (y up) of a 640x480 block, centred in the
        # frame scaled so that the block just fits.
        full_w, full_h = draw_w / scale, draw_h / scale
        ox, oy = (full_w - ref_w) / 2.0, (full_h - ref_h) / 2.0

        def fx(x):  # block x -> figure fraction
            return (x + ox) / full_w

        def fy(y):
            return (y + oy) / full_h

        def rect(x, y, w, h):
            return [fx(x), fy(y), w / full_w, h / full_h]

        def pixel(x, y):  # block -> frame pixels (from the top)
            return (x + ox) * scale, draw_h - (y + oy) * scale

        fh = float(ref_h)
        left, top, bottom, gap = 46.0, 34.0, 36.0, 20.0
        side_h = 80.0
        a = fh - top - bottom - side_h - gap  # the top view's side: 310
        size_x, size_y, depth = self._tank

        top_ax = fig.add_axes(rect(left, bottom + side_h + gap, a, a))
        side_ax = fig.add_axes(rect(left, bottom, a, side_h), sharex=top_ax)
        x0 = left + a + 50.0  # the close-up's left edge
        text_x = x0 - 38.0  # the column's text, aligned with the close-up's y label
        c = 140.0
        close_ax = fig.add_axes(rect(x0, fh - top - c, c, c))
        self._axes = (top_ax, side_ax, close_ax)

        font = 8
        for ax in self._axes:
            ax.tick_params(labelsize=font - 1, length=3, pad=2)
        margin = 16.0  # room for the node numbers outside the walls
        top_ax.set_xlim(-margin, size_x + margin)
        top_ax.set_ylim(-margin, size_y + margin)
        top_ax.set_aspect("equal", adjustable="box", anchor="SW")
        top_ax.set_ylabel("y (m)", fontsize=font, labelpad=1)
        top_ax.tick_params(labelbottom=False)
        top_ax.set_title("top view (x-y)", fontsize=font, loc="left", pad=2)
        side_ax.set_ylim(-depth - 2.0, 2.0)
        side_ax.set_xlabel("x (m)", fontsize=font, labelpad=1)
        side_ax.set_ylabel("z (m)", fontsize=font, labelpad=1)
        side_ax.set_yticks([0.0, -depth / 2.0, -depth])
        side_ax.set_title("side view (x-z), depth stretched", fontsize=font,
                          loc="left", pad=2)
        h = self.closeup
        close_ax.set_xlim(-h, h)
        close_ax.set_ylim(-h, h)
        close_ax.set_aspect("equal", adjustable="box", anchor="NW")
        close_ax.set_title(f"close-up, last {self.closeup_seconds:g} s", fontsize=font,
                           loc="left", pad=2)
        close_ax.set_xlabel("x - x_true (m)", fontsize=font, labelpad=1)
        close_ax.set_ylabel("y - y_true (m)", fontsize=font, labelpad=1)
        close_ax.grid(True, lw=0.4, color="#dddddd")

        # Static scenery: tank walls, water column, work area, nodes.
        (wl, wl_y, wl_z), (wh, wh_y, wh_z) = work_area
        top_ax.add_patch(Rectangle((0, 0), size_x, size_y, fill=True, fc="#eef5fb",
                                   ec="#333333", lw=1.0, zorder=0))
        top_ax.add_patch(Rectangle((wl, wl_y), wh - wl, wh_y - wl_y, fill=False, ec="#888888",
                                   lw=0.8, ls="--", zorder=1))
        side_ax.add_patch(Rectangle((0, -depth), size_x, depth, fill=True, fc="#eef5fb",
                                    ec="#333333", lw=1.0, zorder=0))
        side_ax.axhline(0.0, color="#3d7fd9", lw=1.0, zorder=1)
        side_ax.axhline(-depth, color="#7a5c3a", lw=1.6, zorder=1)
        side_ax.add_patch(Rectangle((wl, wl_z), wh - wl, wh_z - wl_z, fill=False, ec="#888888",
                                    lw=0.8, ls="--", zorder=1))
        nodes = self._nodes
        # The node markers are redrawn over the rays every frame (see below); their
        # numbers sit just outside the wall each node is on, where no ray reaches.
        for n, p in enumerate(nodes, start=1):
            at = p[:2].copy()
            for axis, extent in enumerate((size_x, size_y)):
                if at[axis] < 0.1 * extent:
                    at[axis] = -0.55 * margin
                elif at[axis] > 0.9 * extent:
                    at[axis] = extent + 0.55 * margin
            top_ax.text(at[0], at[1], str(n), fontsize=font - 1, color=NODE_COLOUR,
                        ha="center", va="center", zorder=6, weight="bold")
        close_ax.add_patch(Circle((0, 0), track_gate, fill=False, ec="#1a9e3f", lw=0.9, ls=":"))
        close_ax.plot([0.0], [0.0], marker="o", ms=5, color=TRUTH_COLOUR, zorder=5)

        # Dynamic artists: redrawn over the cached background every frame.
        def line(ax, **style):
            (artist,) = ax.plot([], [], animated=True, **style)
            return artist

        def rays(ax):
            collection = LineCollection([], linewidths=0.7, animated=True, zorder=2)
            ax.add_collection(collection)
            return collection

        truth_style = dict(color=TRUTH_COLOUR, lw=1.2, zorder=4)
        dot = dict(ls="none", marker="o", ms=5, color=TRUTH_COLOUR, zorder=7)
        cross = dict(ls="none", marker="X", ms=7, mfc=ESTIMATE_COLOUR, mec="white", mew=0.6,
                     zorder=8)
        error = dict(color=ESTIMATE_COLOUR, lw=0.9, zorder=6)
        self._rays = (rays(top_ax), rays(side_ax))
        self._trail = (line(top_ax, **truth_style), line(side_ax, **truth_style),
                       line(close_ax, **truth_style))
        self._truth = (line(top_ax, **dot), line(side_ax, **dot))
        self._error = (line(top_ax, **error), line(side_ax, **error), line(close_ax, **error))
        self._estimate = (line(top_ax, **cross), line(side_ax, **cross),
                          line(close_ax, **cross))
        self._estimate_trail = line(close_ax, ls="none", marker=".", ms=2.5,
                                    color=ESTIMATE_COLOUR, alpha=0.6, zorder=3)
        node_style = dict(ls="none", marker="^", ms=6, mfc=NODE_COLOUR, mec="white", mew=0.6)
        self._node_markers = (line(top_ax, **node_style), line(side_ax, **node_style))
        self._node_markers[0].set_data(nodes[:, 0], nodes[:, 1])
        self._node_markers[1].set_data(nodes[:, 0], nodes[:, 2])

        # Text: the labels go into the background; the changing values are pasted.
        title_base = fh - 20.0
        title = fig.text(fx(left), fy(title_base), "Acoustic tracking", fontsize=font + 3,
                         va="baseline", weight="bold")
        canvas.draw()  # to measure the title
        title_end = title.get_window_extent().x1 / scale - ox
        self._title_stamp = _GlyphStamp(dpi, font + 1)
        self._title_at = pixel(title_end + 14.0, title_base)
        handles = [
            Line2D([], [], ls="none", marker="^", ms=6, mfc=NODE_COLOUR, mec="white",
                   label="hydrophone node"),
            Line2D([], [], color=TRUTH_COLOUR, marker="o", ms=4, lw=1.2,
                   label=f"end effector, last {self.trail_seconds:g} s"),
            Line2D([], [], ls="none", marker="X", ms=7, mfc=ESTIMATE_COLOUR, mec="white",
                   label="estimate (last action)"),
            Line2D([], [], color="#888888", lw=0.8, ls="--", label="work area"),
            Line2D([], [], color="#1a9e3f", lw=0.9, ls=":", label=f"{track_gate:g} m track gate"),
        ]
        legend_top = fh - top - c - 30.0
        fig.legend(handles=handles, loc="upper left", fontsize=font - 1, frameon=False,
                   bbox_to_anchor=(fx(text_x), fy(legend_top)), handlelength=1.8,
                   borderaxespad=0.0, borderpad=0.0, labelspacing=0.3)
        line_h = 11.5
        table_top = legend_top - 5 * line_h - 14.0
        fig.text(fx(text_x), fy(table_top), "rays: this step's detections", fontsize=font - 1,
                 va="baseline", weight="bold")
        labels = [(label, colour) for colour, label in ORIGIN_STYLE.values()]
        labels += [("source depth z", TRUTH_COLOUR), ("estimate error", ESTIMATE_COLOUR),
                   ("running RMSE", TRUTH_COLOUR)]
        self._value_stamp = _GlyphStamp(dpi, font - 1)
        self._value_at = []
        for i, (label, colour) in enumerate(labels):
            y = table_top - line_h * (i + 1 + (i >= len(ORIGIN_STYLE)) * 0.6)
            fig.text(fx(text_x + 8.0), fy(y), label, fontsize=font - 1, va="baseline",
                     color=colour)
            self._value_at.append((*pixel(text_x + 160.0, y), _rgba255(colour)))
        self._background = None

    # ------------------------------------------------------------------ frames
    def ray_segments(self, view: str) -> list:
        """The direction rays drawn in the ``"top"`` or ``"side"`` view of the last
        frame, one (2, 2) segment per node and detection (a ray not drawn keeps only
        its finite vertex)."""
        index = {"top": 0, "side": 1}[view]
        return self._rays[index].get_segments()

    def frame(self, time: float | None = None, trail=None, estimate=None,
              estimate_trail=None, azimuth=None, elevation=None, origin=None,
              error: float = float("nan"), rmse: float = float("nan")) -> np.ndarray:
        """One (H, W, 3) uint8 frame; with no arguments, the empty tank.

        Args:
          time: seconds since reset (None: no episode yet).
          trail: (M, 3) true end-effector positions, oldest first, the last one now.
          estimate: (3,) the agent's latest estimate, or None before the first step.
          estimate_trail: (L, 3) the latest estimates for the close-up (L may be 0),
            the last one ``estimate``; the close-up also shows the truth's last L + 1
            positions.
          azimuth, elevation: (D, N) angles (rad) of this period's real detections.
          origin: (D,) their ``detection_origin`` codes (colour of the rays).
          error: the latest estimate's error (m). rmse: the running RMSE (m).
        """
        canvas = self.canvas
        if self._background is None:
            canvas.draw()
            self._background = canvas.copy_from_bbox(self.figure.bbox)
        canvas.restore_region(self._background)
        empty = np.zeros((0, 3))
        trail = empty if trail is None else np.asarray(trail, dtype=np.float64)
        now = trail[-1] if len(trail) else None

        top_rays, side_rays = self._rays
        counts = np.zeros(5, dtype=int)
        if azimuth is not None and len(azimuth):
            origin = np.asarray(origin, dtype=np.int64)
            order = np.argsort(-origin, kind="stable")  # false alarms below, the source on top
            origin = origin[order]
            az = np.asarray(azimuth, dtype=np.float64)[order]
            el = np.asarray(elevation, dtype=np.float64)[order]
            counts += np.bincount(origin + 1, minlength=5)
            # Each detection is a 3-D ray from its node (azimuth and elevation),
            # drawn until it leaves the water: ghosts' rays end where they meet
            # the surface or the bottom. Both views show its projections.
            sin_el = np.sin(el)
            direction = np.stack([sin_el * np.cos(az), sin_el * np.sin(az), np.cos(el)], -1)
            start = np.broadcast_to(self._nodes, direction.shape)
            with np.errstate(divide="ignore", invalid="ignore"):
                bound = np.where(direction > 0, self._box_high, self._box_low)
                reach = np.where(direction != 0, (bound - start) / direction, np.inf)
            length = np.clip(reach.min(axis=-1, initial=self.ray_length), 0.0, None)
            end = start + direction * length[..., None]
            colours = np.repeat(self._origin_colours[origin + 1], az.shape[1], axis=0)
            top_rays.set_segments(
                np.stack([start[..., :2], end[..., :2]], axis=-2).reshape(-1, 2, 2))
            side_rays.set_segments(
                np.stack([start[..., ::2], end[..., ::2]], axis=-2).reshape(-1, 2, 2))
            top_rays.set_color(colours)
            side_rays.set_color(colours)
        else:
            top_rays.set_segments([])
            side_rays.set_segments([])

        for artist, (i, j) in zip(self._trail[:2], ((0, 1), (0, 2)), strict=True):
            artist.set_data(trail[:, i], trail[:, j])
        for artist, (i, j) in zip(self._truth, ((0, 1), (0, 2)), strict=True):
            artist.set_data(trail[-1:, i], trail[-1:, j])
        close_trail, close_estimates = self._trail[2], self._estimate_trail
        if now is not None:
            est_trail = empty if estimate_trail is None else np.asarray(estimate_trail) - now
            recent = trail[-len(est_trail) - 1 :] - now  # the truth over the same steps
            close_trail.set_data(recent[:, 0], recent[:, 1])
            close_estimates.set_data(est_trail[:, 0], est_trail[:, 1])
        else:
            close_trail.set_data([], [])
            close_estimates.set_data([], [])
        if estimate is not None and now is not None:
            e = np.asarray(estimate, dtype=np.float64)
            views = ((e[0], e[1], now[0], now[1]), (e[0], e[2], now[0], now[2]),
                     (e[0] - now[0], e[1] - now[1], 0.0, 0.0))
            for marker, segment, (u, v, u0, v0) in zip(self._estimate, self._error, views,
                                                       strict=True):
                marker.set_data([u], [v])
                segment.set_data([u0, u], [v0, v])
        else:
            for artist in self._estimate + self._error:
                artist.set_data([], [])

        top_ax, side_ax, close_ax = self._axes
        for ax, artists in (
            (top_ax, (top_rays, self._node_markers[0], self._trail[0], self._error[0],
                      self._truth[0], self._estimate[0])),
            (side_ax, (side_rays, self._node_markers[1], self._trail[1], self._error[1],
                       self._truth[1], self._estimate[1])),
            (close_ax, (close_estimates, self._trail[2], self._error[2], self._estimate[2])),
        ):
            for artist in artists:
                ax.draw_artist(artist)
        rgba = np.asarray(canvas.buffer_rgba())
        draw_w, draw_h = self._draw_size
        if rgba.shape[:2] == (draw_h, draw_w):
            out = cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)  # OpenCV's copy: faster than NumPy's
        else:  # Agg rounded the canvas size: pad or crop to the size asked for
            out = np.full((draw_h, draw_w, 3), 255, dtype=np.uint8)
            h, w = min(draw_h, rgba.shape[0]), min(draw_w, rgba.shape[1])
            out[:h, :w] = rgba[:h, :w, :3]

        if time is None:
            title, values = "no episode yet: call reset()", ()
        else:
            title = f"t = {time:6.2f} s   error = {_metres(error)}"
            values = [str(counts[code + 1]) for code in ORIGIN_STYLE]
            values += [_metres(np.nan if now is None else now[2]), _metres(error),
                       _metres(rmse)]
        self._title_stamp.paste(out, title, *self._title_at, colour=(0, 0, 0))
        for value, (x, y, colour) in zip(values, self._value_at, strict=False):
            self._value_stamp.paste(out, value, x, y, colour, align="right")
        if self._draw_size != (self.width, self.height):
            out = cv2.resize(out, (self.width, self.height), interpolation=cv2.INTER_AREA)
        return out

    # ------------------------------------------------------------------ geometry
    #: The panels, by name, in the order of ``self._axes``.
    PANELS = ("top", "side", "closeup")

    def to_pixel(self, panel: str, points) -> np.ndarray:
        """Frame pixel coordinates (column, row from the top) of data points of a panel.

        ``points`` (..., 2) are (x, y) for ``"top"``, (x, z) for ``"side"`` and
        offsets from the true position (m) for ``"closeup"``.
        """
        ax = self._axes[self.PANELS.index(panel)]
        display = ax.transData.transform(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        draw_w, draw_h = self._draw_size
        pixels = np.stack([display[:, 0] * (self.width / draw_w),
                           (draw_h - display[:, 1]) * (self.height / draw_h)], axis=-1)
        return pixels.reshape(np.shape(points))

    def panel_box(self, panel: str) -> tuple[int, int, int, int]:
        """(left, top, right, bottom) frame pixels of a panel's plotting area."""
        ax = self._axes[self.PANELS.index(panel)]
        box = ax.get_window_extent()
        (left, top), (right, bottom) = self.to_pixel(panel, ax.transData.inverted().transform(
            [[box.x0, box.y1], [box.x1, box.y0]]))
        return round(left), round(top), round(right), round(bottom)

    def close(self) -> None:
        """Release the figure (the object is unusable afterwards)."""
        if self.figure is not None:
            self.figure.clear()
        self.figure = None
        self.canvas = None
        self._background = None


def _rgba255(colour: str) -> np.ndarray:
    return np.round(255.0 * _rgba(colour, 1.0)[:3])


def _metres(value: float) -> str:
    return "-" if not np.isfinite(value) else f"{value:.2f} m"
