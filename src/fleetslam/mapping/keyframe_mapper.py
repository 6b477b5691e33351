"""Occupancy mapping from SLAM keyframes that follows the optimised graph.

Each keyframe contributes one scan: its depth image back-projected to points in the camera frame, inserted
from the camera centre at the keyframe's pose, keyframes in id order. The map is always the one that inserting
every keyframe at its integrated pose gives, and the work is incremental: a new keyframe is inserted once; when the
graph is re-optimised (a loop closure moves poses), only the keyframes whose scan moved by more than a tolerance (a
fraction of a voxel) are integrated again at their new pose. Their voxels, where they saw them before and now, are
computed afresh by replaying, in id order, every scan's rays that cross their boxes (no other ray reaches those
voxels), restricted to those voxels: the result is exactly the map rebuilt from every keyframe, without
re-inserting the others. When the replay would cost more than a rebuild (most keyframes moved), the map is rebuilt
instead. So a wall seen before and after a loop never appears twice. Pure: arrays in, an octree out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import transform_points
from fleetslam.intrinsics import pinhole_problem
from fleetslam.mapping import _kernels as K
from fleetslam.mapping.config import MappingConfig, make_octree
from fleetslam.mapping.keys import TREE_MAX_VAL
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.mapping.voxel_table import VoxelTable


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
    """Camera-frame points (x right, y down, z forward) of every ``stride``-th pixel with a valid depth. Raises
    ValueError, naming the values, for focal lengths that are not positive and finite or a principal point that is
    not finite (a hostile or broken camera_info: its points would all be infinite, or mirrored)."""
    if problem := pinhole_problem(fx, fy, cx, cy):
        raise ValueError(f"camera intrinsics: {problem}")
    depth = np.asarray(depth_m, dtype=np.float32)[::stride, ::stride]
    vs, us = np.mgrid[0 : depth_m.shape[0] : stride, 0 : depth_m.shape[1] : stride]
    valid = np.isfinite(depth) & (depth >= min_depth) & (depth <= max_depth)
    z = depth[valid]
    x = (us[valid] - cx) / fx * z
    y = (vs[valid] - cy) / fy * z
    return np.stack([x, y, z], axis=1).astype(np.float32)


ScanKeys = tuple[NDArray[np.uint64], NDArray[np.uint64]]
"""A scan's packed free and occupied keys."""


@dataclass
class _KeyframeScan:
    points_camera: NDArray[np.float32]
    pose: NDArray[np.float64]
    reach: float
    """Distance of its farthest point from the camera (m): a rotation by θ moves no point further than 2·sin(θ/2)
    times this."""
    integrated_pose: NDArray[np.float64] | None = None
    box: NDArray[np.int64] | None = None
    """Smallest and largest key (2×3) of the voxels it updated at its integrated pose."""


def scan_displacement(before: NDArray[np.floating], after: NDArray[np.floating], reach: float) -> float:
    """Upper bound of how far a point within ``reach`` of the camera moves when the camera pose (T_map_camera)
    changes from ``before`` to ``after``: |Δt| + 2·sin(θ/2)·reach, θ the rotation between them."""
    return float(_displacements(np.asarray(before)[None], np.asarray(after)[None], np.array([reach]))[0])


def _displacements(
    before: NDArray[np.floating], after: NDArray[np.floating], reach: NDArray[np.floating]
) -> NDArray[np.float64]:
    shift = np.linalg.norm(after[:, :3, 3] - before[:, :3, 3], axis=1)
    # |R_a - R_b| applied to a point of norm r is 2·sin(θ/2)·r, θ the angle of R_bᵀ·R_a: cos θ = (trace - 1) / 2.
    trace = np.einsum("nij,nij->n", before[:, :3, :3], after[:, :3, :3])
    half_angle_sin = np.sqrt(np.clip((3.0 - trace) / 4.0, 0.0, 1.0))  # sin²(θ/2) = (1 - cos θ) / 2
    return np.asarray(shift + 2.0 * half_angle_sin * reach, dtype=np.float64)


