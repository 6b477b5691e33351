import numpy as np
import pytest

from fleetslam.fusion.fleet_map import FleetMap
from fleetslam.geometry import pose_from_planar
from fleetslam.mapping.octree import OccupancyOctree


def _wall_tree(x: float) -> OccupancyOctree:
    """A tree that saw a wall at x (in its own frame) from the origin, twice."""
    tree = OccupancyOctree(0.1)
    ys, zs = np.meshgrid(np.arange(-0.95, 1.0, 0.1), np.arange(0.05, 1.0, 0.1))  # voxel centres
    wall = np.stack([np.full(ys.size, x), ys.ravel(), zs.ravel()], axis=1)
    for _ in range(2):
        tree.insert_point_cloud(wall, [0.0, 0.0, 0.5])
    return tree


def test_agents_maps_land_in_the_fleet_frame() -> None:
    fleet = FleetMap(0.1)
    fleet.update_agent("c3po", _wall_tree(2.0))
    fleet.update_agent("r2d2", _wall_tree(2.0))
    fleet.set_transform("r2d2", pose_from_planar(10.0, 0.0, np.pi))  # r2d2 faces c3po from x = 10
    fused = fleet.fused()
    # c3po's wall at x = 2 and r2d2's at x = 10 - 2 = 8 (it looks back along -x).
    assert fused.is_occupied([2.05, 0.05, 0.55])
    assert fused.is_occupied([7.95, 0.05, 0.55])
    assert fused.log_odds([5.05, 0.05, 0.55]) is None  # between them: nobody looked there
    for free in ([1.05, 0.05, 0.55], [9.05, 0.05, 0.55]):  # free space in front of each robot
        value = fused.log_odds(free)
        assert value is not None and value < 0


def test_latest_map_replaces_the_previous() -> None:
    fleet = FleetMap(0.1)
    fleet.update_agent("c3po", _wall_tree(2.0))
    assert fleet.fused().is_occupied([2.05, 0.05, 0.55])
    fleet.update_agent("c3po", _wall_tree(3.0))  # after re-optimisation the wall moved
    fused = fleet.fused()
    assert fused.is_occupied([3.05, 0.05, 0.55])
    assert not fused.is_occupied([2.05, 0.05, 0.55])


def test_resolution_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError, match="resolution"):
        FleetMap(0.05).update_agent("c3po", OccupancyOctree(0.1))
