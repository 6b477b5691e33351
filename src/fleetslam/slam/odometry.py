"""Frame-to-local-map RGB-D visual odometry with a windowed bundle adjustment (pure: arrays in, pose out).

Each frame: ORB features are matched to the local map (landmarks with descriptors, in the odometry frame) near
where a motion prediction projects them (the wheel odometry's motion when there is one, else constant velocity);
the pose is found by robust motion-only optimisation of reprojection and depth residuals, point-to-plane residuals
of the frame's depth against the newest keyframe's surface (the room's geometry, where texture is poor), and the
prediction as a prior whose width follows the frame interval (RANSAC PnP only when the guided matches fail). A
frame becomes a keyframe when it tracks too few of the map's landmarks, or moved or turned far enough from the last
keyframe (distances, not frame counts: the decision does not depend on the camera rate). A keyframe adds its new
landmarks and joins a window of recent keyframes; after its pose is out, :meth:`VisualOdometry.local_mapping`
merges the landmarks it made again (:mod:`~fleetslam.slam.landmark_fusion`; without wheels) and bundle-adjusts the
window (poses and landmarks, RGB-D residuals; a ground robot's poses on its floor plane, tied by
the wheels' relative motion), so that one frame's error does not become the next keyframe's map.

When the features fail (a blank wall, motion blur, a dropped stretch of frames) with wheel odometry available, the
pose follows the wheels and the map is kept (``coasting``), so tracking resumes on the same map; only after
``coast_distance`` without a match does the map restart at the wheel pose. Without wheel odometry the frame is
``lost``: the pose follows constant velocity, and the map restarts after ``lost_frames`` such frames (the
pipeline then tries to relocalise on its keyframes).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics
from fleetslam.geometry import invert, orthonormalized, planar_camera_pose, rotation_angle
from fleetslam.slam.config import FeatureConfig, OdometryConfig
from fleetslam.slam.features import FeatureExtractor, Features, import_cv2
from fleetslam.slam.frontend import OdometryResult
from fleetslam.slam.landmark_fusion import View, fuse_into_view, merge_plan
from fleetslam.slam.local_ba import BundleProblem, PosePrior, bundle_adjust
from fleetslam.slam.matching import match_by_projection, match_ratio
from fleetslam.slam.photometric_alignment import (
    FrameIntensity,
    KeyframeIntensity,
    PhotometricTerm,
    level_intrinsics,
    pyramid_level,
)
from fleetslam.slam.pose_refinement import DenseTerm, planar_basis, refine_pose, refine_pose_with_prior
from fleetslam.slam.surface_alignment import KeyframeSurface, SurfaceTerm, depth_samples, sample_stride
from fleetslam.slam.triangulation import match_and_triangulate

logger = logging.getLogger(__name__)


def backproject(
    keypoints: NDArray[np.float32],
    depth: NDArray[np.float32],
    intrinsics: Intrinsics,
    min_depth: float,
    max_depth: float,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """3D points (camera frame) of keypoints from the depth image, and which are valid.

    The depth is interpolated bilinearly between the four pixels around the keypoint when they lie on one surface
    (within 3 % of each other), else taken from the nearest pixel: a keypoint sits between pixels, and on a wall
    seen at an angle the nearest pixel's depth is off by up to half a pixel's depth gradient."""
    h, w = depth.shape
    x = np.clip(keypoints[:, 0].astype(np.float64), 0.0, w - 1.0)
    y = np.clip(keypoints[:, 1].astype(np.float64), 0.0, h - 1.0)
    u0 = np.minimum(np.floor(x).astype(np.intp), w - 2) if w > 1 else np.zeros(len(x), np.intp)
    v0 = np.minimum(np.floor(y).astype(np.intp), h - 2) if h > 1 else np.zeros(len(y), np.intp)
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    fu, fv = x - u0, y - v0
    corners = np.stack([depth[v0, u0], depth[v0, u1], depth[v1, u0], depth[v1, u1]], axis=1).astype(np.float64)
    corners = np.nan_to_num(corners, nan=0.0, posinf=0.0, neginf=0.0)
    weights = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=1)
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    smooth = (lo > 0) & (hi - lo <= 0.03 * lo)
    nearest = depth[np.rint(y).astype(np.intp), np.rint(x).astype(np.intp)].astype(np.float64)
    z = np.where(smooth, np.sum(corners * weights, axis=1), np.nan_to_num(nearest, nan=0.0))
    valid = np.isfinite(z) & (z > min_depth) & (z < max_depth)
    px = (keypoints[:, 0] - intrinsics.cx) * z / intrinsics.fx
    py = (keypoints[:, 1] - intrinsics.cy) * z / intrinsics.fy
    return np.stack([px, py, z], axis=1), valid


def _to_rvec_tvec(T_camera_world: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    cv2 = import_cv2()
    rvec, _ = cv2.Rodrigues(T_camera_world[:3, :3])
    return rvec.reshape(3, 1).astype(np.float64), T_camera_world[:3, 3].reshape(3, 1).astype(np.float64)


def _from_rvec_tvec(rvec: NDArray[np.float64], tvec: NDArray[np.float64]) -> NDArray[np.float64]:
    cv2 = import_cv2()
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.reshape(3)
    return T


class LocalMap:
    """Landmarks in the odometry frame: positions, descriptors, stable ids (increasing) and the frame each was last
    tracked in; capped in size, the longest unseen leave first. A landmark made from a keypoint without depth (a
    bearing, ``far_landmarks``) also keeps its anchor: the camera centre it was first seen from and the standard
    deviation of its inverse distance from there (NaN for the others): the window's adjustment puts an inverse-depth
    prior on it and narrows that deviation with the parallax of the keyframes that saw it."""

    def __init__(self, max_size: int) -> None:
        self.max_size = max_size
        self.points = np.zeros((0, 3))
        self.descriptors: NDArray[Any] | None = None
        self.ids = np.zeros(0, np.int64)
        self.last_seen = np.zeros(0, np.int64)
        self.anchors = np.zeros((0, 4))
        self._next_id = 0

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def clear(self) -> None:
        self.points = np.zeros((0, 3))
        self.descriptors = None
        self.ids = np.zeros(0, np.int64)
        self.last_seen = np.zeros(0, np.int64)
        self.anchors = np.zeros((0, 4))

    def add(
        self,
        points: NDArray[np.float64],
        descriptors: NDArray[Any],
        frame: int = 0,
        anchor: NDArray[np.float64] | None = None,
    ) -> NDArray[np.int64]:
        """Append landmarks (``anchor``: for bearings, the camera centre they were seen from and the standard
        deviation of their inverse distance, for all of them); returns their ids."""
        ids = np.arange(self._next_id, self._next_id + len(points), dtype=np.int64)
        if len(points) == 0:
            return ids
        self._next_id += len(points)
        anchors = np.full((len(points), 4), np.nan) if anchor is None else np.tile(anchor, (len(points), 1))
        if self.descriptors is None or len(self) == 0:
            self.points, self.descriptors = np.array(points, np.float64), descriptors.copy()
            self.ids, self.last_seen = ids, np.full(len(points), frame, np.int64)
            self.anchors = anchors
        else:
            self.points = np.vstack([self.points, points])
            self.descriptors = np.vstack([self.descriptors, descriptors])
            self.ids = np.concatenate([self.ids, ids])
            self.last_seen = np.concatenate([self.last_seen, np.full(len(points), frame, np.int64)])
            self.anchors = np.vstack([self.anchors, anchors])
        excess = len(self.points) - self.max_size
        if excess > 0:
            keep = np.sort(np.argsort(self.last_seen, kind="stable")[excess:])
            self._keep(keep)
        return ids

    def _keep(self, rows: NDArray[np.intp]) -> None:
        assert self.descriptors is not None
        self.points, self.descriptors = self.points[rows], self.descriptors[rows]
        self.ids, self.last_seen = self.ids[rows], self.last_seen[rows]
        self.anchors = self.anchors[rows]

    def merge(self, dropped: NDArray[np.int64], kept: NDArray[np.int64]) -> None:
        """Drop the landmarks ``dropped``, each a duplicate of the one in ``kept`` (which keeps its position and
        descriptor, and the later of the two frames last tracked). Where the one dropped was measured or
        triangulated and the one kept only had its prior (an anchor), the one kept takes its position and loses its
        anchor."""
        rows, found = self.rows(dropped)
        kept_rows, kept_found = self.rows(kept)
        both = found & kept_found
        np.maximum.at(self.last_seen, kept_rows[both], self.last_seen[rows[both]])
        measured = both & np.isnan(self.anchors[rows, 0]) & ~np.isnan(self.anchors[kept_rows, 0])
        self.points[kept_rows[measured]] = self.points[rows[measured]]
        self.anchors[kept_rows[measured]] = np.nan
        keep = np.ones(len(self), bool)
        keep[rows[found]] = False
        self._keep(np.flatnonzero(keep))

    def rows(self, ids: NDArray[np.int64]) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
        """Rows of the given landmark ids, and which of them are still in the map."""
        position = np.searchsorted(self.ids, ids)
        found = position < len(self.ids)
        found[found] = self.ids[position[found]] == ids[found]
        return np.where(found, position, 0).astype(np.intp), found


@dataclass
class _WindowKeyframe:
    """A keyframe of the bundle-adjustment window and what it observed."""

    pose: NDArray[np.float64]
    """``T_world_camera`` (odometry frame)."""
    landmarks: NDArray[np.int64]
    pixels: NDArray[np.float64]
    depths: NDArray[np.float64]
    scales: NDArray[np.float64]
    prior: NDArray[np.float64] | None
    """The wheel odometry's camera pose at this keyframe (``T_odom_camera``), when known."""
    surface: KeyframeSurface | None = None
    """Its depth as vertices and normals, for the next frames' surface term."""
    intensity: KeyframeIntensity | None = None
    """Its selected pixels' points and intensities, for the next frames' photometric term."""


