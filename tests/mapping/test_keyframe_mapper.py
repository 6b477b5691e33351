import numpy as np

from fleetslam.geometry import T_BODY_OPTICAL, pose_from_planar
from fleetslam.mapping.config import MappingConfig
from fleetslam.mapping.keyframe_mapper import KeyframeMapper, depth_to_points


def _wall_depth(distance: float, width: int = 64, height: int = 48) -> np.ndarray:
    return np.full((height, width), distance, np.float32)


def test_depth_to_points_back_projects_a_flat_wall() -> None:
    depth = _wall_depth(2.0)
    depth[0, 0] = np.nan
    points = depth_to_points(depth, 50.0, 50.0, 32.0, 24.0, stride=2)
    assert np.allclose(points[:, 2], 2.0)
    assert points[:, 0].min() < 0 < points[:, 0].max()  # x to the right of the optical axis and left of it
    assert len(points) == 32 * 24 - 1


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
