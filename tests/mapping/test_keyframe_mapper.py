from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from fleetslam.geometry import T_BODY_OPTICAL, invert, make_pose, pose_from_planar, so3_exp, transform_points
from fleetslam.mapping.config import MappingConfig
from fleetslam.mapping.keyframe_mapper import KeyframeMapper, _rays_through, depth_to_points, scan_displacement
from fleetslam.mapping.octree import OccupancyOctree


def _wall_depth(distance: float, width: int = 64, height: int = 48) -> np.ndarray:
    return np.full((height, width), distance, np.float32)


def test_depth_to_points_back_projects_a_flat_wall() -> None:
    depth = _wall_depth(2.0)
    depth[0, 0] = np.nan
    points = depth_to_points(depth, 50.0, 50.0, 32.0, 24.0, stride=2)
    assert np.allclose(points[:, 2], 2.0)
    assert points[:, 0].min() < 0 < points[:, 0].max()  # x to the right of the optical axis and left of it
    assert len(points) == 32 * 24 - 1


@pytest.mark.parametrize(
    ("fx", "fy", "cx"), [(0.0, 50.0, 32.0), (50.0, -50.0, 32.0), (float("nan"), 50.0, 32.0), (50.0, 50.0, float("inf"))]
)
def test_depth_to_points_refuses_intrinsics_that_are_not_a_camera(fx: float, fy: float, cx: float) -> None:
    with pytest.raises(ValueError, match=f"fx={fx}, fy={fy}, cx={cx}"):
        depth_to_points(_wall_depth(2.0), fx, fy, cx, 24.0, stride=2)


def test_map_follows_reoptimised_poses_without_doubled_walls() -> None:
    mapper = KeyframeMapper(MappingConfig(resolution=0.1))
    points = depth_to_points(_wall_depth(2.0), 50.0, 50.0, 32.0, 24.0, stride=2)
    camera = T_BODY_OPTICAL.copy()
    camera[2, 3] = 0.5
    drifted = pose_from_planar(-0.3, 0.0, 0.0) @ camera  # odometry drifted: it believes it is 0.3 m further back
    mapper.add_keyframe(0, points, camera)
    mapper.add_keyframe(1, points, drifted)
    assert mapper.integrate() == 2
    # Drift doubled the wall: at x = 2.0 from keyframe 0 and at x = 1.7 from keyframe 1.
    assert mapper.tree.is_occupied([2.05, 0.05, 0.55]) and mapper.tree.is_occupied([1.75, 0.05, 0.55])
    moved = mapper.update_poses({1: camera})  # the loop closure puts keyframe 1 back where it was
    assert moved == 1
    mapper.integrate()
    assert mapper.rebuilds == 1
    assert not mapper.tree.is_occupied([1.75, 0.05, 0.55])
    assert mapper.tree.is_occupied([2.05, 0.05, 0.55])
    assert mapper.update_poses({0: camera}) == 0  # not moved: no rebuild