def wheel_motion_std(motion: NDArray[np.float64], wheel_drift: float) -> tuple[float, float]:
    """How far off the wheels' measure of a motion is: translation (m) and rotation (rad) standard deviations,
    ``wheel_drift`` of the distance and of the turn (slip), plus 3 mm and 0.2° (timing between the wheel and camera
    stamps)."""
    return (
        wheel_drift * float(np.linalg.norm(motion[:3, 3])) + 3e-3,
        wheel_drift * rotation_angle(motion) + np.radians(0.2),
    )


def wheel_prior_std(motion: NDArray[np.float64], wheel_drift: float) -> tuple[float, float]:
    """How far off the wheels' measure of the motion between two keyframes is, as the window's adjustment weighs it:
    translation (m) and rotation (rad) standard deviations, ``wheel_drift`` of the distance and of the turn, never
    below a millimetre and a tenth of a degree."""
    return (
        wheel_drift * float(np.linalg.norm(motion[:3, 3])) + 1e-3,
        wheel_drift * rotation_angle(motion) + np.radians(0.1),
    )


class VisualOdometry:
    """RGB-D frame-to-local-map odometry (the ``visual`` :class:`~fleetslam.slam.frontend.OdometryFrontEnd`).
    ``track`` is called once per frame, in order."""

    provides_features = True
    """Keyframes carry ORB (or SIFT, AKAZE) features for loop closure."""

    def __init__(
        self,
        config: OdometryConfig,
        intrinsics: Intrinsics,
        features: FeatureConfig | None = None,
        base_camera: NDArray[np.float64] | None = None,
    ) -> None:
        """``base_camera`` (T_base_camera) enables ``config.planar_motion``; it may also be set later."""
        self.config = config
        self.intrinsics = intrinsics
        fc = features if features is not None else FeatureConfig.model_validate({})
        #: Pixel distances in the configuration are for a 640-pixel-wide image; a smaller image moves less.
        self._pixel_scale = intrinsics.width / 640.0
        # ORB's patch covers the same part of the scene at any resolution (31 px at 640 wide): on a small image a
        # full-size patch would only blur the descriptor and keep features a patch away from the border.
        patch = max(15, round(fc.orb_patch_size * min(self._pixel_scale, 1.0)))
        self.extractor = FeatureExtractor(
            fc.kind,
            fc.max_features,
            fc.grid_rows,
            fc.grid_cols,
            fc.orb_fast_threshold,
            fc.orb_levels,
            patch,
            subpixel_window=max(1, round(fc.subpixel_window * self._pixel_scale)) if fc.subpixel_window else 0,
        )
        self._K = intrinsics.K
        self.local_map = LocalMap(config.local_map_size)
        self.window: deque[_WindowKeyframe] = deque(maxlen=config.window_keyframes)
        self._retired: deque[_WindowKeyframe] = deque(maxlen=config.window_fixed_keyframes or 1)
        """Keyframes that left the window, newest last: held fixed in its adjustment where they share landmarks."""
        self.pose = np.eye(4)
        self._velocity = np.eye(4)
        """Motion of the last frame, ``T_previous_current``."""
        self._previous_prior: NDArray[np.float64] | None = None
        self._keyframe_pose: NDArray[np.float64] | None = None
        self._keyframe_tracked = 0
        self.frames = 0
        self.base_camera = base_camera
        self._last_stamp: float | None = None
        self._frame_interval = 1.0 / 30.0
        self._coasted = 0.0
        """Distance (m) followed on the wheels since the map last tracked."""
        self._candidates: deque[_Candidates] = deque(maxlen=config.window_keyframes)
        """Keypoints without depth of the window's keyframes, oldest first, waiting to be triangulated."""
        self._lost_frames = 0
        self._adjustment_pending = False
        self._insertion_pending: _InsertionPending | None = None
        self._fusion_pending: _FusionPending | None = None
        """The newest keyframe's keypoints, for the landmark fusion that precedes the window's adjustment."""
        self.fused_landmarks = 0
        """Landmarks merged into another since the start (``fuse_landmarks``)."""
        self._surface_stride = sample_stride(intrinsics, config.surface_samples) if config.surface_samples > 0 else 0
        self._photometric_level = pyramid_level(intrinsics.width)
        self._photometric_block = (
            sample_stride(level_intrinsics(intrinsics, self._photometric_level), config.photometric_samples)
            if config.photometric_samples > 0
            else 0
        )

    # -- prediction ---------------------------------------------------------------------------------------------
    def _predict(self, prior: NDArray[np.float64] | None) -> _Prediction:
        """Where the frame should be: the wheels' motion since the last frame when known (off by their slip:
        ``wheel_drift`` of the motion, plus a few millimetres of timing), else constant velocity (off by what the
        configured accelerations can change within the frame interval: ½·a·Δt²)."""
        if prior is not None and self._previous_prior is not None and self.config.use_prior:
            motion = invert(self._previous_prior) @ prior
            std = wheel_motion_std(motion, self.config.wheel_drift)
            return _Prediction(self.constrain(self.pose @ motion), std, True)
        # The velocity itself comes from two noisy poses: its error (a few millimetres and tenths of a degree per
        # frame, whatever the rate) adds to what the acceleration can change. Without that floor, a tight prior at
        # a high rate passes a velocity error on from frame to frame and the pose runs away with it.
        half_dt2 = 0.5 * self._frame_interval**2
        std = (
            float(np.hypot(self.config.motion_prior_acceleration * half_dt2, 0.005)),
            float(np.hypot(self.config.motion_prior_angular_acceleration * half_dt2, np.radians(0.3))),
        )
        return _Prediction(self.constrain(self.pose @ self._velocity), std, False)

    def constrain(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """The pose projected onto the robot's plane of motion when ``planar_motion`` is on (and the mounting
        known); otherwise unchanged."""
        if not self.planar:
            return pose
        assert self.base_camera is not None
        return planar_camera_pose(pose, self.base_camera)

    @property
    def planar(self) -> bool:
        return bool(self.config.planar_motion and self.base_camera is not None)

    # -- the frame ----------------------------------------------------------------------------------------------
    def track(
        self, rgb: NDArray[np.uint8], depth: NDArray[np.float32], stamp: float, prior: NDArray[np.float64] | None = None
    ) -> OdometryResult:
        """Estimate ``T_world_camera`` of this frame.

        Args:
            rgb: ``(H, W, 3)`` uint8 colour image (or ``(H, W)`` grayscale).
            depth: ``(H, W)`` float32 metres registered to ``rgb`` (0 = invalid).
            stamp: capture time in seconds (sets the motion prior's width).
            prior: optional pose of this frame from wheel odometry (any fixed frame).
        """
        cv2 = import_cv2()
        self.local_mapping()
        t0 = time.perf_counter()
        timings: dict[str, float] = {}
        gray = rgb if rgb.ndim == 2 else cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        mask = None
        if self.config.depth_as_mask:
            mask = ((depth > self.config.min_depth) & (depth < self.config.max_depth)).astype(np.uint8)
        feats = self.extractor.detect(gray, mask)
        points_cam, valid = backproject(
            feats.keypoints, depth, self.intrinsics, self.config.min_depth, self.config.max_depth
        )
        t1 = time.perf_counter()
        timings["features"] = (t1 - t0) * 1e3
        if self._last_stamp is not None and 0.0 < stamp - self._last_stamp < 2.0:
            self._frame_interval = stamp - self._last_stamp
        self._last_stamp = stamp
        prior_arr = None if prior is None else np.asarray(prior, dtype=np.float64)
        prediction = self._predict(prior_arr)
        intensity = None
        if self._photometric_block:
            # The blur is given for a 640-pixel-wide image; the level is narrower by 2^level.
            blur = self.config.photometric_blur * self._pixel_scale / 2**self._photometric_level
            intensity = FrameIntensity.from_gray(gray, self.intrinsics, blur, self._photometric_level)
        frame = _Frame(feats, points_cam, valid, prior_arr, depth, intensity)
        self.frames += 1

        if len(self.local_map) == 0:
            start = self.pose if self.frames == 1 else prediction.pose
            lost = self.frames > 1 and not prediction.from_wheels
            return self._restart(start, frame, lost=lost, timings=timings, t0=t0)

        matched_frame, matched_map, pose, inliers = self._track_map(frame, prediction, timings)
        if pose is None:
            return self._untracked(prediction, frame, len(matched_frame), timings, t0)
        self._coasted = 0.0
        self._lost_frames = 0
        tracked_ids = self.local_map.ids[matched_map[inliers]]
        self.local_map.last_seen[matched_map[inliers]] = self.frames
        # Landmarks placed from bearings do not delay keyframes: the keyframe rules count the map a keyframe could
        # have made without them (more tracked, fewer keyframes, fewer loops closed: triangulation_keyframes).
        former_bearing = ~np.isnan(self.local_map.anchors[matched_map, 3])
        is_keyframe = self._needs_keyframe(pose, int((inliers & ~former_bearing).sum()))
        if is_keyframe:
            # Making the keyframe (its new landmarks, the triangulation, its surface) is local mapping's work, as
            # in ORB-SLAM: the frame's pose goes out first (local_mapping(), or the next track(), makes it).
            self._insertion_pending = _InsertionPending(pose.copy(), frame, matched_frame[inliers], tracked_ids)
        return self._finish(pose, int(inliers.sum()), len(matched_frame), is_keyframe, False, frame, timings, t0)

    # -- tracking -----------------------------------------------------------------------------------------------
    def _track_map(
        self, frame: _Frame, prediction: _Prediction, timings: dict[str, float]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64] | None, NDArray[np.bool_]]:
        """Matches (frame index, map row), the pose and the inlier mask; pose None when tracking failed."""
        t1 = time.perf_counter()
        need = self.config.min_inliers
        radius = self.config.search_radius * self._pixel_scale
        predicted = prediction.pose
        use_prior = self.config.motion_prior_acceleration > 0
        matched_frame, matched_map = self._match(frame.features, predicted, radius)
        pose, inliers = None, np.zeros(len(matched_frame), bool)
        timings["match"] = (time.perf_counter() - t1) * 1e3
        t2 = time.perf_counter()
        if len(matched_frame) >= need:
            pose, inliers = self._optimize(
                frame, matched_frame, matched_map, predicted, prediction if use_prior else None
            )
        if pose is None or inliers.sum() < 2 * need:
            # The prediction may be off (a bump, a slip, a dropped stretch of frames): search wider, then the
            # whole image, and let RANSAC find the pose without the prediction.
            t_wide = time.perf_counter()
            wide = self._match(frame.features, predicted, 4 * radius)
            if len(wide[0]) < 2 * need:
                wide = self._match(frame.features, None, 0.0)
            timings["match"] += (time.perf_counter() - t_wide) * 1e3
            ransac = self._ransac(frame, *wide, predicted)
            if ransac is not None:
                candidate, candidate_inliers = self._optimize(frame, *wide, ransac, None)
                if candidate is not None and candidate_inliers.sum() > inliers.sum():
                    pose, inliers = candidate, candidate_inliers
                    matched_frame, matched_map = wide
        timings["pose"] = (time.perf_counter() - t2) * 1e3
        if pose is None or inliers.sum() < need or not self._plausible(pose, predicted):
            return matched_frame, matched_map, None, inliers
        return matched_frame, matched_map, pose, inliers

    def _match(
        self, feats: Features, predicted: NDArray[np.float64] | None, radius: float
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Ratio-test matches frame → local map; with a predicted pose only within ``radius`` pixels of where each
        landmark should appear (repetitive texture such as floor tiles then cannot mismatch)."""
        if len(feats) < 2 or self.local_map.descriptors is None or len(self.local_map) < 2:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        # Bearings (far_landmarks) are the window's business until their distance is known.
        placed = np.flatnonzero(np.isnan(self.local_map.anchors[:, 0]))
        if predicted is None:
            q, t = match_ratio(feats.descriptors, self.local_map.descriptors[placed], self.config.match_ratio)
            return q, placed[t]
        T_cw = invert(predicted)
        cam = self.local_map.points @ T_cw[:3, :3].T + T_cw[:3, 3]
        z = np.maximum(cam[:, 2], 1e-9)
        u = self.intrinsics.fx * cam[:, 0] / z + self.intrinsics.cx
        v = self.intrinsics.fy * cam[:, 1] / z + self.intrinsics.cy
        visible = np.flatnonzero(
            np.isnan(self.local_map.anchors[:, 0])
            & (cam[:, 2] > self.config.min_depth)
            & (u > -radius)
            & (u < self.intrinsics.width + radius)
            & (v > -radius)
            & (v < self.intrinsics.height + radius)
        )
        q, t = match_by_projection(
            feats.keypoints,
            feats.descriptors,
            np.stack([u[visible], v[visible]], axis=1),
            self.local_map.descriptors[visible],
            radius,
            self.config.match_ratio,
            self.config.max_descriptor_distance if self.extractor.binary else 0.0,
            self.config.same_point_radius * self._pixel_scale,
        )
        return q, visible[t]

    def _optimize(
        self,
        frame: _Frame,
        matched_frame: NDArray[np.intp],
        matched_map: NDArray[np.intp],
        start: NDArray[np.float64],
        prediction: _Prediction | None,
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.bool_]]:
        """Robust motion-only optimisation of the frame's pose against the matched landmarks (reprojection and,
        where the frame has depth, depth residuals) with the prediction as a prior (dropped when the matches
        clearly contradict it); twice, dropping the matches the first pass found to be outliers. Returns
        (``T_world_camera``, inlier mask)."""
        n = len(matched_frame)
        if n < 4:
            return None, np.zeros(n, bool)
        feats = frame.features
        points = self.local_map.points[matched_map]
        pixels = feats.keypoints[matched_frame].astype(np.float64)
        pixel_std = self.config.pixel_std * feats.scales[matched_frame].astype(np.float64)
        depths = np.where(frame.valid[matched_frame], frame.points[matched_frame, 2], 0.0)
        basis = planar_basis(self.base_camera) if self.planar and self.base_camera is not None else None
        huber = 2.0 * self.config.pixel_std * self._pixel_scale
        T_cw = invert(start)
        keep = np.ones(n, bool)
        fused: tuple[NDArray[np.float64], tuple[float, float]] | None = None
        dense = self._dense_terms(frame, start)
        for first in (True, False):
            idx = np.flatnonzero(keep)
            depth = (depths[idx], self.config.depth_noise)
            if first and prediction is not None:
                # Whether the prediction may be fused is decided once, on every match (the gate).
                T_cw, used = refine_pose_with_prior(
                    T_cw, points[idx], pixels[idx], self._K, invert(prediction.pose), prediction.std,
                    pixel_std=pixel_std[idx], huber_px=huber, iterations=4,
                    gate=self.config.motion_prior_gate, basis=basis, depth=depth, dense=dense,
                )  # fmt: skip
                fused = (invert(prediction.pose), prediction.std) if used else None
            else:
                T_cw = refine_pose(
                    T_cw, points[idx], pixels[idx], self._K, pixel_std=pixel_std[idx], huber_px=huber,
                    iterations=4 if first else 3, basis=basis, depth=depth, prior=fused, dense=dense,
                )  # fmt: skip
            chi2 = _chi2(T_cw, points, pixels, pixel_std, depths, self.config.depth_noise, self._K)
            # χ² at 95 % for 2 (no depth) or 3 (with depth) residuals, as ORB-SLAM's mono/stereo thresholds.
            inliers = chi2 <= np.where(depths > 0, 7.815, 5.991)
            if inliers.sum() < 4:
                return None, inliers
            if first and inliers.all():
                return self.constrain(invert(T_cw)), inliers
            keep = inliers
        return self.constrain(invert(T_cw)), keep

    def _ransac(
        self,
        frame: _Frame,
        matched_frame: NDArray[np.intp],
        matched_map: NDArray[np.intp],
        predicted: NDArray[np.float64],
    ) -> NDArray[np.float64] | None:
        """PnP RANSAC pose (``T_world_camera``) from matches without relying on the prediction, or None."""
        cv2 = import_cv2()
        if len(matched_frame) < max(6, self.config.min_inliers):
            return None
        object_points = self.local_map.points[matched_map].astype(np.float64)
        image_points = frame.features.keypoints[matched_frame].astype(np.float64)
        rvec, tvec = _to_rvec_tvec(invert(predicted))
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            object_points,
            image_points,
            self._K,
            None,
            rvec,
            tvec,
            useExtrinsicGuess=True,
            iterationsCount=self.config.pnp_iterations,
            reprojectionError=self.config.pnp_reprojection_error * self._pixel_scale,
            confidence=0.99,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not ok or inliers is None or len(inliers) < self.config.min_inliers:
            return None
        return self.constrain(invert(_from_rvec_tvec(rvec, tvec)))

    def _plausible(self, pose: NDArray[np.float64], predicted: NDArray[np.float64]) -> bool:
        """A pose farther from the prediction than the platform could move in the frame interval is a failure."""
        error = invert(predicted) @ pose
        dt = max(self._frame_interval, 1.0 / 30.0)
        return bool(
            np.linalg.norm(error[:3, 3]) <= self.config.max_prediction_error * dt * 30.0
            and np.degrees(rotation_angle(error)) <= self.config.max_prediction_error_deg * dt * 30.0
        )

    # -- keyframes and the window -------------------------------------------------------------------------------
    def _needs_keyframe(self, pose: NDArray[np.float64], inliers: int) -> bool:
        """A keyframe when the view moved or turned far from the last one, or it tracks too few landmarks — but
        only once it moved or turned a little (``keyframe_min_*``): at a high camera rate, tracking counts that
        dip for a frame would otherwise make keyframes a few millimetres apart, each adding its own error to the
        map. Distances, not frame counts: the decision is the same at any camera rate."""
        if self._keyframe_pose is None:
            return True
        motion = invert(self._keyframe_pose) @ pose
        distance = float(np.linalg.norm(motion[:3, 3]))
        turn = float(np.degrees(rotation_angle(motion)))
        if distance > self.config.keyframe_translation or turn > self.config.keyframe_rotation_deg:
            return True
        if inliers < 2 * self.config.min_inliers:
            return True  # about to lose the map: extend it now, wherever we are
        moved = distance > self.config.keyframe_min_translation or turn > self.config.keyframe_min_rotation_deg
        weak = inliers < self.config.keyframe_inlier_ratio * self._keyframe_tracked
        return bool(moved and (weak or inliers < self.config.keyframe_min_tracked))

    def _insert_keyframe(
        self, pose: NDArray[np.float64], frame: _Frame, tracked: NDArray[np.intp], tracked_ids: NDArray[np.int64]
    ) -> None:
        """Add the frame's new landmarks (measured depth, and triangulated with the last keyframe where the depth
        camera saw nothing) and the frame to the window, and mark the window's adjustment pending."""
        new = frame.valid.copy()
        new[tracked] = False
        new_index = np.flatnonzero(new)
        world = frame.points[new_index] @ pose[:3, :3].T + pose[:3, 3]
        new_ids = self.local_map.add(world, frame.features.descriptors[new_index], self.frames)
        unmeasured = ~frame.valid
        unmeasured[tracked] = False
        far_index, far_ids, leftover = self._triangulate(pose, frame, np.flatnonzero(unmeasured))
        bearing_ids = np.full(len(leftover), -1, np.int64)
        if self._far_landmarks(frame):
            # Keypoints beside a measured depth (bearing_edge_radius) stay triangulation candidates only.
            beyond = self._beyond_range(frame, leftover)
            bearing_ids[beyond] = self._bearing_landmarks(pose, frame, leftover[beyond])
            far_index = np.concatenate([far_index, leftover[beyond]])
            far_ids = np.concatenate([far_ids, bearing_ids[beyond]])
        observed = np.concatenate([tracked, new_index, far_index])
        if len(self.window) == self.window.maxlen and self.config.window_fixed_keyframes:
            self._retired.append(self.window[0])
        self.window.append(
            _WindowKeyframe(
                pose=pose.copy(),
                landmarks=np.concatenate([tracked_ids, new_ids, far_ids]),
                pixels=frame.features.keypoints[observed].astype(np.float64),
                depths=np.where(frame.valid[observed], frame.points[observed, 2], 0.0),
                scales=frame.features.scales[observed].astype(np.float64),
                prior=frame.prior,
                surface=self._keyframe_surface(frame),
                intensity=self._keyframe_intensity(frame),
            )
        )
        feats = frame.features
        self._candidates.append(_Candidates(
            self.window[-1], feats.keypoints[leftover].astype(np.float64), feats.descriptors[leftover],
            feats.scales[leftover].astype(np.float64), bearing_ids,
        ))  # fmt: skip
        if self.config.fuse_landmarks and self.extractor.binary:
            depths = np.where(frame.valid, frame.points[:, 2], 0.0)
            self._fusion_pending = _FusionPending(self.window[-1], feats, depths, observed)
        # The window's adjustment is local mapping: it runs after the frame's pose is out (local_mapping()).
        self._adjustment_pending = len(self.window) >= 2 and self.config.window_keyframes >= 2
        self._keyframe_pose = pose.copy()
        self._keyframe_tracked = int(frame.valid.sum())

    def _far_landmarks(self, frame: _Frame) -> bool:
        """Whether the keyframe's keypoints without depth become landmarks at once (``far_landmarks``): not where
        the wheels measure the motion (they hold the heading; a ground robot's results stay as they were)."""
        wheels = self.config.use_prior and self.config.wheel_drift > 0 and frame.prior is not None
        return self.config.far_landmarks and not wheels

    def _bearing_landmarks(
        self, pose: NDArray[np.float64], frame: _Frame, index: NDArray[np.intp]
    ) -> NDArray[np.int64]:
        """Landmarks of the keypoints ``index`` (no depth): on their rays, at the distance of the inverse-depth
        prior's mean, anchored at this keyframe's centre; returns their ids."""
        if len(index) == 0:
            return np.zeros(0, np.int64)
        keypoints = frame.features.keypoints[index].astype(np.float64)
        rays = np.stack(
            [
                (keypoints[:, 0] - self.intrinsics.cx) / self.intrinsics.fx,
                (keypoints[:, 1] - self.intrinsics.cy) / self.intrinsics.fy,
                np.ones(len(index)),
            ],
            axis=1,
        )
        rays /= np.linalg.norm(rays, axis=1)[:, None]
        mean, std = self._inverse_depth_prior()
        world = (rays / mean) @ pose[:3, :3].T + pose[:3, 3]
        anchor = np.append(pose[:3, 3], std)
        return self.local_map.add(world, frame.features.descriptors[index], self.frames, anchor=anchor)

    def _beyond_range(self, frame: _Frame, index: NDArray[np.intp]) -> NDArray[np.bool_]:
        """Which of the keypoints ``index`` (no depth) have no measured depth within ``bearing_edge_radius`` pixels
        either: their depth is missing because they lie beyond the sensor's range, not because they sit on a depth
        edge (a nearer surface's border) or in a small hole."""
        r = self.config.bearing_edge_radius
        if r <= 0 or len(index) == 0:
            return np.ones(len(index), bool)
        valid = (frame.depth > 0).astype(np.uint8)
        near = import_cv2().dilate(valid, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
        pixels = np.rint(frame.features.keypoints[index]).astype(np.intp)
        h, w = near.shape
        return ~near[np.clip(pixels[:, 1], 0, h - 1), np.clip(pixels[:, 0], 0, w - 1)]

    def _triangulated_spread(self) -> float:
        """Relative standard deviation of the distance of a point triangulated from two rays ``min_parallax_deg``
        apart, each off by ``pixel_std``: √2·(σ/f)/α."""
        return float(
            np.sqrt(2.0) * self.config.pixel_std / self.intrinsics.fx / np.radians(self.config.min_parallax_deg)
        )

    def _inverse_depth_prior(self) -> tuple[float, float]:
        """Mean and standard deviation (1/m) of a bearing's inverse distance before any parallax: the depth camera
        did not measure it, so it lies beyond ``max_depth`` (or the sensor's own reach), 1/d in (0, 1/max_depth): the
        mean 1/(2·max_depth), the deviation ``bearing_inverse_depth_std``."""
        return 0.5 / self.config.max_depth, self.config.bearing_inverse_depth_std

    def local_mapping(self) -> NDArray[np.float64] | None:
        """Make the new keyframe (its landmarks, the triangulation, its surface) and bundle-adjust the window
        (ORB-SLAM's local mapping: the keyframe's pose is published first, this follows before the next frame is
        tracked); returns the keyframe's adjusted pose, or None when no adjustment was pending. :meth:`track` runs
        pending local mapping itself first, so the results are the same whether or not the caller runs it in
        between."""
        insertion, self._insertion_pending = self._insertion_pending, None
        if insertion is not None:
            self._insert_keyframe(insertion.pose, insertion.frame, insertion.tracked, insertion.tracked_ids)
        if not self._adjustment_pending:
            return None
        self._adjustment_pending = False
        self._fuse_landmarks()
        adjusted = orthonormalized(self.constrain(self._adjust_window()))
        # The frame that became the keyframe is still the newest: its pose and the velocity follow the adjustment.
        self._velocity = self._velocity @ invert(self.pose) @ adjusted
        self.pose = adjusted
        self._keyframe_pose = adjusted.copy()
        return adjusted.copy()

    def _fuse_landmarks(self) -> None:
        """Merge the landmarks made twice around the newest keyframe (``fuse_landmarks``; see
        :mod:`~fleetslam.slam.landmark_fusion`): the local map's landmarks are projected into the new keyframe, and
        where one falls on a keypoint that observes another landmark, the two become the one with more observations
        in the window, in the local map and in every keyframe of the window and its fixed keyframes (ORB-SLAM also
        projects the new keyframe's landmarks into its neighbours; measured here, that direction made the hand-held
        cells worse: docs/slam.md)."""
        pending, self._fusion_pending = self._fusion_pending, None
        if pending is None or not self.window or pending.keyframe is not self.window[-1]:
            return
        if len(self._wheel_priors(list(self.window))) == len(self.window) - 1:
            return  # the wheels tie the window: see OdometryConfig.fuse_landmarks
        keyframe, feats, local_map = pending.keyframe, pending.features, self.local_map
        if local_map.descriptors is None or len(local_map) == 0:
            return
        options: dict[str, float] = {
            "max_distance": self.config.fuse_descriptor_distance,
            "pixel_std": self.config.pixel_std,
            "depth_noise": self.config.depth_noise,
            "min_depth": self.config.min_depth,
        }
        landmarks = np.full(len(feats), -1, np.int64)
        landmarks[pending.observed] = keyframe.landmarks[: len(pending.observed)]
        view = View(keyframe.pose, feats.keypoints.astype(np.float64), feats.descriptors,
                    feats.scales.astype(np.float64), pending.depths, landmarks)  # fmt: skip
        distinct = None
        if self.config.bearing_fusion_radius > 0:
            distinct = ~np.isnan(local_map.anchors[:, 0])
        forward = fuse_into_view(
            view, local_map.ids, local_map.points, local_map.descriptors, self._K, **options, distinct=distinct,
            distinct_radius=self.config.bearing_fusion_radius, distinct_ratio=self.config.bearing_fusion_ratio,
        )  # fmt: skip
        if len(forward.observed_index):
            # Keypoints of the new keyframe that had no landmark observe the one projected onto them.
            index = forward.observed_index
            keyframe.landmarks = np.concatenate([keyframe.landmarks, forward.observed_ids])
            keyframe.pixels = np.vstack([keyframe.pixels, feats.keypoints[index].astype(np.float64)])
            keyframe.depths = np.concatenate([keyframe.depths, pending.depths[index]])
            keyframe.scales = np.concatenate([keyframe.scales, feats.scales[index].astype(np.float64)])
        if not len(forward.duplicates):
            return
        keyframes = list(self._retired) + list(self.window)
        seen, counts = np.unique(np.concatenate([kf.landmarks for kf in keyframes]), return_counts=True)
        dropped, kept = merge_plan(forward.duplicates, dict(zip(seen.tolist(), counts.tolist(), strict=True)))
        for kf in keyframes:
            hit = np.isin(kf.landmarks, dropped)
            if not hit.any():
                continue
            kf.landmarks = kf.landmarks.copy()
            kf.landmarks[hit] = kept[np.searchsorted(dropped, kf.landmarks[hit])]
            # A keyframe that observed both keeps its first observation of the point.
            _, first = np.unique(kf.landmarks, return_index=True)
            if len(first) < len(kf.landmarks):
                rows = np.sort(first)
                kf.landmarks, kf.pixels = kf.landmarks[rows], kf.pixels[rows]
                kf.depths, kf.scales = kf.depths[rows], kf.scales[rows]
        local_map.merge(dropped, kept)
        self.fused_landmarks += len(dropped)

    def _keyframe_surface(self, frame: _Frame) -> KeyframeSurface | None:
        if not self._surface_stride:
            return None
        return KeyframeSurface.from_depth(
            frame.depth, self.intrinsics, self._surface_stride, self.config.min_depth, self.config.max_depth
        )

    def _keyframe_intensity(self, frame: _Frame) -> KeyframeIntensity | None:
        if frame.intensity is None:
            return None
        return KeyframeIntensity.select(
            frame.intensity, frame.depth, self._photometric_block,
            self.config.photometric_min_gradient, self.config.min_depth, self.config.max_depth,
        )  # fmt: skip

    def _dense_terms(self, frame: _Frame, start: NDArray[np.float64]) -> list[DenseTerm]:
        """The point-to-plane term against the surface keyframe (``surface_reach``) and the photometric term
        against the newest keyframe, those that are on and have what they need; ``start`` is where the frame's
        pose refinement starts."""
        if not self.window:
            return []
        keyframe = self.window[-1]
        terms: list[DenseTerm] = []
        reference = self._surface_keyframe(start)
        if reference.surface is not None:
            points = depth_samples(
                frame.depth, self.intrinsics, self._surface_stride, self.config.min_depth, self.config.max_depth
            )
            terms.append(SurfaceTerm(reference.surface, reference.pose, points, self.config.depth_noise,
                                     self.config.surface_std_scale))  # fmt: skip
        if keyframe.intensity is not None and frame.intensity is not None and len(keyframe.intensity.points):
            terms.append(PhotometricTerm(keyframe.intensity, keyframe.pose, frame.intensity,
                                         self.config.photometric_std))  # fmt: skip
        return terms

    def _surface_keyframe(self, start: NDArray[np.float64]) -> _WindowKeyframe:
        """The (non-empty) window's oldest keyframe with a surface within ``surface_reach`` and
        ``surface_reach_deg`` of ``start``, else the newest: aligned to the newest alone, the surface term starts
        again from that keyframe's error at every keyframe, which in weak texture comes every few frames."""
        reach, reach_deg = self.config.surface_reach, self.config.surface_reach_deg
        if reach <= 0:
            return self.window[-1]
        for keyframe in self.window:
            if keyframe.surface is None:
                continue
            motion = invert(keyframe.pose) @ start
            if np.linalg.norm(motion[:3, 3]) <= reach and np.degrees(rotation_angle(motion)) <= reach_deg:
                return keyframe
        return self.window[-1]

    def _triangulate(
        self, pose: NDArray[np.float64], frame: _Frame, unmeasured: NDArray[np.intp]
    ) -> tuple[NDArray[np.intp], NDArray[np.int64], NDArray[np.intp]]:
        """Landmarks from this keyframe's keypoints without depth matched along epipolar segments (see
        :mod:`~fleetslam.slam.triangulation`) to the newest ``triangulation_keyframes`` keyframes of the window, the
        oldest of them first: as ORB-SLAM triangulates with its covisible keyframes, a longer baseline gives a wider
        angle, so far texture ahead of a camera moving forward (a few tenths of a degree between neighbouring
        keyframes) is triangulated once the keyframes searched span enough of the path. Each keyframe's entry gains
        its observations of the landmarks it helped make. Returns this frame's keypoint indices, the new landmark
        ids and the unmeasured keypoints left over (this keyframe's candidates for the next ones)."""
        feats = frame.features
        found_index: list[NDArray[np.intp]] = []
        found_ids: list[NDArray[np.int64]] = []
        if self.config.triangulate:
            window = {id(kf) for kf in self.window}
            for candidates in list(self._candidates)[-self.config.triangulation_keyframes :]:
                previous = candidates.keyframe
                if (
                    id(previous) not in window
                    or len(candidates.pixels) == 0
                    or len(unmeasured) == 0
                    or np.linalg.norm(pose[:3, 3] - previous.pose[:3, 3]) < 0.02
                ):
                    continue
                result = match_and_triangulate(
                    previous.pose, candidates.pixels, candidates.descriptors,
                    pose, feats.keypoints[unmeasured], feats.descriptors[unmeasured], feats.scales[unmeasured],
                    self._K, near=0.5 * self.config.max_depth, far=10.0 * self.config.max_depth,
                    tolerance_px=2.0 * self.config.pixel_std * self._pixel_scale,
                    min_parallax_deg=self.config.min_parallax_deg,
                )  # fmt: skip
                if not len(result.points):
                    continue
                index = unmeasured[result.index_b]
                ids = self.local_map.add(result.points, feats.descriptors[index], self.frames)
                # A candidate that is a bearing already becomes the triangulated point (the keyframe observes it).
                bearing = candidates.bearings[result.index_a]
                rows, found = self.local_map.rows(bearing)
                found &= bearing >= 0
                if found.any():
                    self.local_map.points[rows[found]] = result.points[found]
                    self.local_map.anchors[rows[found], :3] = np.nan
                    self.local_map.last_seen[rows[found]] = self.frames
                    self.local_map.merge(ids[found], bearing[found])
                    ids = np.where(found, bearing, ids)
                fresh = ~found
                previous.landmarks = np.concatenate([previous.landmarks, ids[fresh]])
                previous.pixels = np.vstack([previous.pixels, candidates.pixels[result.index_a[fresh]]])
                previous.depths = np.concatenate([previous.depths, np.zeros(int(fresh.sum()))])
                previous.scales = np.concatenate([previous.scales, candidates.scales[result.index_a[fresh]]])
                candidates.remove(result.index_a)
                found_index.append(index)
                found_ids.append(ids)
                unmeasured = np.setdiff1d(unmeasured, index)
        if not found_index:
            return np.zeros(0, np.intp), np.zeros(0, np.int64), unmeasured
        return np.concatenate(found_index), np.concatenate(found_ids), unmeasured

    def _adjust_window(self) -> NDArray[np.float64]:
        """Bundle-adjust the window (its oldest keyframe fixed, and, where no wheel prior ties the window, the
        ``window_fixed_keyframes`` that left it before, fixed, observing the landmarks they share with it:
        ORB-SLAM's fixed covisible keyframes, which tie the landmarks to where earlier keyframes saw them) and write
        the result back; returns the newest keyframe's pose."""
        retired = list(self._retired) if self._needs_fixed_keyframes() else []
        window = retired + list(self.window)
        fixed = np.arange(len(window)) <= len(retired)
        obs_pose = np.concatenate([np.full(len(kf.landmarks), k, np.intp) for k, kf in enumerate(window)])
        ids = np.concatenate([kf.landmarks for kf in window])
        _, found = self.local_map.rows(ids)
        # Landmarks seen from one keyframe only constrain nothing but themselves; those the window does not see
        # are not its business.
        unique, counts = np.unique(ids[found], return_counts=True)
        in_window = np.concatenate([kf.landmarks for kf in self.window])
        shared = np.isin(ids, unique[counts >= 2]) & np.isin(ids, in_window) & found
        if shared.sum() < self.config.min_inliers:
            return window[-1].pose
        landmark_ids, point_index = np.unique(ids[shared], return_inverse=True)
        point_rows, _ = self.local_map.rows(landmark_ids)
        pixels = np.concatenate([kf.pixels for kf in window])[shared]
        depths = np.concatenate([kf.depths for kf in window])[shared]
        scales = np.concatenate([kf.scales for kf in window])[shared]
        poses = np.stack([invert(kf.pose) for kf in window])
        problem = self._problem(
            poses,
            self.local_map.points[point_rows],
            obs_pose[shared],
            point_index.astype(np.intp),
            pixels,
            depths,
            scales,
            fixed=fixed,
        )
        problem.priors = self._wheel_priors(window)
        problem.point_anchors = self.local_map.anchors[point_rows]
        problem.inverse_depth_prior = self._inverse_depth_prior()
        result = bundle_adjust(problem, iterations=self.config.window_iterations)
        if not np.isfinite(result.final_cost) or result.final_cost > result.initial_cost:
            return window[-1].pose
        self.local_map.points[point_rows] = result.points
        # A landmark a keyframe measured the depth of is no longer a bearing only; the others' inverse distance is
        # as uncertain as the adjustment left it (the point's own block, the poses held).
        anchors = self.local_map.anchors
        bearing = np.flatnonzero(~np.isnan(anchors[point_rows, 0]))
        if len(bearing) and len(result.point_hessian):
            offset = result.points[bearing] - anchors[point_rows[bearing], :3]
            distance = np.maximum(np.linalg.norm(offset, axis=1), 1e-6)
            ray = offset / distance[:, None]
            covariance = np.linalg.inv(result.point_hessian[bearing] + 1e-9 * np.eye(3))
            std = np.sqrt(np.maximum(np.einsum("pi,pij,pj->p", ray, covariance, ray), 0.0)) / distance**2
            anchors[point_rows[bearing], 3] = np.minimum(anchors[point_rows[bearing], 3], std)
            # As well placed as a point triangulated from two rays min_parallax_deg apart: an ordinary landmark.
            placed = std * distance <= self._triangulated_spread()
            anchors[point_rows[bearing[placed]], :3] = np.nan
        measured = np.unique(point_index[(depths > 0) & result.inliers])
        anchors[point_rows[measured]] = np.nan
        for kf, T_cw in zip(window, result.poses, strict=True):
            kf.pose = orthonormalized(self.constrain(invert(T_cw)))
        # Observations the adjustment found to be wrong matches leave the window.
        bad = np.zeros(len(ids), bool)
        bad[np.flatnonzero(shared)[~result.inliers]] = True
        start = 0
        for kf in window:
            stop = start + len(kf.landmarks)
            keep = ~bad[start:stop]
            if not keep.all():
                kf.landmarks, kf.pixels = kf.landmarks[keep], kf.pixels[keep]
                kf.depths, kf.scales = kf.depths[keep], kf.scales[keep]
            start = stop
        return window[-1].pose

    def _needs_fixed_keyframes(self) -> bool:
        """Whether the window's adjustment holds the retired keyframes fixed (``window_fixed_keyframes``): only when
        the wheels do not tie each of its keyframes to the one before. A wheel prior already keeps the window from
        turning about its oldest keyframe (and fixed keyframes there cost a ground robot accuracy); without one, the
        oldest keyframe alone holds the heading and it random-walks from window to window."""
        if not self.config.window_fixed_keyframes or not self._retired:
            return False
        return len(self._wheel_priors(list(self.window))) < len(self.window) - 1

    def _wheel_priors(self, window: list[_WindowKeyframe]) -> list[PosePrior]:
        """Relative-pose priors between consecutive window keyframes from the wheel odometry (σ:
        :func:`wheel_prior_std`)."""
        if not self.config.use_prior or self.config.wheel_drift <= 0:
            return []
        priors = []
        for k in range(1, len(window)):
            a, b = window[k - 1].prior, window[k].prior
            if a is None or b is None:
                continue
            measured = invert(a) @ b
            sigma_t, sigma_r = wheel_prior_std(measured, self.config.wheel_drift)
            # The prior relates T_cw poses: T_c(k-1)_c(k) = T_cw(k-1)·T_cw(k)⁻¹ ⇒ measured is camera k in camera k-1.
            priors.append(PosePrior(k - 1, k, measured, np.diag([sigma_t**-2] * 3 + [sigma_r**-2] * 3)))
        return priors

    def _problem(
        self,
        poses_cw: NDArray[np.float64],
        points: NDArray[np.float64],
        obs_pose: NDArray[np.intp],
        obs_point: NDArray[np.intp],
        pixels: NDArray[np.float64],
        depths: NDArray[np.float64],
        scales: NDArray[np.float64],
        fixed: NDArray[np.bool_],
    ) -> BundleProblem:
        return BundleProblem(
            poses=poses_cw,
            points=points,
            obs_pose=obs_pose,
            obs_point=obs_point,
            pixels=pixels,
            depths=depths,
            pixel_std=self.config.pixel_std * scales,
            camera_matrix=self._K,
            fixed=fixed,
            depth_noise=self.config.depth_noise,
            basis=planar_basis(self.base_camera) if self.planar and self.base_camera is not None else None,
        )

    # -- failures -----------------------------------------------------------------------------------------------
    def _untracked(
        self, prediction: _Prediction, frame: _Frame, matches: int, timings: dict[str, float], t0: float
    ) -> OdometryResult:
        """The frame could not be placed on the map: follow the prediction, keep the map while it may still match."""
        predicted = prediction.pose
        if prediction.from_wheels:
            step = invert(self.pose) @ predicted
            self._coasted += float(np.linalg.norm(step[:3, 3]))
            if self._coasted > self.config.coast_distance:
                logger.debug("odometry: %.2f m on the wheels without a match; map restarted", self._coasted)
                return self._restart(predicted, frame, lost=False, timings=timings, t0=t0, coasting=True)
            return self._finish(predicted, 0, matches, False, False, frame, timings, t0, coasting=True)
        self._lost_frames += 1
        if self._lost_frames >= self.config.lost_frames:
            return self._restart(predicted, frame, lost=True, timings=timings, t0=t0)
        return self._finish(predicted, 0, matches, False, True, frame, timings, t0)

    def _restart(
        self,
        pose: NDArray[np.float64],
        frame: _Frame,
        *,
        lost: bool,
        timings: dict[str, float],
        t0: float,
        coasting: bool = False,
    ) -> OdometryResult:
        """Start the local map afresh from this frame at ``pose`` (a keyframe)."""
        pose = self.constrain(pose)
        self.local_map.clear()
        self.window.clear()
        self._retired.clear()
        self._candidates.clear()
        self._coasted = 0.0
        self._lost_frames = 0
        self._keyframe_pose = None
        self._insert_keyframe(pose, frame, np.zeros(0, np.intp), np.zeros(0, np.int64))
        result = self._finish(pose, 0, 0, True, lost, frame, timings, t0, coasting=coasting)
        result.map_restarted = True
        return result

    def relocalize(self, result: OdometryResult, pose: NDArray[np.float64]) -> OdometryResult:
        """Put a lost frame back on the map at ``pose`` (found by the loop-closure side) and restart tracking
        from it: the local map is re-seeded with this frame's points at the corrected pose."""
        self._adjustment_pending = False  # the window it would adjust is dropped
        self._insertion_pending = None
        self.pose = self.constrain(np.asarray(pose, np.float64)).copy()
        self._velocity = np.eye(4)
        self.local_map.clear()
        self.window.clear()
        self._retired.clear()
        self._candidates.clear()
        world = result.points3d.astype(np.float64) @ self.pose[:3, :3].T + self.pose[:3, 3]
        ids = self.local_map.add(world, result.descriptors, self.frames)
        self.window.append(
            _WindowKeyframe(
                pose=self.pose.copy(),
                landmarks=ids,
                pixels=result.keypoints.astype(np.float64),
                depths=result.points3d[:, 2].astype(np.float64),
                scales=np.ones(len(ids)),
                prior=self._previous_prior,
            )
        )
        self._keyframe_pose = self.pose.copy()
        self._keyframe_tracked = len(result.points3d)
        self._lost_frames = 0
        result.pose = self.pose.copy()
        result.lost = False
        return result

    def _finish(
        self,
        pose: NDArray[np.float64],
        inliers: int,
        matches: int,
        is_keyframe: bool,
        lost: bool,
        frame: _Frame,
        timings: dict[str, float],
        t0: float,
        *,
        coasting: bool = False,
    ) -> OdometryResult:
        pose = orthonormalized(self.constrain(pose))
        self._velocity = invert(self.pose) @ pose
        self.pose = pose
        self._previous_prior = frame.prior
        timings["total"] = (time.perf_counter() - t0) * 1e3
        valid = frame.valid
        return OdometryResult(
            pose=pose.copy(),
            inliers=inliers,
            matches=matches,
            is_keyframe=is_keyframe,
            lost=lost,
            timings=timings,
            keypoints=frame.features.keypoints[valid],
            points3d=frame.points[valid].astype(np.float32),
            descriptors=frame.features.descriptors[valid],
            responses=frame.features.responses[valid],
            coasting=coasting,
        )


@dataclass
class _Frame:
    """One frame's features and their 3D points."""

    features: Features
    points: NDArray[np.float64]
    """(N, 3) camera-frame points of the keypoints (valid where ``valid``)."""
    valid: NDArray[np.bool_]
    prior: NDArray[np.float64] | None
    depth: NDArray[np.float32]
    intensity: FrameIntensity | None = None
    """The smoothed image and its gradients (for the photometric term), when that term is on."""


@dataclass
class _Candidates:
    """A keyframe's keypoints without depth, waiting for the next keyframe to be triangulated with."""

    keyframe: _WindowKeyframe
    pixels: NDArray[np.float64]
    descriptors: NDArray[Any]
    scales: NDArray[np.float64]
    bearings: NDArray[np.int64]
    """The bearing landmark each keypoint already is (``far_landmarks``), −1 where none."""

    def remove(self, rows: NDArray[np.intp]) -> None:
        """Drop the candidates that became landmarks."""
        keep = np.ones(len(self.pixels), bool)
        keep[rows] = False
        self.pixels, self.descriptors, self.scales = self.pixels[keep], self.descriptors[keep], self.scales[keep]
        self.bearings = self.bearings[keep]


@dataclass
class _InsertionPending:
    """A frame that becomes a keyframe, waiting for local mapping to add it to the map and the window."""

    pose: NDArray[np.float64]
    frame: _Frame
    tracked: NDArray[np.intp]
    """Its keypoints that tracked a landmark."""
    tracked_ids: NDArray[np.int64]
    """Those landmarks."""


@dataclass
class _FusionPending:
    """The newest keyframe's features, waiting for the landmark fusion (``fuse_landmarks``)."""

    keyframe: _WindowKeyframe
    features: Features
    depths: NDArray[np.float64]
    """Measured depth of every keypoint, 0 where none."""
    observed: NDArray[np.intp]
    """The keypoints behind the keyframe's observations, in their order."""


@dataclass
class _Prediction:
    """Where the motion model puts the frame, and how far it may be off (metres, radians per axis)."""

    pose: NDArray[np.float64]
    std: tuple[float, float]
    from_wheels: bool


def _chi2(
    T_cw: NDArray[np.float64],
    points: NDArray[np.float64],
    pixels: NDArray[np.float64],
    pixel_std: NDArray[np.float64],
    depths: NDArray[np.float64],
    depth_noise: float,
    camera_matrix: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Whitened squared residual (reprojection, and depth where measured) of each point at a pose."""
    k = camera_matrix
    p = points @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = np.maximum(p[:, 2], 1e-6)
    du = (k[0, 0] * p[:, 0] / z + k[0, 2] - pixels[:, 0]) / pixel_std
    dv = (k[1, 1] * p[:, 1] / z + k[1, 2] - pixels[:, 1]) / pixel_std
    dz = np.where(depths > 0, (p[:, 2] - depths) / (depth_noise * depths**2 + 1e-3), 0.0)
    return np.where(p[:, 2] > 1e-6, du**2 + dv**2 + dz**2, np.inf)
