"""The fleet map node over a real router: two agents' octomaps in, the fused map out."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.fusion.node import FleetMapConfig, FleetMapNode
from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.mapping.octomap_io import octomap_message_fields
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import transform_msg
from fleetslam.msg.typesys import get_type, message_from_dict

from ..support import wait_until


def _agent_map() -> Any:
    tree = OccupancyOctree(0.1)
    ys, zs = np.meshgrid(np.arange(-0.95, 1.0, 0.1), np.arange(0.05, 1.0, 0.1))
    wall = np.stack([np.full(ys.size, 2.05), ys.ravel(), zs.ravel()], axis=1)
    tree.insert_point_cloud(wall, [0.0, 0.0, 0.5])
    return message_from_dict("octomap_msgs/msg/Octomap", octomap_message_fields(tree.resolution, tree.leaves()))


def test_fleet_node_fuses_agents_in_the_fleet_frame(make_context: Callable[..., Context]) -> None:
    fleet = Node("fleet_map", context=make_context())
    config = FleetMapConfig(resolution=0.1, start_poses={"r2d2": [10.0, 0.0, 0.0, 0.0, 0.0, np.pi]}, publish_rate=5.0,
                            require_placement=False)  # fmt: skip
    FleetMapNode(fleet, config)
    clouds: list[Any] = []
    fleet.create_subscription("sensor_msgs/msg/PointCloud2", "/fleet/map/occupied", clouds.append, QoSProfile(depth=5))
    latched = QoSProfile(durability="transient_local", depth=1)
    for agent in ("c3po", "r2d2"):
        node = Node("mapping", context=make_context(agent))
        node.create_publisher("octomap_msgs/msg/Octomap", "map/octomap", latched).publish(_agent_map())

    def both_walls() -> bool:
        if not clouds:
            return False
        xyz = np.frombuffer(bytes(clouds[-1].data), np.float32).reshape(-1, 3)
        # float32 centres of the 0.1 m wall voxels; a neighbouring voxel is 0.1 off
        return bool((np.abs(xyz[:, 0] - 2.05) < 0.06).any() and (np.abs(xyz[:, 0] - 7.95) < 0.06).any())

    assert wait_until(both_walls, 10.0)  # 5 Hz once both latched maps arrived; 10 s covers discovery under load


def test_fleet_node_fuses_without_subscribers_and_serves_late_ones(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    fleet_node = Node("fleet_map", context=make_context())
    config = FleetMapConfig(resolution=0.1, start_poses={"r2d2": [10.0, 0.0, 0.0, 0.0, 0.0, np.pi]},
                            agents=["c3po", "r2d2"], publish_rate=5.0, maps_dir=str(tmp_path),
                            require_placement=False)  # fmt: skip
    fleet = FleetMapNode(fleet_node, config)
    latched = QoSProfile(durability="transient_local", depth=1)
    for agent in ("c3po", "r2d2"):
        node = Node("mapping", context=make_context(agent))
        node.create_publisher("octomap_msgs/msg/Octomap", "map/octomap", latched).publish(_agent_map())
    assert wait_until(lambda: fleet.fleet.agents() == ["c3po", "r2d2"], 10.0)
    assert fleet._published == {"occupied": 0, "octomap": 0}  # nobody asked: nothing built or sent
    save = fleet_node.create_client("fleetslam_msgs/srv/SaveMap", "/fleet/map/save")
    request = get_type("fleetslam_msgs/srv/SaveMap_Request")
    refused = save.call(request(path=str(tmp_path / "elsewhere.bt")), timeout=10)  # a path, not a name
    assert not refused.success and "not a plain file name" in refused.message
    response = save.call(request(path="fleet.bt"), timeout=10)
    assert response.success, response.message
    saved = OccupancyOctree.read(tmp_path / "fleet.bt")
    assert saved.is_occupied([2.05, 0.05, 0.55]) and saved.is_occupied([7.95, 0.05, 0.55])
    viewer = Node("viewer", context=make_context())
    octomaps: list[Any] = []
    viewer.create_subscription("octomap_msgs/msg/Octomap", "/fleet/map/octomap", octomaps.append, latched)
    assert wait_until(lambda: bool(octomaps), 10.0)
    assert octomaps[-1].header.frame_id == "fleet" and len(octomaps[-1].data) > 0


def test_agents_without_start_poses_wait_for_the_placement_their_slam_publishes(
    make_context: Callable[..., Context],
) -> None:
    fleet_node = Node("fleet_map", context=make_context())
    fleet = FleetMapNode(fleet_node, FleetMapConfig(resolution=0.1, agents=["c3po", "r2d2"], publish_rate=5.0))
    latched = QoSProfile(durability="transient_local", depth=1)
    placement = {}
    for agent in ("c3po", "r2d2"):
        node = Node("mapping", context=make_context(agent))
        node.create_publisher("octomap_msgs/msg/Octomap", "map/octomap", latched).publish(_agent_map())
        placement[agent] = node.create_publisher("geometry_msgs/msg/TransformStamped", "slam/fleet_transform", latched)
    assert wait_until(lambda: len(fleet._latest) == 2, 10.0)
    time.sleep(0.5)
    assert fleet.fleet.agents() == []  # neither is placed: nothing lands at the origin
    # The reference agent's SLAM places itself at the fleet origin; r2d2's once its closures agree.
    placement["c3po"].publish(transform_msg(np.eye(4), "fleet", "c3po/map", 0).transforms[0])
    assert wait_until(lambda: fleet.fleet.agents() == ["c3po"], 10.0)
    placement["r2d2"].publish(transform_msg(np.eye(4), "fleet", "c3po/map", 0).transforms[0])  # not r2d2's: ignored
    time.sleep(0.5)
    assert fleet.fleet.agents() == ["c3po"]
    r2d2_in_fleet = pose_from_xyz_rpy(10.0, 0.0, 0.0, 0.0, 0.0, np.pi)
    placement["r2d2"].publish(transform_msg(r2d2_in_fleet, "fleet", "r2d2/map", 0).transforms[0])
    assert wait_until(lambda: fleet.fleet.agents() == ["c3po", "r2d2"], 10.0)

    def both_walls() -> bool:
        # The node's own tick may be fusing r2d2's map as it lands: its map is in once a fusion has taken it.
        fleet.fuse_pending()
        fused = fleet.fleet.fused()
        return bool(fused.is_occupied([2.05, 0.05, 0.55]) and fused.is_occupied([7.95, 0.05, 0.55]))

    assert wait_until(both_walls, 10.0)
    np.testing.assert_allclose(fleet.placed["r2d2"], r2d2_in_fleet, atol=1e-9)
