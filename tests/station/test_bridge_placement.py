"""The bridge follows each agent's placement in the fleet frame (latched ``slam/fleet_transform``) and its camera's
mounting (``tf_static``) and gives them to the browsers, live and in the snapshot a browser that connects later
gets; a transform that is not finite is not. SLAM's camera pose becomes the robot's base pose for its marker."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from fleetslam.geometry import invert, pose_from_quat, pose_from_xyz_rpy
from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import odometry_msg, pose_msg, transform_msg
from fleetslam.station.bridge import LEVEL_CAMERA, StationBridge, robot_pose
from fleetslam.topics import FLEET_PLACEMENTS, FLEET_TRANSFORM, SLAM_ODOM, TF_STATIC

from ..support import wait_until

MOUNTING = pose_from_xyz_rpy(0.1, 0.0, 0.3, -np.pi / 2 - np.radians(5.0), 0.0, -np.pi / 2)


def _matrix(values: list[float] | None) -> np.ndarray:
    return np.reshape(values, (4, 4))


def test_an_agents_placement_and_mounting_reach_the_browsers_and_the_snapshot(
    make_context: Callable[..., Context],
) -> None:
    sent: list[dict[str, Any]] = []
    lock = threading.Lock()

    def emit(message: dict[str, Any], agent: str | None) -> None:
        with lock:
            sent.append(message)

    def of_type(kind: str) -> list[dict[str, Any]]:
        with lock:
            return [m for m in sent if m["type"] == kind and m.get("agent") == "r2d2"]

    robot = Node("slam", context=make_context("/r2d2"))
    placement = robot.create_publisher(FLEET_TRANSFORM.type, FLEET_TRANSFORM.name, FLEET_TRANSFORM.qos())
    mounting = robot.create_publisher(TF_STATIC.type, TF_STATIC.name, TF_STATIC.qos())
    mounting.publish(transform_msg(MOUNTING, "base_link", "camera_optical_frame", 0))
    pose = pose_from_xyz_rpy(3.0, -1.0, 0.2, 0.0, 0.0, 0.4)
    placement.publish(transform_msg(pose, "fleet", "r2d2/map", 1).transforms[0])  # before the console: latched
    slam_odom = robot.create_publisher(SLAM_ODOM.type, SLAM_ODOM.name, SLAM_ODOM.qos())
    robot.create_publisher("nav_msgs/msg/Odometry", "odom")  # what makes the console find an agent
    bridge = StationBridge(make_context(), emit)
    try:
        assert wait_until(lambda: any(m["placement"] and m["mounting"] for m in of_type("frame")), 10.0)
        message = of_type("frame")[-1]
        np.testing.assert_allclose(_matrix(message["placement"]), pose, atol=1e-12)  # row-major
        np.testing.assert_allclose(_matrix(message["mounting"]), MOUNTING, atol=1e-12)
        assert message in bridge.snapshot()
        broken = transform_msg(pose, "fleet", "r2d2/map", 2).transforms[0]
        broken.transform.translation.x = float("nan")
        bridge._on_placement(bridge.agents["r2d2"], broken)  # as the subscription would (a sample may be dropped)
        assert len(of_type("frame")) == 2
        moved = pose_from_xyz_rpy(3.1, -1.0, 0.2, 0.0, 0.0, 0.4)
        placement.publish(transform_msg(moved, "fleet", "r2d2/map", 3).transforms[0])
        assert wait_until(lambda: len(of_type("frame")) >= 3, 10.0)
        np.testing.assert_allclose(_matrix(of_type("frame")[-1]["placement"]), moved, atol=1e-12)
        assert [m for m in bridge.snapshot() if m["type"] == "frame"] == [of_type("frame")[-1]]
        # SLAM's camera pose: the browsers get the robot's base (camera pose times the mounting's inverse).
        camera = pose_from_xyz_rpy(2.0, 0.1, 1.5, -1.7, 0.05, -0.6)
        slam_odom.publish(odometry_msg(pose_msg(camera), frame_id="map", child_frame_id="camera_optical_frame",
                                       stamp_ns=1))  # fmt: skip
        assert wait_until(lambda: bool(of_type("pose")), 10.0)
        sent_pose = of_type("pose")[-1]
        drawn = pose_from_quat([sent_pose["x"], sent_pose["y"], sent_pose["z"]], sent_pose["q"])
        np.testing.assert_allclose(drawn, camera @ invert(MOUNTING), atol=1e-9)
    finally:
        bridge.close()
        robot.destroy()


def test_without_a_known_mounting_the_robot_is_a_level_camera_looking_ahead() -> None:
    base = pose_from_xyz_rpy(1.0, 2.0, 0.0, 0.0, 0.0, 0.7)  # heading 0.7 rad in a z-up frame
    pose = robot_pose(base @ LEVEL_CAMERA, None)
    assert pose["yaw"] == pytest.approx(0.7)
    np.testing.assert_allclose(pose_from_quat([pose["x"], pose["y"], pose["z"]], pose["q"]), base, atol=1e-12)


def test_the_back_ends_placement_wins_over_the_agents_own(make_context: Callable[..., Context]) -> None:
    """The fleet map lands an agent by the joint optimisation's ``/fleet/placements``: the console draws the agent's
    frame by it too (else by the agent's own ``slam/fleet_transform``), also for an agent it finds later."""
    sent: list[dict[str, Any]] = []
    lock = threading.Lock()

    def emit(message: dict[str, Any], agent: str | None) -> None:
        with lock:
            sent.append(message)

    def latest_frame() -> dict[str, Any] | None:
        with lock:
            frames = [m for m in sent if m["type"] == "frame" and m.get("agent") == "r2d2"]
        return frames[-1] if frames else None

    own, joint = pose_from_xyz_rpy(3.0, -1.0, 0.0, 0, 0, 0.4), pose_from_xyz_rpy(3.02, -1.01, 0.0, 0, 0, 0.405)
    backend = Node("fleet_backend", context=make_context("/"))
    placements = backend.create_publisher(FLEET_PLACEMENTS.type, FLEET_PLACEMENTS.name, FLEET_PLACEMENTS.qos())
    message = transform_msg(joint, "fleet", "r2d2/map", 1)
    forged = transform_msg(pose_from_xyz_rpy(9, 9, 9, 0, 0, 0), "fleet", "fleet/map", 1).transforms[0]
    message.transforms.append(forged)  # the fleet itself is not an agent
    placements.publish(message)  # before the agent is known: kept until it is
    bridge = StationBridge(make_context(), emit)
    robot = Node("slam", context=make_context("/r2d2"))
    try:
        assert wait_until(lambda: placements.matched_subscriptions > 0, 10.0)
        own_placement = robot.create_publisher(FLEET_TRANSFORM.type, FLEET_TRANSFORM.name, FLEET_TRANSFORM.qos())
        own_placement.publish(transform_msg(own, "fleet", "r2d2/map", 2).transforms[0])
        robot.create_publisher("nav_msgs/msg/Odometry", "odom")  # what makes the console find an agent
        assert wait_until(lambda: "r2d2" in bridge.agents and bridge.agents["r2d2"].own_placement is not None, 10.0)
        frame = latest_frame()
        assert frame is not None
        np.testing.assert_allclose(_matrix(frame["placement"]), joint, atol=1e-12)
        assert "fleet" not in bridge.agents or bridge.agents["fleet"].placement is None
    finally:
        bridge.close()
        robot.destroy()
        backend.destroy()
