"""Occupancy mapping from SLAM keyframes that follows the optimised graph.

Each keyframe contributes one scan: its depth image back-projected to points in the camera frame, inserted
from the camera centre at the keyframe's pose. When the graph is re-optimised (a loop closure moves poses), the
keyframes whose pose moved more than a tolerance make the map stale, and it is rebuilt from every keyframe at its
new pose, so a wall seen before and after the loop never appears twice. Pure: arrays in, an octree out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import rotation_angle, transform_points, translation_distance
from fleetslam.mapping.config import MappingConfig, make_octree
from fleetslam.mapping.octree import OccupancyOctree


def depth_to_points(
    depth_m: NDArray[np.floating],
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    *,
    stride: int = 4,
    min_depth: float = 0.3,
    max_depth: float = 6.0,
) -> NDArray[np.float32]:
    """Camera-frame points (x right, y down, z forward) of every ``stride``-th pixel with a valid depth."""
    depth = np.asarray(depth_m, dtype=np.float32)[::stride, ::stride]
    vs, us = np.mgrid[0 : depth_m.shape[0] : stride, 0 : depth_m.shape[1] : stride]
    valid = np.isfinite(depth) & (depth >= min_depth) & (depth <= max_depth)
    z = depth[valid]
    x = (us[valid] - cx) / fx * z
    y = (vs[valid] - cy) / fy * z
    return np.stack([x, y, z], axis=1).astype(np.float32)


@dataclass
class _KeyframeScan:
    points_camera: NDArray[np.float32]
    pose: NDArray[np.float64]
    integrated_pose: NDArray[np.float64] | None = None


@dataclass
class KeyframeMapper:
    """Keeps every keyframe's scan and integrates them into an octree at their current poses.

    Args:
        config: resolution and sensor model.
        rebuild_translation: a keyframe that moved more than this (m) after optimisation triggers a rebuild.
        rebuild_rotation: same for rotation (rad).
    """

    config: MappingConfig = field(default_factory=MappingConfig)
    rebuild_translation: float = 0.02
    rebuild_rotation: float = 0.01
    scans: dict[int, _KeyframeScan] = field(default_factory=dict)
    rebuilds: int = 0
    _tree: OccupancyOctree | None = None
    _stale: bool = False

    @property
    def tree(self) -> OccupancyOctree:
        if self._tree is None:
            self._tree = make_octree(self.config)
        return self._tree

    def add_keyframe(self, keyframe_id: int, points_camera: NDArray[np.floating], pose: NDArray[np.floating]) -> None:
        """A new keyframe (points in its camera frame, pose T_map_camera); integrated by :meth:`integrate`."""
        self.scans[keyframe_id] = _KeyframeScan(
            np.asarray(points_camera, dtype=np.float32).reshape(-1, 3), np.asarray(pose, dtype=np.float64)
        )

    def update_poses(self, poses: dict[int, NDArray[np.floating]]) -> int:
        """New (optimised) poses; returns how many integrated keyframes moved beyond the tolerance."""
        moved = 0
        for keyframe_id, pose in poses.items():
            scan = self.scans.get(keyframe_id)
            if scan is None:
                continue
            scan.pose = np.asarray(pose, dtype=np.float64)
            if scan.integrated_pose is not None and (
                translation_distance(scan.pose, scan.integrated_pose) > self.rebuild_translation
                or rotation_angle(np.linalg.inv(scan.integrated_pose) @ scan.pose) > self.rebuild_rotation
            ):
                moved += 1
        if moved:
            self._stale = True
        return moved

    def integrate(self) -> int:
        """Insert keyframes not yet in the map (or rebuild it if poses moved); returns scans inserted."""
        if self._stale:
            self._tree = make_octree(self.config)
            for scan in self.scans.values():
                scan.integrated_pose = None
            self._stale = False
            self.rebuilds += 1
        inserted = 0
        for keyframe_id in sorted(self.scans):
            scan = self.scans[keyframe_id]
            if scan.integrated_pose is not None:
                continue
            points = transform_points(scan.pose, scan.points_camera)
            origin = scan.pose[:3, 3]
            if self.config.min_range > 0 and len(points):
                keep = np.linalg.norm(points - origin, axis=1) >= self.config.min_range
                points = points[keep]
            self.tree.insert_point_cloud(
                points, origin, max_range=self.config.max_range, discretize=self.config.discretize
            )
            scan.integrated_pose = scan.pose.copy()
            inserted += 1
        return inserted

    def reset(self) -> None:
        self.scans.clear()
        self._tree = None
        self._stale = False
