"""LTAT as a perception front end: stereo images -> marker corners ([LTAT] §2.1).

:class:`LTATFrontEnd` turns the ``stereo`` observation of
``auv_envs/LARSCapture-v0`` into its ``features`` observation (protocol of
:mod:`baselines.frontend`), so that the ``ckf-pd`` agent can act on images.

**First box, without truth.** Until the marker has been found, every frame
is searched for it by colour in both whole images: each red blob with a
triangular outline is a candidate, candidates of the two views are paired
along the rectified rows, and the pair whose triangulated side lengths match
``calibration.marker_sides`` best (within ``size_tolerance``) is the AUV's
marker -- the look-alike analogs carry a 0.8x marker and fail the check. The
tracker starts on that pair's corner boxes.
"""

from __future__ import annotations

import time

import numpy as np

from baselines.lars.perception.detector import DetectorParams
from baselines.lars.perception.ltat import LTATOutput, LTATParams, LTATracker
from baselines.lars.perception.siamese import (
    Pyramid,
    SiameseTrackerParams,
    load_siamese,
    marker_box,
)
from baselines.lars.perception.stereo import find_marker_pair


class LTATFrontEnd:
    """Stereo images -> ``features`` observation of ``auv_envs/LARSCapture-v0`` ([LTAT] §2.1).

    Front-end protocol of :mod:`baselines.frontend`: ``reset(seed)``,
    ``__call__(observation, info) -> features`` (``pixels`` (2, 3, 2)
    float32, zero where not visible; ``visible`` (2, 3) int8;
    ``joint_position``/``joint_velocity`` passed through), ``stats()``.
    ``info`` is never read. Corners are reported when found in both views
    and verified by :func:`~.stereo.stereo_check` (all three), or, with the marker
    cut by one image's border, those seen in both that pass the row and
    base-length checks (:meth:`LTATracker._partial`).

    Until the marker is first found the front end runs
    :func:`find_marker_pair` on every frame (see the module docstring);
    afterwards :class:`LTATracker`.

    Args:
        calibration: the env's ``LARSCalibration`` (stereo rig, marker sides).
        weights_dir: the Siamese tracker's weights (default: the shipped ones).
    """

    def __init__(self, calibration, weights_dir=None, params: LTATParams | None = None,
                 tracker_params: SiameseTrackerParams | None = None,
                 detector_params: DetectorParams | None = None):
        net, self.weights_meta = load_siamese(weights_dir)
        self.rig = calibration.stereo
        self.marker_sides = tuple(calibration.marker_sides)
        self.params = params or LTATParams()
        self.ltat = LTATracker(net, self.rig, self.marker_sides, tracker_params,
                               detector_params, params=self.params)
        self._size = (self.rig.left.height, self.rig.left.width, 3)
        self.reset(None)

    def reset(self, seed: int | None = None) -> None:
        self.ltat.reset(np.random.default_rng(seed))
        #: The last frame's :class:`LTATOutput` (None before the marker is found).
        self.last_output: LTATOutput | None = None
        self.frames = 0
        self.initialised_at: int | None = None
        self.seconds = 0.0

    def __call__(self, observation, info=None) -> dict:
        start = time.perf_counter()
        keys = ("left", "right", "joint_position", "joint_velocity")
        if not isinstance(observation, dict) or any(k not in observation for k in keys):
            raise ValueError(f"LTATFrontEnd expects the 'stereo' observation dict with keys {keys}")
        left, right = observation["left"], observation["right"]
        for name, image in (("left", left), ("right", right)):
            if image.shape != self._size or image.dtype != np.uint8:
                raise ValueError(f"{name} image must be {self._size} uint8 (the calibration's "
                                 f"size), got {image.shape} {image.dtype}")
        if not self.ltat.started:
            corners = find_marker_pair(self.ltat.extractor, left, right, self.rig,
                                       self.marker_sides, self.params.row_tolerance,
                                       self.params.size_tolerance)
            if corners is not None:
                boxes = np.array([marker_box(corners[v]) for v in range(2)])
                self.ltat.start([Pyramid(left), Pyramid(right)], boxes)
                self.initialised_at = self.frames
                self.last_output = LTATOutput(boxes, np.ones(2), np.zeros(2, bool), corners,
                                              np.ones((2, 3), dtype=bool))
        else:
            self.last_output = self.ltat.step([Pyramid(left), Pyramid(right)], (left, right))
        self.frames += 1
        pixels = np.zeros((2, 3, 2), dtype=np.float32)
        visible = np.zeros((2, 3), dtype=np.int8)
        out = self.last_output
        if out is not None and out.corners is not None:
            pixels[out.visible] = out.corners[out.visible]
            visible[out.visible] = 1
        self.seconds += time.perf_counter() - start
        return {
            "pixels": pixels,
            "visible": visible,
            "joint_position": np.asarray(observation["joint_position"], dtype=np.float32).copy(),
            "joint_velocity": np.asarray(observation["joint_velocity"], dtype=np.float32).copy(),
        }

    def stats(self) -> dict:
        c = self.ltat.counts
        return {
            "ltat_frames": self.frames,
            "ltat_initialised_at": -1 if self.initialised_at is None else self.initialised_at,
            "ltat_verified_frames": c["verified"],
            "ltat_lost_views": c["lost_views"],
            "ltat_redetections": c["redetections"],
            "ltat_stereo_transfers": c["transfers"],
            "ltat_partial_frames": c["partial"],
            "ltat_detector_fits": self.ltat.detector.fits,
            "ltat_ms_per_frame": 1e3 * self.seconds / max(self.frames, 1),
        }
