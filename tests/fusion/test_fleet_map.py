import numpy as np
import pytest

from fleetslam.fusion.fleet_map import FleetMap
from fleetslam.geometry import pose_from_planar
from fleetslam.mapping.keys import pack
from fleetslam.mapping.octree import OccupancyOctree, _expand_to_finest


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


def _room_tree(seeds: list[int], size: float = 2.0) -> OccupancyOctree:
    """Scans of a room's walls (x, y = ±size) from random origins near its centre."""
    tree = OccupancyOctree(0.1)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        origin = np.array([*rng.uniform(-0.5, 0.5, 2), 0.5])
        angles, heights = rng.uniform(0, 2 * np.pi, 400), rng.uniform(0.0, 1.2, 400)
        direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        t = np.min(np.where(np.abs(direction) > 1e-9, (size - np.sign(direction) * origin[:2]) / np.abs(direction),
                            1e9), axis=1)  # fmt: skip
        tree.insert_point_cloud(np.column_stack([origin[:2] + direction * t[:, None], heights]), origin)
    return tree


def _merged(trees: dict[str, OccupancyOctree], transforms: dict[str, np.ndarray]) -> OccupancyOctree:
    """The fleet map fused from scratch: each agent's tree merged in name order."""
    fused = OccupancyOctree(0.1)
    for name in sorted(trees):
        transform = transforms.get(name, np.eye(4))
        fused.merge(trees[name], None if np.array_equal(transform, np.eye(4)) else transform)
    return fused


def _voxels(tree: OccupancyOctree) -> dict[int, float]:
    keys, values = _expand_to_finest(tree.leaves())
    return dict(zip(pack(keys).tolist(), values.tolist(), strict=True))


def test_incremental_fusion_equals_fusing_from_scratch() -> None:
    """Agent maps that grow, shrink and move, one agent turned by an angle off the grid: after every change the
    fleet map holds exactly what fusing every agent's latest map from scratch gives."""
    fleet = FleetMap(0.1)
    trees: dict[str, OccupancyOctree] = {}
    transforms = {"r2d2": pose_from_planar(3.33, -1.27, 0.4)}
    fleet.set_transform("r2d2", transforms["r2d2"])
    steps: list[tuple[str, OccupancyOctree | np.ndarray]] = [
        ("c3po", _room_tree([1])), ("r2d2", _room_tree([2])), ("c3po", _room_tree([1, 3, 4])),
        ("r2d2", _room_tree([2, 5])), ("c3po", _room_tree([6], size=1.5)),  # re-optimised: smaller, moved walls
        ("r2d2", pose_from_planar(3.0, -1.0, 0.9)), ("c3po", pose_from_planar(0.05, 0.0, 0.0)),
    ]  # fmt: skip
    for agent, change in steps:
        if isinstance(change, OccupancyOctree):
            trees[agent] = change
            fleet.update_agent(agent, change)
        else:
            transforms[agent] = change
            fleet.set_transform(agent, change)
        assert _voxels(fleet.fused()) == _voxels(_merged(trees, transforms)), (agent, len(trees))


def test_a_small_change_fuses_only_the_voxels_it_touches() -> None:
    fleet = FleetMap(0.1)
    fleet.set_transform("r2d2", pose_from_planar(6.0, 0.0, 0.7))
    fleet.update_agent("c3po", _room_tree([1, 2, 3]))
    fleet.update_agent("r2d2", _room_tree([4, 5, 6]))
    full = fleet.fused_voxel_updates
    bigger = _room_tree([4, 5, 6])
    wall = np.column_stack([np.full(20, 1.95), np.linspace(-0.5, 0.5, 20), np.full(20, 0.55)])
    bigger.insert_point_cloud(wall, [1.0, 0.0, 0.55])  # one more short scan
    fleet.update_agent("r2d2", bigger)
    assert 0 < fleet.fused_voxel_updates - full < 0.1 * full
    assert _voxels(fleet.fused()) == _voxels(
        _merged({"c3po": _room_tree([1, 2, 3]), "r2d2": bigger}, {"r2d2": pose_from_planar(6.0, 0.0, 0.7)})
    )