def _scan_box(points: NDArray[np.floating], origin: NDArray[np.floating], resolution: float) -> NDArray[np.int64]:
    """Smallest and largest key (2×3) that a scan's rays may update: the box of its origin and points, one voxel
    wider for the ray walk's round-off."""
    corners = np.vstack([origin[None], points]) if len(points) else origin[None]
    lo = np.floor((corners.min(axis=0) - resolution) / resolution) + TREE_MAX_VAL
    hi = np.floor((corners.max(axis=0) + resolution) / resolution) + TREE_MAX_VAL
    return np.clip(np.stack([lo, hi]), 0, 2 * TREE_MAX_VAL - 1).astype(np.int64)


def _rays_through(
    points: NDArray[np.floating], origin: NDArray[np.floating], boxes: NDArray[np.int64], resolution: float
) -> NDArray[np.bool_]:
    """Which rays (origin → point segments) cross any of the key boxes (widened by a voxel): the only rays of a
    scan that can update a voxel in them."""
    lows = (boxes[:, 0] - TREE_MAX_VAL - 1) * resolution
    highs = (boxes[:, 1] - TREE_MAX_VAL + 2) * resolution
    return np.asarray(
        K.rays_crossing_boxes(np.ascontiguousarray(points, np.float64), np.asarray(origin, np.float64), lows, highs)
    )


