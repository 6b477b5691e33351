"""The mapping node over a real router: keyframes in, occupancy products and services out."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from fleetslam.geometry import T_BODY_OPTICAL, pose_to_quat
from fleetslam.mapping.node import MappingNode, MappingNodeConfig
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.typesys import get_type, message_from_dict

from ..support import wait_until


def _keyframe(keyframe_id: int, pose: np.ndarray, distance: float) -> Any:
    depth_mm = np.full((48, 64), int(distance * 1000), np.uint16)
    ok, png = cv2.imencode(".png", depth_mm)
    assert ok
    t, q = pose_to_quat(pose)
    msg = message_from_dict(
        "fleetslam_msgs/msg/Keyframe",
        {"agent": "c3po", "id": keyframe_id, "depth_format": "png16_mm", "depth": png.reshape(-1).tolist(),
         "camera_info": {"width": 64, "height": 48, "k": [50.0, 0, 32.0, 0, 50.0, 24.0, 0, 0, 1]},
         "pose": {"position": dict(zip("xyz", t.tolist(), strict=True)),
                  "orientation": dict(zip("xyzw", q.tolist(), strict=True))}},
    )  # fmt: skip
    return msg


def test_mapping_node_maps_keyframes_and_serves(make_context: Callable[..., Context], tmp_path: Path) -> None:
    mapping = Node("mapping", context=make_context("c3po"))
    MappingNode(mapping, MappingNodeConfig(publish_rate=5.0, pixel_stride=2))
    slam = Node("slam", context=make_context("c3po"))
    clouds: list[Any] = []
    octomaps: list[Any] = []
    grids: list[Any] = []
    viewer = Node("viewer", context=make_context())
    viewer.create_subscription("sensor_msgs/msg/PointCloud2", "/c3po/map/occupied", clouds.append, QoSProfile(depth=5))
    viewer.create_subscription("octomap_msgs/msg/Octomap", "/c3po/map/octomap", octomaps.append, QoSProfile(depth=5))
    viewer.create_subscription("nav_msgs/msg/OccupancyGrid", "/c3po/map/grid", grids.append, QoSProfile(depth=5))
    keyframes = slam.create_publisher("fleetslam_msgs/msg/Keyframe", "keyframes", QoSProfile(depth=50))
    camera = T_BODY_OPTICAL.copy()
    camera[2, 3] = 0.5
    time.sleep(0.5)
    keyframes.publish(_keyframe(0, camera, 2.0))
    assert wait_until(lambda: bool(clouds) and bool(octomaps) and bool(grids), 10.0)
    cloud = clouds[-1]
    xyz = np.frombuffer(bytes(cloud.data), np.float32).reshape(-1, 3)
    assert len(xyz) > 100 and np.allclose(xyz[:, 0], 2.0 + 0.025, atol=0.03)  # the wall, 2 m ahead
    assert octomaps[-1].id == "OcTree" and octomaps[-1].binary and len(octomaps[-1].data) > 0
    assert grids[-1].info.width > 0 and 100 in set(np.asarray(grids[-1].data).tolist())
    save = viewer.create_client("fleetslam_msgs/srv/SaveMap", "/c3po/map/save")
    assert save.wait_for_service(5.0)
    response = save.call(get_type("fleetslam_msgs/srv/SaveMap_Request")(path=str(tmp_path / "c3po.bt")), timeout=10)
    assert response.success, response.message
    octomap = pytest.importorskip("octomap", reason="octomap-python is the oracle")
    in_file = octomap.OcTree(str(tmp_path / "c3po.bt").encode())
    assert response.message.startswith(f"{in_file.size()} nodes written"), response.message
    saved = OccupancyOctree.read(tmp_path / "c3po.bt")
    assert saved.is_occupied([2.025, 0.025, 0.525])
    reset = viewer.create_client("std_srvs/srv/Trigger", "/c3po/map/reset")
    assert reset.wait_for_service(5.0)
    assert reset.call(get_type("std_srvs/srv/Trigger_Request")(), timeout=10).success
    assert wait_until(lambda: clouds[-1].width == 0, 5.0)
