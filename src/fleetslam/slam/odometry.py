"""Frame-to-local-map RGB-D visual odometry (RTAB-Map's F2M strategy), pure: arrays in, pose out.

Each frame: features are detected and matched by descriptor to the local map (3D points in the odometry
frame from recent keyframes); the pose is estimated by PnP RANSAC seeded with a motion prediction (constant
velocity, or the change of the wheel-odometry prior) and refined by Levenberg–Marquardt on the inliers.
A frame becomes a keyframe when the inlier count drops below a ratio of the last keyframe's features or it
moved far enough; its features with valid depth then join the local map (the oldest points leave first).
When tracking is lost, the pose follows the prior (or constant velocity) and the local map restarts from
the current frame, so a texture-less wall does not break the trajectory.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics
from fleetslam.geometry import invert, planar_camera_pose, rotation_angle
from fleetslam.slam.config import FeatureConfig, OdometryConfig
from fleetslam.slam.features import FeatureExtractor, Features, import_cv2
from fleetslam.slam.matching import match_by_projection, match_ratio
from fleetslam.slam.pose_refinement import planar_basis, refine_pose_with_prior

logger = logging.getLogger(__name__)


@dataclass
class OdometryResult:
    """Outcome of :meth:`VisualOdometry.track`."""

    pose: NDArray[np.float64]
    """``T_world_camera`` in the odometry frame."""
    inliers: int
    """PnP inliers (0 when lost)."""
    matches: int
    """Descriptor matches against the local map."""
    is_keyframe: bool
    lost: bool
    timings: dict[str, float] = field(default_factory=dict)
    """Milliseconds per step (features, match, pnp, update, total)."""
    keypoints: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    """Keypoints with valid depth (for the loop-closure side on keyframes)."""
    points3d: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    """Their 3D points in the camera frame."""
    descriptors: NDArray[Any] = field(default_factory=lambda: np.zeros((0, 32), np.uint8))


def backproject(
    keypoints: NDArray[np.float32],
    depth: NDArray[np.float32],
    intrinsics: Intrinsics,
    min_depth: float,
    max_depth: float,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """3D points (camera frame) of keypoints from the nearest depth pixel, and which are valid."""
    h, w = depth.shape
    u = np.clip(np.rint(keypoints[:, 0]).astype(np.intp), 0, w - 1)
    v = np.clip(np.rint(keypoints[:, 1]).astype(np.intp), 0, h - 1)
    z = depth[v, u].astype(np.float64)
    valid = np.isfinite(z) & (z > min_depth) & (z < max_depth)
    x = (keypoints[:, 0] - intrinsics.cx) * z / intrinsics.fx
    y = (keypoints[:, 1] - intrinsics.cy) * z / intrinsics.fy
    return np.stack([x, y, z], axis=1), valid


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
    """3D points (odometry frame) with descriptors, oldest first, capped in size."""

    def __init__(self, max_size: int) -> None:
        self.max_size = max_size
        self.points = np.zeros((0, 3))
        self.descriptors: NDArray[Any] | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def clear(self) -> None:
        self.points = np.zeros((0, 3))
        self.descriptors = None

    def add(self, points: NDArray[np.float64], descriptors: NDArray[Any]) -> None:
        if len(points) == 0:
            return
        if self.descriptors is None:
            self.points, self.descriptors = points.copy(), descriptors.copy()
        else:
            self.points = np.vstack([self.points, points])
            self.descriptors = np.vstack([self.descriptors, descriptors])
        excess = len(self.points) - self.max_size
        if excess > 0:
            self.points = self.points[excess:]
            self.descriptors = self.descriptors[excess:]


class VisualOdometry:
    """RGB-D frame-to-local-map odometry. ``track`` is called once per frame, in order."""

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
        self.extractor = FeatureExtractor(
            fc.kind, fc.max_features, fc.grid_rows, fc.grid_cols, fc.orb_fast_threshold, fc.orb_levels
        )
        self._K = intrinsics.K
        self.local_map = LocalMap(config.local_map_size)
        self.pose = np.eye(4)
        self._velocity = np.eye(4)
        """Motion of the last frame, ``T_previous_current``."""
        self._previous_prior: NDArray[np.float64] | None = None
        self._keyframe_pose: NDArray[np.float64] | None = None
        self._keyframe_features = 0
        self.frames = 0
        self.base_camera = base_camera
        self._last_stamp: float | None = None
        self._frame_interval = 1.0 / 30.0

    def _predict(self, prior: NDArray[np.float64] | None) -> NDArray[np.float64]:
        if prior is not None and self._previous_prior is not None and self.config.use_prior:
            return self.pose @ invert(self._previous_prior) @ prior
        return self.pose @ self._velocity

    def track(
        self, rgb: NDArray[np.uint8], depth: NDArray[np.float32], stamp: float, prior: NDArray[np.float64] | None = None
    ) -> OdometryResult:
        """Estimate ``T_world_camera`` of this frame.

        Args:
            rgb: ``(H, W, 3)`` uint8 colour image (or ``(H, W)`` grayscale).
            depth: ``(H, W)`` float32 metres registered to ``rgb`` (0 = invalid).
            stamp: capture time in seconds (logged only; prediction is per frame).
            prior: optional pose of this frame from wheel odometry (any fixed frame).
        """
        cv2 = import_cv2()
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
        predicted = self._predict(prior)
        if self._last_stamp is not None and 0.0 < stamp - self._last_stamp < 1.0:
            self._frame_interval = stamp - self._last_stamp
        self._last_stamp = stamp
        prior_arr = None if prior is None else np.asarray(prior, dtype=np.float64)

        if self.frames == 0 or len(self.local_map) == 0:
            self.frames += 1
            pose = predicted if self.frames > 1 else self.pose
            return self._finish(
                pose, 0, 0, True, self.frames > 1, feats, points_cam, valid, None, prior_arr, timings, t0
            )

        matched_frame, matched_map = self._match(feats, predicted)
        if len(matched_frame) < 2 * self.config.min_inliers:
            # The prediction may be wrong (a bump, a slip): search the whole image instead.
            matched_frame, matched_map = self._match(feats, None)
        t2 = time.perf_counter()
        timings["match"] = (t2 - t1) * 1e3
        solved, inlier_index = self._solve(feats, matched_frame, matched_map, predicted)
        t3 = time.perf_counter()
        timings["pnp"] = (t3 - t2) * 1e3
        self.frames += 1
        n_inliers = len(inlier_index)
        if solved is not None and not self._consistent(solved, predicted):
            logger.debug("odometry at %.3f: PnP pose far from the prediction, rejected", stamp)
            solved = None
        if solved is None or n_inliers < self.config.min_inliers:
            logger.debug("odometry lost at %.3f: %d inliers", stamp, n_inliers)
            return self._finish(
                predicted,
                n_inliers,
                len(matched_frame),
                True,
                True,
                feats,
                points_cam,
                valid,
                None,
                prior_arr,
                timings,
                t0,
            )
        is_keyframe = self._needs_keyframe(solved, n_inliers)
        used = matched_frame[inlier_index]
        return self._finish(
            solved,
            n_inliers,
            len(matched_frame),
            is_keyframe,
            False,
            feats,
            points_cam,
            valid,
            used,
            prior_arr,
            timings,
            t0,
        )

    def constrain(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """The pose projected onto the robot's plane of motion when ``planar_motion`` is on (and the mounting
        known); otherwise unchanged."""
        if not self.config.planar_motion or self.base_camera is None:
            return pose
        return planar_camera_pose(pose, self.base_camera)

    def relocalize(self, result: OdometryResult, pose: NDArray[np.float64]) -> OdometryResult:
        """Put a lost frame back on the map at ``pose`` (found by the loop-closure side) and restart tracking
        from it: the local map is re-seeded with this frame's points at the corrected pose."""
        self.pose = self.constrain(np.asarray(pose, np.float64)).copy()
        self._velocity = np.eye(4)
        self.local_map.clear()
        world = result.points3d.astype(np.float64) @ self.pose[:3, :3].T + self.pose[:3, 3]
        self.local_map.add(world, result.descriptors)
        self._keyframe_pose = self.pose.copy()
        self._keyframe_features = len(result.points3d)
        result.pose = self.pose.copy()
        result.lost = False
        return result

    def _match(
        self, feats: Features, predicted: NDArray[np.float64] | None
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Ratio-test matches frame → local map; with a predicted pose only within ``search_radius`` pixels of
        where each map point should appear (repetitive texture such as floor tiles then cannot mismatch)."""
        if len(feats) < 2 or self.local_map.descriptors is None or len(self.local_map) < 2:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        if predicted is not None:
            T_cw = invert(predicted)
            cam = self.local_map.points @ T_cw[:3, :3].T + T_cw[:3, 3]
            front = np.flatnonzero(cam[:, 2] > self.config.min_depth)
            z = cam[front, 2]
            projected = np.stack(
                [
                    self.intrinsics.fx * cam[front, 0] / z + self.intrinsics.cx,
                    self.intrinsics.fy * cam[front, 1] / z + self.intrinsics.cy,
                ],
                axis=1,
            )
            q, t = match_by_projection(
                feats.keypoints,
                feats.descriptors,
                projected,
                self.local_map.descriptors[front],
                self.config.search_radius,
                self.config.match_ratio,
                self.config.max_descriptor_distance if self.extractor.binary else 0.0,
            )
            return q, front[t]
        return match_ratio(feats.descriptors, self.local_map.descriptors, self.config.match_ratio)

    def _solve(
        self,
        feats: Features,
        matched_frame: NDArray[np.intp],
        matched_map: NDArray[np.intp],
        predicted: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.intp]]:
        cv2 = import_cv2()
        if len(matched_frame) < max(6, self.config.min_inliers):
            return None, np.zeros(0, np.intp)
        object_points = self.local_map.points[matched_map].astype(np.float64)
        image_points = feats.keypoints[matched_frame].astype(np.float64)
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
            reprojectionError=self.config.pnp_reprojection_error,
            confidence=0.99,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not ok or inliers is None or len(inliers) < 4:
            return None, np.zeros(0, np.intp)
        index = inliers.reshape(-1).astype(np.intp)
        if self.config.motion_prior_acceleration <= 0:
            rvec, tvec = cv2.solvePnPRefineLM(object_points[index], image_points[index], self._K, None, rvec, tvec)
            return invert(_from_rvec_tvec(rvec, tvec)), index
        # How far the motion can depart from the prediction within one frame interval: ½·a·Δt².
        half_dt2 = 0.5 * self._frame_interval**2
        start = _from_rvec_tvec(rvec, tvec)
        basis = None
        if self.config.planar_motion and self.base_camera is not None:
            start = invert(self.constrain(invert(start)))
            basis = planar_basis(self.base_camera)
        T_cw, _ = refine_pose_with_prior(
            start,
            object_points[index],
            image_points[index],
            self._K,
            invert(predicted),
            (
                self.config.motion_prior_acceleration * half_dt2,
                self.config.motion_prior_angular_acceleration * half_dt2,
            ),
            huber_px=self.config.pnp_reprojection_error,
            gate=self.config.motion_prior_gate,
            basis=basis,
        )
        return invert(T_cw), index

    def _consistent(self, pose: NDArray[np.float64], predicted: NDArray[np.float64]) -> bool:
        error = invert(predicted) @ pose
        return bool(
            np.linalg.norm(error[:3, 3]) <= self.config.max_prediction_error
            and np.degrees(rotation_angle(error)) <= self.config.max_prediction_error_deg
        )

    def _needs_keyframe(self, pose: NDArray[np.float64], inliers: int) -> bool:
        if self._keyframe_pose is None:
            return True
        if inliers < self.config.keyframe_inlier_ratio * self._keyframe_features:
            return True
        motion = invert(self._keyframe_pose) @ pose
        return bool(
            np.linalg.norm(motion[:3, 3]) > self.config.keyframe_translation
            or np.degrees(rotation_angle(motion)) > self.config.keyframe_rotation_deg
        )

    def _finish(
        self,
        pose: NDArray[np.float64],
        inliers: int,
        matches: int,
        is_keyframe: bool,
        lost: bool,
        feats: Features,
        points_cam: NDArray[np.float64],
        valid: NDArray[np.bool_],
        matched_inliers: NDArray[np.intp] | None,
        prior: NDArray[np.float64] | None,
        timings: dict[str, float],
        t0: float,
    ) -> OdometryResult:
        t_update = time.perf_counter()
        pose = self.constrain(pose)
        self._velocity = invert(self.pose) @ pose
        self.pose = pose
        self._previous_prior = prior
        if lost:
            # Restart the local map here: old points cannot be matched, and keeping them would only
            # pull the next PnP towards the wrong pose.
            self.local_map.clear()
        if is_keyframe:
            new = valid.copy()
            if matched_inliers is not None:
                new[matched_inliers] = False
            world = points_cam[new] @ pose[:3, :3].T + pose[:3, 3]
            self.local_map.add(world, feats.descriptors[new])
            self._keyframe_pose = pose.copy()
            self._keyframe_features = int(valid.sum())
        timings["update"] = (time.perf_counter() - t_update) * 1e3
        timings["total"] = (time.perf_counter() - t0) * 1e3
        return OdometryResult(
            pose=pose.copy(),
            inliers=inliers,
            matches=matches,
            is_keyframe=is_keyframe,
            lost=lost,
            timings=timings,
            keypoints=feats.keypoints[valid],
            points3d=points_cam[valid].astype(np.float32),
            descriptors=feats.descriptors[valid],
        )


def make_odometry(
    config: OdometryConfig,
    features: FeatureConfig,
    intrinsics: Intrinsics,
    base_camera: NDArray[np.float64] | None = None,
) -> VisualOdometry:
    """Build the odometry from configuration."""
    return VisualOdometry(config, intrinsics, features, base_camera)