@dataclass
class KeyframeMapper:
    """Keeps every keyframe's scan and integrates them into an octree at their current poses.

    Args:
        config: resolution and sensor model.
        move_tolerance: a keyframe whose scan moved more than this (m, bound on any of its points) after
            optimisation is integrated again; None: half the resolution.
        rebuild_fraction: when replaying the rays that reach the moved keyframes' voxels would cost more than this
            fraction of inserting every keyframe again, the map is rebuilt instead.
    """

    config: MappingConfig = field(default_factory=MappingConfig)
    move_tolerance: float | None = None
    rebuild_fraction: float = 1.0
    scans: dict[int, _KeyframeScan] = field(default_factory=dict)
    inserted: int = 0
    """Scans inserted into the map so far (new keyframes and rebuilds)."""
    reintegrated: int = 0
    """Moved keyframes integrated again at their new pose without a rebuild."""
    replayed: int = 0
    """Scans replayed over the moved keyframes' voxels."""
    rebuilds: int = 0
    """Times the whole map was rebuilt because that was cheaper."""
    _tree: OccupancyOctree | None = None
    _moved: dict[int, ScanKeys | None] = field(default_factory=dict)
    """Keyframes to integrate again, with the keys they had before when their scan itself was replaced."""
    _graph_poses: dict[int, NDArray[np.float64]] = field(default_factory=dict)
    """Optimised poses of keyframes not received yet (the graph may overtake its keyframes)."""

    @property
    def tree(self) -> OccupancyOctree:
        if self._tree is None:
            self._tree = make_octree(self.config, track_changes=False)
        return self._tree

    @property
    def tolerance(self) -> float:
        return self.config.resolution / 2 if self.move_tolerance is None else self.move_tolerance

    def _pose_is_valid(self, pose: NDArray[np.floating]) -> bool:
        """A finite 4×4 rigid transform whose origin lies inside the octree's key range."""
        matrix = np.asarray(pose, dtype=np.float64)
        if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
            return False
        rotation = matrix[:3, :3]
        rigid = np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3) and np.linalg.det(rotation) > 0
        inside = bool(np.abs(matrix[:3, 3]).max() < self.config.resolution * TREE_MAX_VAL)
        return bool(rigid) and inside

    def _checked_pose(self, keyframe_id: int, pose: NDArray[np.floating]) -> NDArray[np.float64]:
        if not self._pose_is_valid(pose):
            raise ValueError(f"keyframe {keyframe_id}: pose is not a finite rigid transform inside the map")
        return np.asarray(pose, dtype=np.float64)

    @property
    def pending(self) -> int:
        """Keyframes waiting to be inserted or integrated again."""
        return sum(1 for scan in self.scans.values() if scan.integrated_pose is None) + len(self._moved)

    def add_keyframe(self, keyframe_id: int, points_camera: NDArray[np.floating], pose: NDArray[np.floating]) -> None:
        """A new keyframe (points in its camera frame, pose T_map_camera); integrated by :meth:`integrate`.

        A pose the graph gave for it before it arrived is newer than its own and wins. A pose that is not a
        finite rigid transform inside the map raises ValueError (and changes nothing: one bad keyframe must not
        poison every later integration); points that are not finite are left out.
        """
        pose = self._checked_pose(keyframe_id, pose)
        points = np.asarray(points_camera, dtype=np.float32).reshape(-1, 3)
        points = points[np.isfinite(points).all(axis=1)]
        reach = float(np.sqrt((points.astype(np.float64) ** 2).sum(axis=1).max())) if len(points) else 0.0
        graph_pose = self._graph_poses.pop(keyframe_id, None)
        scan = _KeyframeScan(points, np.asarray(pose if graph_pose is None else graph_pose, dtype=np.float64), reach)
        previous = self.scans.get(keyframe_id)
        if previous is not None and previous.integrated_pose is not None:  # sent again: the new scan replaces it
            self._moved[keyframe_id] = self._moved.get(keyframe_id) or self._keys(
                *self._world_scan(previous, self._integrated_pose(keyframe_id))
            )
            scan.integrated_pose, scan.box = previous.integrated_pose, previous.box
        self.scans[keyframe_id] = scan

    def update_poses(self, poses: dict[int, NDArray[np.floating]], *, tolerance: float | None = None) -> int:
        """New (optimised) poses; returns how many integrated keyframes now wait to be integrated again because
        their scan moved beyond the tolerance (since it was integrated; ``tolerance`` instead of the mapper's for
        these poses). Raises ValueError naming the keyframes whose pose is not a finite rigid transform inside the
        map, before changing anything."""
        bad = [i for i, pose in poses.items() if not self._pose_is_valid(pose)]
        if bad:
            raise ValueError(f"graph poses of keyframes {bad[:10]} are not finite rigid transforms inside the map")
        integrated: list[int] = []
        for keyframe_id, pose in poses.items():
            scan = self.scans.get(keyframe_id)
            if scan is None:
                self._graph_poses[keyframe_id] = np.asarray(pose, dtype=np.float64)
                continue
            scan.pose = np.asarray(pose, dtype=np.float64)
            if scan.integrated_pose is not None:
                integrated.append(keyframe_id)
        if integrated:
            moved = _displacements(
                np.stack([self._integrated_pose(i) for i in integrated]),
                np.stack([self.scans[i].pose for i in integrated]),
                np.array([self.scans[i].reach for i in integrated]),
            )
            limit = self.tolerance if tolerance is None else tolerance
            for i, far in zip(integrated, (moved > limit).tolist(), strict=True):
                if far:
                    self._moved.setdefault(i, None)
                elif i in self._moved and self._moved[i] is None:  # moved back before it was integrated again
                    del self._moved[i]
        return len(self._moved)

    @property
    def moved(self) -> int:
        """Integrated keyframes waiting to be integrated again at their new pose."""
        return len(self._moved)

    def integrate(self, *, moved: bool = True) -> int:
        """Insert keyframes not yet in the map and, with ``moved``, integrate the moved ones again (or rebuild the
        map when that is cheaper); returns the number of scans inserted or replayed."""
        work = self._reintegrate() if moved and self._moved else 0
        inserted = 0
        for keyframe_id in sorted(self.scans):
            scan = self.scans[keyframe_id]
            if scan.integrated_pose is None:
                points, origin = self._world_scan(scan, scan.pose)
                self.tree.apply_update(*self._keys(points, origin))
                scan.integrated_pose, scan.box = scan.pose.copy(), _scan_box(points, origin, self.config.resolution)
                inserted += 1
        self.inserted += inserted
        return work + inserted

    def _reintegrate(self) -> int:
        """The moved keyframes' voxels (before and now) computed afresh from every ray that may touch them."""
        moved = sorted(self._moved)
        old = {i: keys or self._keys(*self._world_scan(self.scans[i], self._integrated_pose(i)))
               for i, keys in self._moved.items()}  # fmt: skip
        self._moved.clear()
        new_scans = {i: self._world_scan(self.scans[i], self.scans[i].pose) for i in moved}
        new = {i: self._keys(*scan) for i, scan in new_scans.items()}
        boxes = np.stack(
            [self._box_of(i) for i in moved] + [_scan_box(*new_scans[i], self.config.resolution) for i in moved]
        )
        # Every other scan's rays that cross the moved scans' boxes (before and now): only they reach those voxels.
        others = [i for i, scan in self.scans.items() if scan.box is not None and i not in new]
        if others:
            own = np.stack([self._box_of(i) for i in others])
            overlap = ((own[:, None, 0] <= boxes[None, :, 1]) & (own[:, None, 1] >= boxes[None, :, 0])).all(axis=2)
            others = [i for i, hit in zip(others, np.any(overlap, axis=1).tolist(), strict=True) if hit]
        # Work in rays: a rebuild inserts every scan's; a replay traces the moved scans' twice, then of the other
        # scans that overlap only the rays that cross the moved scans' boxes, and looks up and assigns their voxels
        # (about twice the cost of an insertion per ray).
        total = sum(len(scan.points_camera) for scan in self.scans.values() if scan.integrated_pose is not None)
        budget = self.rebuild_fraction * total / 2
        replay = 2 * sum(len(self.scans[i].points_camera) for i in moved)
        rays: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        for i in others:
            if replay > budget:
                break
            points, origin = self._world_scan(self.scans[i], self._integrated_pose(i))
            if not self.config.discretize:  # (merging endpoints needs the whole scan)
                points = points[_rays_through(points, origin, boxes, self.config.resolution)]
            if len(points):
                rays[i] = (points, origin)
                replay += len(points)
        if replay > budget:
            self._tree = None
            for scan in self.scans.values():
                scan.integrated_pose = scan.box = None
            self.rebuilds += 1
            return 0  # integrate() inserts them all
        member = VoxelTable()
        for keys in (*old.values(), *new.values()):
            member.set(np.concatenate(keys), np.zeros(sum(len(k) for k in keys), np.float32))
        voxels, _ = member.items()
        scratch = make_octree(self.config, track_changes=False)
        for i in sorted([*rays, *moved]):
            free, occupied = new[i] if i in new else self._keys(*rays[i])
            scratch.apply_update(free[~np.isnan(member.get(free))], occupied[~np.isnan(member.get(occupied))])
        self.tree.assign(voxels, scratch.voxel_log_odds(voxels))
        for i in moved:
            scan = self.scans[i]
            scan.integrated_pose, scan.box = scan.pose.copy(), _scan_box(*new_scans[i], self.config.resolution)
        self.reintegrated += len(moved)
        self.replayed += len(rays) + len(moved)
        return len(rays) + len(moved)

    def _integrated_pose(self, keyframe_id: int) -> NDArray[np.float64]:
        pose = self.scans[keyframe_id].integrated_pose
        assert pose is not None
        return pose

    def _box_of(self, keyframe_id: int) -> NDArray[np.int64]:
        box = self.scans[keyframe_id].box
        assert box is not None
        return box

    def _world_scan(
        self, scan: _KeyframeScan, pose: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The scan's points in the map frame at a pose (the nearer than ``min_range`` dropped), and its origin."""
        points = transform_points(pose, scan.points_camera)
        origin = pose[:3, 3]
        if self.config.min_range > 0 and len(points):
            points = points[np.linalg.norm(points - origin, axis=1) >= self.config.min_range]
        return points, origin

    def _keys(self, points: NDArray[np.float64], origin: NDArray[np.float64]) -> ScanKeys:
        return self.tree.compute_update(
            points, origin, max_range=self.config.max_range, discretize=self.config.discretize
        )

    def reset(self) -> None:
        self.scans.clear()
        self._tree = None
        self._moved.clear()
        self._graph_poses.clear()