def _room_keyframe(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points of a room's walls (x = ±2, y = ±2, z 0..1.2) seen from a random camera pose inside."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-0.5, 0.5, 2)
    camera = pose_from_planar(x, y, rng.uniform(-np.pi, np.pi)) @ T_BODY_OPTICAL
    camera[2, 3] = 0.5
    angles, heights = rng.uniform(0, 2 * np.pi, 500), rng.uniform(0.0, 1.2, 500)
    direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    origin = camera[:2, 3]
    t = np.min(np.where(np.abs(direction) > 1e-9, (2.0 - np.sign(direction) * origin) / np.abs(direction), 1e9),
               axis=1)  # fmt: skip
    world = np.column_stack([origin + direction * t[:, None], heights])
    return transform_points(invert(camera), world).astype(np.float32), camera


def _fresh(keyframes: dict[int, tuple[np.ndarray, np.ndarray]], **options: float) -> KeyframeMapper:
    mapper = KeyframeMapper(MappingConfig(resolution=0.1), **options)  # type: ignore[arg-type]
    for i, (points, pose) in keyframes.items():
        mapper.add_keyframe(i, points, pose)
    mapper.integrate()
    return mapper


def _same_map(a: OccupancyOctree, b: OccupancyOctree) -> None:
    la, lb = a.leaves(), b.leaves()
    np.testing.assert_array_equal(la.keys, lb.keys)
    np.testing.assert_array_equal(la.depths, lb.depths)
    np.testing.assert_array_equal(la.log_odds, lb.log_odds)


def test_moved_keyframes_are_integrated_again_and_the_map_is_the_rebuilt_one() -> None:
    """Twelve keyframes of one room: voxels get up to twelve updates, clamped after five in a row; the voxels of
    the moved keyframes are replayed from every scan in id order, so the map is exactly the rebuilt one."""
    keyframes = {i: _room_keyframe(i) for i in range(12)}
    mapper = _fresh(keyframes, rebuild_fraction=np.inf)
    moved = {i: (points, pose_from_planar(0.15, -0.1, 0.05) @ pose) for i, (points, pose) in keyframes.items()
             if i in (3, 8)}  # fmt: skip
    assert mapper.update_poses({0: keyframes[0][1], **{i: pose for i, (_, pose) in moved.items()}}) == 2
    assert mapper.pending == 2
    assert mapper.integrate() == 12  # the room's scans all overlap the moved ones: all replayed
    assert (mapper.inserted, mapper.reintegrated, mapper.replayed, mapper.rebuilds, mapper.pending) == (12, 2, 12, 0, 0)
    _same_map(mapper.tree, _fresh({**keyframes, **moved}).tree)


def test_only_scans_near_the_moved_keyframes_are_replayed() -> None:
    """Two rooms 20 m apart: a keyframe that moves in one replays that room's scans, never the other's."""
    far = pose_from_planar(20.0, 0.0, 0.0)
    keyframes = {i: _room_keyframe(i) for i in range(4)}
    keyframes.update(
        {10 + i: (points, far @ pose) for i, (points, pose) in enumerate(_room_keyframe(i) for i in range(4, 8))}
    )
    mapper = _fresh(keyframes, rebuild_fraction=np.inf)  # always replay, to count what it replays
    points, pose = keyframes[11]
    shifted = pose_from_planar(0.2, 0.0, 0.0) @ pose
    assert mapper.update_poses({11: shifted}) == 1
    assert mapper.integrate() == 4 and mapper.replayed == 4 and mapper.rebuilds == 0
    _same_map(mapper.tree, _fresh({**keyframes, 11: (points, shifted)}).tree)


def test_most_keyframes_moving_rebuilds_the_map() -> None:
    keyframes = {i: _room_keyframe(i) for i in range(4)}
    mapper = _fresh(keyframes)
    moved = {i: (points, pose_from_planar(0.0, 0.2, 0.0) @ pose) for i, (points, pose) in keyframes.items() if i}
    assert mapper.update_poses({i: pose for i, (_, pose) in moved.items()}) == 3
    mapper.add_keyframe(4, *_room_keyframe(4))
    assert mapper.integrate(moved=False) == 1  # the new keyframe only; the moved ones wait
    assert (mapper.moved, mapper.pending, mapper.rebuilds) == (3, 3, 0)
    keyframes[4] = _room_keyframe(4)
    assert mapper.integrate() == 5  # every keyframe, once
    assert (mapper.rebuilds, mapper.reintegrated, mapper.inserted) == (1, 0, 10)
    _same_map(mapper.tree, _fresh({**keyframes, **moved}).tree)


def test_a_keyframe_sent_again_replaces_its_scan() -> None:
    keyframes = {i: _room_keyframe(i) for i in range(6)}
    mapper = _fresh(keyframes, rebuild_fraction=np.inf)
    points, pose = keyframes[2]
    mapper.add_keyframe(2, points[: len(points) // 2], pose)  # the same keyframe, half its points
    assert mapper.pending == 1
    mapper.integrate()
    _same_map(mapper.tree, _fresh({**keyframes, 2: (points[: len(points) // 2], pose)}).tree)


def test_a_move_counts_by_how_far_the_scan_moves() -> None:
    points, pose = _room_keyframe(0)
    reach = float(np.linalg.norm(points, axis=1).max())
    assert 1.5 < reach < 3.5  # the room's walls from inside it
    mapper = _fresh({0: (points, pose), 1: _room_keyframe(1)}, rebuild_fraction=np.inf)  # tolerance: 5 cm
    nudged = pose_from_planar(0.03, 0.0, 0.0) @ pose
    assert scan_displacement(pose, nudged, reach) == pytest.approx(0.03)
    assert mapper.update_poses({0: nudged}) == 0  # 3 cm: every point stays within its voxel or the next
    # A turn about the camera moves its farthest point by 2·sin(θ/2)·reach: 0.01 rad ≈ 2-3 cm, 0.03 rad ≈ 6-9 cm.
    turned = pose @ make_pose(so3_exp([0.0, 0.01, 0.0]))
    assert scan_displacement(pose, turned, reach) == pytest.approx(2 * np.sin(0.005) * reach)
    assert mapper.update_poses({0: turned}) == 0
    assert mapper.update_poses({0: pose @ make_pose(so3_exp([0.0, 0.03, 0.0]))}) == 1
    assert mapper.update_poses({0: nudged}) == 0  # back within the tolerance before it was integrated again
    assert mapper.update_poses({0: pose @ make_pose(so3_exp([0.0, 0.03, 0.0]))}) == 1
    mapper.integrate()
    assert mapper.reintegrated == 1


def test_a_move_may_be_judged_with_another_tolerance() -> None:
    """The mapping node following the fleet back-end judges the back-end's moves by a tolerance of its own."""
    points, pose = _room_keyframe(0)
    mapper = _fresh({0: (points, pose), 1: _room_keyframe(1)}, rebuild_fraction=np.inf)  # tolerance: 5 cm
    moved = pose_from_planar(0.08, 0.0, 0.0) @ pose
    assert mapper.update_poses({0: moved}, tolerance=0.1) == 0  # 8 cm: within 10 cm
    np.testing.assert_array_equal(mapper.scans[0].pose, moved)  # the pose is taken all the same
    assert mapper.update_poses({0: moved}) == 1  # beyond the mapper's own 5 cm
    assert mapper.update_poses({0: moved}, tolerance=0.1) == 0  # judged again: it need not move after all


def test_a_graph_pose_that_overtakes_its_keyframe_is_used() -> None:
    points, pose = _room_keyframe(0)
    optimised = pose_from_planar(0.3, 0.0, 0.0) @ pose
    mapper = KeyframeMapper(MappingConfig(resolution=0.1))
    assert mapper.update_poses({7: optimised}) == 0  # not received yet
    mapper.add_keyframe(7, points, pose)
    mapper.integrate()
    _same_map(mapper.tree, _fresh({7: (points, optimised)}).tree)


def _corridor_keyframe(x: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points of a corridor's walls (y = ±1, x from -1 to 13, z 0..1.2) that a depth camera at (x, 0)
    sees within 3 m and 60° of its heading, along or across the corridor."""
    rng = np.random.default_rng(seed)
    heading = rng.choice([0.0, np.pi / 2, np.pi, -np.pi / 2]) + rng.uniform(-0.3, 0.3)
    camera = pose_from_planar(x, 0.0, heading) @ T_BODY_OPTICAL
    camera[2, 3] = 0.5
    angles, heights = heading + rng.uniform(-0.5, 0.5, 600), rng.uniform(0.0, 1.2, 600)
    direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    half, centre = np.array([7.0, 1.0]), np.array([6.0, 0.0])
    origin = camera[:2, 3] - centre
    t = np.min(np.where(np.abs(direction) > 1e-9, (half - np.sign(direction) * origin) / np.abs(direction), 1e9),
               axis=1)  # fmt: skip
    world = np.column_stack([camera[:2, 3] + direction * t[:, None], heights])[t <= 3.0]
    return transform_points(invert(camera), world).astype(np.float32), camera


def test_replaying_only_the_rays_that_cross_the_moved_scans_is_exact() -> None:
    """Keyframes along a corridor: of the other scans that overlap the moved one, only the rays that cross its box
    are traced again (the others cannot reach its voxels); the map is still exactly the rebuilt one."""
    keyframes = {i: _corridor_keyframe(0.75 * i, i) for i in range(17)}
    mapper = _fresh(keyframes, rebuild_fraction=np.inf)
    points, pose = keyframes[8]
    box = mapper.scans[8].box
    assert box is not None
    crossing = [_rays_through(transform_points(p, q), p[:3, 3], box[None], 0.1).mean() for q, p in keyframes.values()]
    assert min(crossing) < 0.5 < max(crossing)  # some scans' rays partly, some not at all: a real subset
    shifted = pose_from_planar(0.1, 0.05, 0.02) @ pose
    assert mapper.update_poses({8: shifted}) == 1
    mapper.integrate()
    assert mapper.reintegrated == 1 and mapper.rebuilds == 0
    _same_map(mapper.tree, _fresh({**keyframes, 8: (points, shifted)}).tree)


@pytest.mark.parametrize(
    "corrupt",
    [
        lambda pose: pose.__setitem__((0, 3), np.nan),
        lambda pose: pose.__setitem__((1, 1), np.inf),
        lambda pose: pose.__setitem__((slice(0, 3), slice(0, 3)), 0.0),  # a zero quaternion's rotation
        lambda pose: pose.__setitem__((slice(0, 3), 0), -pose[:3, 0]),  # a reflection
        lambda pose: pose.__setitem__((2, 3), 1e6),  # beyond the octree's keys
    ],
)
def test_poses_that_are_not_finite_rigid_transforms_in_the_map_are_refused_and_change_nothing(
    corrupt: Callable[[NDArray[np.float64]], None],
) -> None:
    mapper = KeyframeMapper(MappingConfig(resolution=0.1))
    good = np.eye(4)
    bad = np.eye(4)
    corrupt(bad)
    points = np.array([[0.0, 0.0, 2.0], [np.nan, 0.0, 2.0], [0.1, np.inf, 2.0]])
    with pytest.raises(ValueError, match="keyframe 0: pose"):
        mapper.add_keyframe(0, points, bad)
    assert not mapper.scans
    mapper.add_keyframe(1, points, good)
    assert mapper.integrate() == 1 and mapper.tree.is_occupied([0.05, 0.05, 2.05])  # the finite point went in
    with pytest.raises(ValueError, match=r"keyframes \[1\]"):
        mapper.update_poses({1: bad})
    np.testing.assert_array_equal(mapper.scans[1].pose, good)
    assert mapper.pending == 0
