"""[LAMP]'s lamp tracker as a front end: an image of guide lamps -> labelled pixel tracks.

The pipeline follows [LAMP] §2 (Zhang et al., "Monocular vision guided lamp array tracking
method for the UUV recovery process", J. Unmanned Undersea Systems 29(4), 2021); this module
composes its parts, each in its own module:

1. **Improved adaptive thresholding** (§2.1.2): a classic local-mean adaptive threshold
   pre-segments the frame into foreground regions (BLOB analysis); each region then gets its own
   threshold (Otsu's, [LAMP] ref. [9]) inside its bounding box; morphological closing, opening
   and hole filling smooth the lamp silhouettes
   (:func:`~baselines.docking.perception.segmentation.segment_lamps`).
2. **Blob analysis** (§2.1.1, §2.2.3 1)): centre, area and bounding box of each lamp blob
   (:class:`~baselines.docking.perception.segmentation.Blobs`).
3. **Identity at initialisation** (§2.2.2): when every lamp is detected, the lamps are labelled by
   geometry: for the L-shaped array A, B, C, D by the shape of the L
   (:func:`~baselines.docking.perception.identity.identify_l_shape`: [LAMP] uses edge
   lengths; we use the line A-B-C, B between A and C, and the side D is on, which a perspective
   view keeps); for a convex ring such as the six symmetric docking lights by their cyclic order
   and the fit of the rigid array with the INS attitude
   (:func:`~baselines.docking.perception.identity.ring_labelings`, our documented rule; four of
   the six lights suffice).
4. **One EKF per lamp on its blob features** (§2.2.3 1)):
   :class:`~baselines.docking.perception.lamp_tracking.BlobEKF`.
5. **Cost matrix with the array's rigid-body information + Hungarian assignment** (§2.2.3 2)):
   the EKF prediction of each lamp is weighed with the lamp's position predicted by the rigid
   array (:class:`~baselines.docking.estimation.camera_position.CameraPositionFilter`);
   detections are assigned with ``scipy.optimize.linear_sum_assignment`` under a gate.
6. **Corrected tracks** (§2.2.3 steps 3-4): matched lamps are corrected by their detection;
   lamps out of view (or occluded) keep a prediction ([LAMP] Fig. 10 b, d).

Our choices where [LAMP] is silent, each measured on this package's renders (the blob centre
and the rigid-array observer are explained in their modules):

* A lamp is reported visible only when its centre is: the pixels where the rest of the array
  puts the centre must be lit. A lamp half hidden by the fork or the image border leaves a
  blob whose circle is biased; the env, too, calls a lamp visible when the line of sight to
  its centre is clear.
* Lamps whose blobs merge (overlapping in the image) are reported where the array, fitted to
  the merged blob through the mean of its members' projections, puts them.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from auv_envs.core.camera import pixel_space
from auv_envs.core.frames import rotation_from_euler
from baselines.docking.estimation.camera_position import CameraPositionFilter
from baselines.docking.perception.identity import identify_l_shape, ring_labelings
from baselines.docking.perception.lamp_tracking import (
    DETECTED,
    MERGED,
    PREDICTED,
    UNINITIALISED,
    BlobEKF,
    LampTrackerParams,
    LampTracks,
)
from baselines.docking.perception.segmentation import Blobs, SegmentationParams, segment_lamps

#: A disc cut by a straight edge (an occluder, the image border) keeps its centre iff more than
#: half of it is left, which is then also its enclosing circle's share: the least fill of a
#: blob whose centre is trusted.
MIN_FILL = 0.5
#: Noise scale of the centre of a blob cut by the image border (its circle may be biased).
BORDER_SIGMA_SCALE = 4.0


class LampArrayFrontEnd:
    """[LAMP]'s lamp tracker as a front end (see :mod:`baselines.frontend`).

    ``front_end(observation, info)`` turns an ``image`` observation of a docking env into its
    ``features`` observation: ``pixels`` (n, 2) float32 (zero where not visible), ``visible``
    (n,) int8, ``velocity`` and ``attitude`` passed through. A lamp is reported visible when it
    was detected in this frame (alone or inside a merged blob), at its corrected position.
    Predictions of the other lamps are in :attr:`tracks`. ``info`` is never read: the front end
    sees only the observation and the calibration.

    Args:
        calibration: the env's ``calibration`` (intrinsics, extrinsics, light positions and
            labels, control period).
        identity: ``"l-shape"`` (lamps A, B, C, D of [LAMP]), ``"ring"`` (a convex planar
            array seen from the front) or ``"auto"`` (l-shape for labels A, B, C, D, else ring).
        segmentation: :class:`SegmentationParams`.
        tracking: :class:`LampTrackerParams`.
    """

    def __init__(self, calibration, identity: str = "auto",
                 segmentation: SegmentationParams | None = None,
                 tracking: LampTrackerParams | None = None):
        labels = tuple(calibration.light_labels)
        if identity == "auto":
            identity = "l-shape" if labels == ("A", "B", "C", "D") else "ring"
        if identity not in ("l-shape", "ring"):
            raise ValueError(f"unknown identity rule {identity!r}; valid: 'auto', 'l-shape', "
                             "'ring'")
        if identity == "l-shape" and len(labels) != 4:
            raise ValueError("the l-shape identity rule needs four lamps")
        self.identity = identity
        self.labels = labels
        self.intrinsics = calibration.intrinsics
        self.segmentation = segmentation or SegmentationParams()
        self.params = tracking or LampTrackerParams()
        self._points = np.array(calibration.light_positions, dtype=float)
        self._cam_rot_body = np.array(calibration.extrinsics.rotation, dtype=float)
        self._cam_pos_body = np.array(calibration.extrinsics.position, dtype=float)
        self._dt = float(calibration.control_period)
        self._n = len(labels)
        self._image_shape = (self.intrinsics.height, self.intrinsics.width, 3)
        # The bounds of the env's features ``pixels`` space, which the output must lie in.
        pixels = pixel_space(self.intrinsics.width, self.intrinsics.height, (self._n,))
        self._pixel_bounds = (pixels.low, pixels.high)
        self._pose = CameraPositionFilter(self.intrinsics, self._points)
        self._transition = BlobEKF.transition(self._dt, self.params.accel_sigma,
                                              self.params.size_accel_sigma)
        # Sensor noise of the scenario (calibration) on top of the model's own allowances.
        self._attitude_sigma = float(calibration.attitude_noise_std)
        self._displacement_sigma = self._dt * math.hypot(self.params.velocity_sigma,
                                                         calibration.velocity_noise_std)
        self.reset()

    @classmethod
    def from_env(cls, env, **kwargs) -> LampArrayFrontEnd:
        """Front end for a docking env in ``image`` mode (wrapped or not)."""
        env = getattr(env, "unwrapped", env)
        if getattr(env, "obs_mode", None) != "image":
            raise ValueError("the lamp-array front end needs an env with obs_mode='image'")
        return cls(env.calibration, **kwargs)

    # ------------------------------------------------------------------ protocol
    def reset(self, seed: int | None = None) -> None:
        del seed  # deterministic
        self._tracks: list[BlobEKF] | None = None
        self._status = np.full(self._n, UNINITIALISED)
        self._prev_motion: tuple[np.ndarray, np.ndarray] | None = None  # body rot, velocity
        self._frames_without_detection = 0
        self._counts = {"frames": 0, "initialisations": 0, "track_losses": 0,
                        "detected": 0, "merged": 0, "predicted": 0}

    def __call__(self, observation, info: dict | None = None) -> dict:
        del info  # never read: no ground truth in the front end
        image, velocity, attitude = self._check_observation(observation)
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        blobs = segment_lamps(gray, self.segmentation)
        body_rot = rotation_from_euler(*attitude, np)
        self._pose.set_rotation(body_rot @ self._cam_rot_body, self._attitude_sigma)
        world_velocity = body_rot @ velocity[:3]
        if self._tracks is None:
            self._initialise(gray, blobs)
        else:
            self._track(gray, blobs, self._camera_displacement(body_rot, world_velocity))
        self._prev_motion = (body_rot, world_velocity)
        self._count()
        return self._features(velocity, attitude)

    def stats(self) -> dict:
        """Counts over the episode: frames, initialisations, track losses, and the fraction of
        initialised lamp-frames that were detected, merged or only predicted."""
        c = self._counts
        lamp_frames = max(c["detected"] + c["merged"] + c["predicted"], 1)
        return {
            "lamp_frames": c["frames"],
            "lamp_initialisations": c["initialisations"],
            "lamp_track_losses": c["track_losses"],
            "lamp_detected_fraction": c["detected"] / lamp_frames,
            "lamp_merged_fraction": c["merged"] / lamp_frames,
            "lamp_predicted_fraction": c["predicted"] / lamp_frames,
        }

    @property
    def initialised(self) -> bool:
        return self._tracks is not None

    @property
    def tracks(self) -> LampTracks:
        """Every lamp's corrected position or prediction after the last frame."""
        if self._tracks is None:
            nan = np.full((self._n, 2), np.nan)
            return LampTracks(self.labels, nan, np.full(self._n, np.nan), self._status.copy())
        pixels = np.array([t.position for t in self._tracks])
        front = self._pose.project()[3]
        pixels[~front] = np.nan
        radii = np.array([t.x[4] for t in self._tracks])
        return LampTracks(self.labels, pixels, radii, self._status.copy())

    # ------------------------------------------------------------------ steps
    def _check_observation(self, observation):
        if not isinstance(observation, dict):
            raise TypeError(f"observation must be a dict (image obs mode), got "
                            f"{type(observation).__name__}")
        missing = {"image", "velocity", "attitude"} - set(observation)
        if missing:
            raise KeyError(f"observation lacks {sorted(missing)}; the lamp-array front end "
                           "needs the image obs mode")
        image = observation["image"]
        if (not isinstance(image, np.ndarray) or image.dtype != np.uint8
                or image.shape != self._image_shape):
            raise ValueError(f"image must be a uint8 array of shape {self._image_shape} (the "
                             f"calibration's size), got "
                             f"{getattr(image, 'dtype', None)} {np.shape(image)}")
        velocity = np.asarray(observation["velocity"], dtype=float)
        attitude = np.asarray(observation["attitude"], dtype=float)
        if velocity.shape != (4,) or attitude.shape != (3,):
            raise ValueError(f"velocity must be (4,) and attitude (3,), got {velocity.shape} "
                             f"and {attitude.shape}")
        if not (np.isfinite(velocity).all() and np.isfinite(attitude).all()):
            raise ValueError("velocity and attitude must be finite")
        return image, velocity, attitude

    def _initialise(self, gray: np.ndarray, blobs: Blobs) -> None:
        """Label the lamps once enough are detected, alone and whole ([LAMP] §2.2.1-2.2.2):
        all four of the L-shaped array, at least ``ring_init_min`` lights of a ring."""
        p = self.params
        k = len(blobs)
        need = self._n if self.identity == "l-shape" else min(p.ring_init_min, self._n)
        if not need <= k <= self._n or blobs.on_border.any():
            return
        if ((blobs.fill < MIN_FILL).any()
                or not all(self._centre_is_bright(gray, c) for c in blobs.centres)):
            return  # a lamp is partly hidden: its centre is not reliable yet
        if self.identity == "l-shape":
            order = identify_l_shape(blobs.centres, self._points)
            labels = None if order is None else np.argsort(order)
        else:
            labels = self._identify_ring(blobs.centres)
        if labels is None:
            return
        residual = self._pose.initialise(labels, blobs.centres, p.pixel_sigma)
        if not residual <= p.init_max_residual:
            return  # the labelled array does not fit the rigid layout: wait for a better frame
        # The lamps are identical ([LAMP] §1.2), so radius x depth is the same for all; a
        # blob much smaller than its depth allows is a lamp partly hidden.
        depth = (self._points[labels] - self._pose.t) @ self._pose.world_to_cam[2]
        size = blobs.radii * depth
        if size.max() > 1.3 * size.min():
            return
        projected, _, _, _ = self._pose.project()
        typical_radius = float(np.median(blobs.radii))
        detected = np.full(self._n, -1)
        detected[labels] = np.arange(k)
        self._tracks = []
        for i in range(self._n):
            j = detected[i]
            if j >= 0:  # from its blob
                x0, var = [*blobs.centres[j], 0.0, 0.0, blobs.radii[j], 0.0], 1.0
            else:  # not seen: where the array puts it
                x0, var = [*projected[i], 0.0, 0.0, typical_radius, 0.0], 25.0
            p0 = np.diag([var, var, 100.0**2, 100.0**2, 1.0, 10.0**2])
            self._tracks.append(BlobEKF(x0, p0))
        self._status = np.where(detected >= 0, DETECTED, PREDICTED)
        self._frames_without_detection = 0
        self._counts["initialisations"] += 1

    def _identify_ring(self, centres: np.ndarray) -> np.ndarray | None:
        """The :func:`ring_labelings` candidate that best fits the rigid array with the
        measured attitude, if it fits (RMS <= ``init_max_residual`` px) and no other comes
        close (the runner-up must be twice as far off, and 2 px farther)."""
        centre = self._points.mean(axis=0)
        # The lights' cyclic order in the image, as seen from 5 m in front of them (DS -x).
        view, _, _, front = self._pose.project(centre - np.array([5.0, 0.0, 0.0]))
        if not front.all():
            return None  # turned away from the station: no nominal view to order them by
        rel = view - view.mean(axis=0)
        ring_order = np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))
        scored = []
        for labels in ring_labelings(centres, ring_order):
            scored.append((self._pose.fit_residual(labels, centres), labels))
        scored.sort(key=lambda item: item[0])
        best = scored[0][0]
        runner_up = scored[1][0] if len(scored) > 1 else math.inf
        if best > self.params.init_max_residual or runner_up < max(2.0 * best, best + 2.0):
            return None
        return scored[0][1]

    def _camera_displacement(self, body_rot: np.ndarray, world_velocity: np.ndarray):
        """Camera motion since the last frame: the DVL velocity (trapezoidal rule) moves the
        body, the change of INS attitude swings the camera about it."""
        prev_rot, prev_velocity = self._prev_motion
        return (0.5 * (prev_velocity + world_velocity) * self._dt
                + (body_rot - prev_rot) @ self._cam_pos_body)

    def _track(self, gray: np.ndarray, blobs: Blobs, displacement: np.ndarray) -> None:
        p = self.params
        pose = self._pose
        pose.predict(displacement, self._displacement_sigma)
        rigid, jac_t, jac_theta, front = pose.project()
        rigid_cov = pose.prediction_cov(jac_t, jac_theta) + p.rigid_sigma**2 * np.eye(2)

        # Predict each lamp, then weigh the prediction with the rigid array's (§2.2.3 2)).
        for i, track in enumerate(self._tracks):
            track.predict(*self._transition)
            if front[i]:
                track.update_position(rigid[i], rigid_cov[i])
        predicted = np.array([t.position for t in self._tracks])
        members = self._blob_members(blobs, predicted, front)

        # A lamp is seen when its centre is: a blob left by a lamp whose centre is hidden (a
        # sliver beside the fork, half a lamp at the border) has a biased circle. The test
        # point is where the rest of the array puts the centre: the array updated with every
        # other candidate blob (which absorbs this frame's INS attitude error). The lamp's own
        # blob and track are left out, as they may be the biased ones. A disc cut by a straight
        # edge keeps its centre iff more than half of it is left, which is then also its
        # circle's share: a blob cut by the image border must fill half its circle. The array
        # is then updated with the seen blobs only.
        prior = pose.snapshot()
        seen = {}
        for j, lamps in members.items():
            pose.restore(prior)
            others = [k for k in members if k != j]
            pose.update(*self._pose_measurements(blobs, members, others))
            test_points = pose.project()[0]
            lit = [i for i in lamps if self._centre_is_bright(gray, test_points[i])]
            if lit and not (len(lamps) == 1 and blobs.on_border[j] and blobs.fill[j] < MIN_FILL):
                seen[j] = lit
        pose.restore(prior)
        pose.update(*self._pose_measurements(blobs, members, seen))

        status = np.full(self._n, PREDICTED)
        rigid = pose.project()[0]
        for j, lamps in seen.items():
            if len(members[j]) == 1:
                self._update_with_blob(self._tracks[lamps[0]], blobs, j)
                status[lamps[0]] = DETECTED
            else:
                # Lamps in a merged blob are where the array, just fitted to it, puts them.
                for i in lamps:
                    self._tracks[i].update_position(rigid[i], p.pixel_sigma**2 * np.eye(2))
                status[lamps] = MERGED
        self._status = status

        if seen:
            self._frames_without_detection = 0
        else:
            self._frames_without_detection += 1
            if self._frames_without_detection >= p.lost_after:
                self._counts["track_losses"] += 1
                self._tracks = None
                self._status[:] = UNINITIALISED

    def _pose_measurements(self, blobs: Blobs, members: dict[int, list[int]],
                           used) -> tuple[list, np.ndarray, np.ndarray]:
        """Array-filter measurements from the blobs ``used`` (indices): a blob measures the
        mean projection of all its member lamps (one, or several when merged)."""
        groups, pixels, sigmas = [], [], []
        for j in used:
            lamps = members[j]
            groups.append(np.array(lamps))
            pixels.append(blobs.centres[j])
            if len(lamps) == 1:
                scale = BORDER_SIGMA_SCALE if blobs.on_border[j] else 1.0
                sigmas.append(self.params.pixel_sigma * scale)
            else:
                sigmas.append(max(blobs.radii[j] / 2.0, self.params.pixel_sigma))
        return groups, np.array(pixels).reshape(-1, 2), np.array(sigmas)

    def _blob_members(self, blobs: Blobs, predicted: np.ndarray,
                      front: np.ndarray) -> dict[int, list[int]]:
        """Which lamps each blob holds: its Hungarian match, plus the unmatched lamps predicted
        inside its circle (lamps whose images overlap form one merged blob)."""
        if not len(blobs):
            return {}
        members = {j: [i] for i, j in self._assign(blobs, front)}
        matched = {i for lamps in members.values() for i in lamps}
        margin = self.params.merge_margin
        for k in range(self._n):
            if k in matched or not front[k]:
                continue
            gap = np.linalg.norm(blobs.centres - predicted[k], axis=1) - blobs.radii
            j = int(np.argmin(gap))
            if gap[j] <= margin:
                members.setdefault(j, []).append(k)
        return members

    def _centre_is_bright(self, gray: np.ndarray, uv: np.ndarray) -> bool:
        """Whether every pixel within ``centre_halo`` px of ``uv`` is lamp-bright and inside
        the image (a lamp whose centre is near an occluder's edge is not claimed)."""
        col, row = math.floor(uv[0]), math.floor(uv[1])
        halo = self.params.centre_halo
        height, width = gray.shape
        if not (halo <= col < width - halo and halo <= row < height - halo):
            return False
        patch = gray[row - halo : row + halo + 1, col - halo : col + halo + 1]
        return bool(patch.min() >= self.segmentation.min_peak)

    def _assign(self, blobs: Blobs, front: np.ndarray) -> list[tuple[int, int]]:
        """Hungarian assignment of detections to lamps on the gated Mahalanobis cost."""
        p = self.params
        n, m = self._n, len(blobs)
        cost = np.full((n, m), np.inf)
        for i, track in enumerate(self._tracks):
            if not front[i]:
                continue
            diff = blobs.centres - track.position
            S = track.position_cov + p.pixel_sigma**2 * np.eye(2)
            maha = np.einsum("ij,ij->i", diff @ np.linalg.inv(S), diff)
            dist = np.linalg.norm(diff, axis=1)
            ok = (maha <= p.gate_chi2) & (dist <= p.gate_px)
            cost[i, ok] = maha[ok]
        valid = np.isfinite(cost)
        if not valid.any():
            return []
        # A gated-out pair costs more than any full set of valid pairs (an inf cost
        # would make SciPy's linear_sum_assignment raise on an infeasible set).
        big = p.gate_chi2 * (min(n, m) + 1) + 1.0
        rows, cols = linear_sum_assignment(np.where(valid, cost, big))
        return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if valid[i, j]]

    def _update_with_blob(self, track: BlobEKF, blobs: Blobs, j: int) -> None:
        p = self.params
        s = max(track.x[4], 0.5)
        _, _, w, h = blobs.boxes[j]
        z = np.array([blobs.centres[j, 0], blobs.centres[j, 1], blobs.areas[j], w, h], float)
        sigma_edge = 1.0
        R = np.diag([p.pixel_sigma**2, p.pixel_sigma**2,
                     (2.0 * math.pi * s * sigma_edge + 2.0) ** 2, 1.5**2, 1.5**2])
        if blobs.on_border[j]:
            # A blob cut by the image border: its size says nothing, its centre little.
            R[:2, :2] *= BORDER_SIGMA_SCALE**2
            track.update(z, R, rows=[0, 1])
        else:
            track.update(z, R)

    def _count(self) -> None:
        c = self._counts
        c["frames"] += 1
        if self._tracks is not None:
            c["detected"] += int(np.sum(self._status == DETECTED))
            c["merged"] += int(np.sum(self._status == MERGED))
            c["predicted"] += int(np.sum(self._status == PREDICTED))

    def _features(self, velocity: np.ndarray, attitude: np.ndarray) -> dict:
        pixels = np.zeros((self._n, 2), dtype=np.float32)
        visible = np.zeros(self._n, dtype=np.int8)
        if self._tracks is not None:
            reported = (self._status == DETECTED) | (self._status == MERGED)
            for i in np.flatnonzero(reported):
                pixels[i] = self._tracks[i].position
            visible[reported] = 1
            np.clip(pixels, *self._pixel_bounds, out=pixels)
        return {
            "pixels": pixels,
            "visible": visible,
            "velocity": velocity.astype(np.float32),
            "attitude": attitude.astype(np.float32),
        }


__all__ = ["LampArrayFrontEnd"]
