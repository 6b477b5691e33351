"""The robot's pipeline end to end over a real router: simulator → SLAM node → mapping node.

The simulator runs as its own process (as in a deployment); the SLAM and mapping nodes of agent c3po run here.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from fleetslam.mapping.node import MappingNode, MappingNodeConfig
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.slam.node import SlamNode, SlamNodeConfig

from ..support import wait_until

pytest.importorskip("mujoco")


def test_simulated_robot_is_tracked_and_mapped(router_endpoint: str, make_context: Callable[..., Context]) -> None:
    slam = Node("slam", context=make_context("c3po"))
    slam_node = SlamNode(slam, SlamNodeConfig())
    mapping = Node("mapping", context=make_context("c3po"))
    MappingNode(mapping, MappingNodeConfig(publish_rate=2.0))
    viewer = Node("viewer", context=make_context())
    keyframes: list[Any] = []
    graphs: list[Any] = []
    clouds: list[Any] = []
    poses: list[Any] = []
    map_to_odom: list[Any] = []
    viewer.create_subscription("fleetslam_msgs/msg/Keyframe", "/c3po/keyframes", keyframes.append, QoSProfile(depth=50))
    viewer.create_subscription("fleetslam_msgs/msg/KeyframeGraph", "/c3po/graph", graphs.append, QoSProfile(depth=5))
    viewer.create_subscription("sensor_msgs/msg/PointCloud2", "/c3po/map/occupied", clouds.append, QoSProfile(depth=5))
    viewer.create_subscription("nav_msgs/msg/Odometry", "/c3po/slam/odom", poses.append, QoSProfile(depth=100))

    def on_tf(msg: Any) -> None:
        map_to_odom.extend(t for t in msg.transforms if t.header.frame_id == "map" and t.child_frame_id == "odom")

    viewer.create_subscription("tf2_msgs/msg/TFMessage", "/c3po/tf", on_tf, QoSProfile(depth=100))
    env = {**os.environ, "FLEETSLAM_ROUTER": router_endpoint, "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0",
           "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}  # fmt: skip
    sim = subprocess.Popen(
        [sys.executable, "-m", "fleetslam.cli.main", "sim", "run", "--robots", "c3po", "--camera-hz", "5",
         "--resolution", "320x240", "--autopilot", "loop", "--duration", "15"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip

    def moved() -> bool:
        if len(poses) < 2:
            return False
        a, b = poses[0].pose.pose.position, poses[-1].pose.pose.position
        return bool(np.linalg.norm([b.x - a.x, b.y - a.y, b.z - a.z]) > 0.2)

    try:
        # The graph follows the keyframes within its publication period (1 s) with the latest state.
        graph_grew = lambda: bool(graphs) and len(graphs[-1].poses) >= 2  # noqa: E731
        assert wait_until(lambda: len(keyframes) >= 3 and bool(clouds) and moved() and graph_grew(), 60.0), (
            f"keyframes {len(keyframes)}, clouds {len(clouds)}, poses {len(poses)}, graphs {len(graphs)}"
        )
    finally:
        sim.terminate()
        output, _ = sim.communicate(timeout=30)
    assert slam_node.frames >= 3, output[-2000:]
    keyframe = keyframes[-1]
    assert keyframe.agent == "c3po" and keyframe.depth_format == "png16_mm" and len(keyframe.rgb) > 0
    assert keyframe.descriptor_length == 32 and len(keyframe.descriptors) > 0
    # The bag-of-words vector: one TF-IDF weight per word.
    assert len(keyframe.word_ids) > 0 and len(keyframe.word_weights) == len(keyframe.word_ids)
    assert np.all(np.isfinite(keyframe.word_weights)) and np.all(keyframe.word_weights >= 0)
    # Wheel odometry (odom + tf_static base_link → camera) gave the frames their prior, and the map → odom
    # correction is on tf: near identity on a short run that starts at the odometry's origin.
    assert slam_node.base_camera is not None and slam_node.priors_used >= 3
    assert map_to_odom, "no map → odom transform on /c3po/tf"
    shift = map_to_odom[-1].transform.translation
    assert np.linalg.norm([shift.x, shift.y]) < 2.0
    assert graphs and len(graphs[-1].poses) >= 2 and len(graphs[-1].constraints) >= 1
    # The graph carries each keyframe's full stamp (the camera's, to the nanosecond).
    keyframe_stamps = {int(k.id): (k.header.stamp.sec, k.header.stamp.nanosec) for k in keyframes}
    graph = graphs[-1]
    shared = [(int(i), (t.sec, t.nanosec)) for i, t in zip(graph.keyframe_ids, graph.stamps, strict=True)]
    assert any(i in keyframe_stamps for i, _ in shared)
    assert all(keyframe_stamps[i] == stamp for i, stamp in shared if i in keyframe_stamps)
    xyz = np.frombuffer(bytes(clouds[-1].data), np.float32).reshape(-1, 3)
    assert len(xyz) > 50  # occupied voxels of the hall seen by the camera
