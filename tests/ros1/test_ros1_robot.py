"""Issue 16, item 2: a ROS 1 robot feeds fleetslam. A rospy RGB-D camera publishing as a Kinect driver does
(``/camera/rgb/image_raw``, ``/camera/depth_registered/image_raw``, ``/camera/rgb/camera_info``) into a real
roscore, bridged with remaps into c3po's namespace, drives fleetslam's SLAM and mapping nodes."""

from __future__ import annotations

import json
import subprocess
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.datasets.base import Intrinsics
from fleetslam.geometry import T_BODY_OPTICAL, pose_from_planar
from fleetslam.mapping.node import MappingNode, MappingNodeConfig
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.ros1.bridge import Ros1Bridge, TopicRule
from fleetslam.ros1.node import Ros1Node
from fleetslam.slam.node import SlamNode, SlamNodeConfig

from ..slam.textured_room import make_textures, render
from ..support import wait_until
from .conftest import Master, need_ros1

CAMERA = Path(__file__).with_name("ros1_rgbd_camera.py")
REMAPS = [
    "/camera/rgb/image_raw:=/c3po/camera/rgb/image_raw",
    "/camera/depth_registered/image_raw:=/c3po/camera/depth/image_raw",
    "/camera/rgb/camera_info:=/c3po/camera/rgb/camera_info",
]


def _render_frames(folder: Path, count: int) -> float:
    """``count`` frames of the textured room, the camera moving 1 cm a frame; returns the distance covered."""
    intrinsics = Intrinsics(80.0, 80.0, 40.0, 30.0, 80, 60)
    textures = make_textures(np.random.default_rng(0))
    folder.mkdir()
    for k in range(count):
        rgb, depth = render(pose_from_planar(0.01 * k, 0.0, 0.0) @ T_BODY_OPTICAL, intrinsics, textures)
        (folder / f"rgb{k}.bin").write_bytes(np.ascontiguousarray(rgb, np.uint8).tobytes())
        (folder / f"depth{k}.bin").write_bytes(np.ascontiguousarray(depth, "<f4").tobytes())
    k_matrix = [intrinsics.fx, 0.0, intrinsics.cx, 0.0, intrinsics.fy, intrinsics.cy, 0.0, 0.0, 1.0]
    (folder / "meta.json").write_text(json.dumps({"width": 80, "height": 60, "count": count, "K": k_matrix}))
    return 0.01 * (count - 1)


def test_a_ros1_rgbd_camera_drives_fleetslam_slam_and_mapping(
    roscore: Master, make_context: Callable[..., Context], tmp_path: Path
) -> None:
    need_ros1()
    distance = _render_frames(tmp_path / "frames", 20)
    positions: list[tuple[float, float, float]] = []
    cloud_points: list[int] = []
    lock = threading.Lock()

    def on_odom(msg: Any) -> None:
        p = msg.pose.pose.position
        with lock:
            positions.append((p.x, p.y, p.z))

    with (
        Ros1Node("fleetslam_bridge", master_uri=roscore.uri) as ros1,
        Node("fleetslam_bridge", context=make_context()) as bridge_node,
        Ros1Bridge(bridge_node, ros1, from_ros1=[TopicRule.parse(r) for r in REMAPS], scan_period_s=0.2) as bridge,
        Node("slam", context=make_context("c3po")) as slam,
        Node("mapping", context=make_context("c3po")) as mapping,
        Node("observer", context=make_context()) as observer,
    ):  # fmt: skip
        slam_node = SlamNode(slam, SlamNodeConfig(use_wheel_odometry=False, maps_dir=str(tmp_path)))
        mapping_node = MappingNode(mapping, MappingNodeConfig(publish_rate=5.0, maps_dir=str(tmp_path)))
        observer.create_subscription("nav_msgs/msg/Odometry", "/c3po/slam/odom", on_odom, QoSProfile(depth=50))
        observer.create_subscription("sensor_msgs/msg/PointCloud2", "/c3po/map/occupied",
                                     lambda m: cloud_points.append(m.width * m.height),
                                     QoSProfile(durability="transient_local", depth=5))  # fmt: skip
        camera = subprocess.Popen(
            ["/usr/bin/python3", str(CAMERA), str(tmp_path / "frames"), "--rate", "5"],
            env=roscore.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert wait_until(lambda: len(positions) >= 25 and any(cloud_points), timeout_s=90), (
                len(positions), cloud_points, bridge.bridged_from_ros1, camera.poll())  # fmt: skip
        finally:
            camera.terminate()
            _, err = camera.communicate(timeout=10)
        assert set(bridge.bridged_from_ros1.values()) == {r.partition(":=")[2] for r in REMAPS}, err
        assert all(c["errors"] == 0 for c in bridge.topic_counts().values()), bridge.topic_counts()
        assert slam_node.camera_info is not None and list(slam_node.camera_info.k) == [80, 0, 40, 0, 80, 30, 0, 0, 1]
        assert slam_node.counts["keyframes"] >= 1 and mapping_node.mapper.scans
    with lock:
        track = np.array(positions)
    travelled = float(np.max(np.linalg.norm(track - track[0], axis=1)))
    assert 0.5 * distance < travelled < 1.5 * distance, (travelled, distance)  # SLAM followed the camera's motion
