"""The bridge sends the browsers what they can draw: poses at most ``pose_rate_hz`` per robot and source."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable
from typing import Any

from fleetslam.middleware import Context, Node
from fleetslam.msg.typesys import message_from_dict
from fleetslam.station.bridge import StationBridge

from ..support import wait_until


def test_poses_reach_the_browsers_at_the_pose_rate(make_context: Callable[..., Context]) -> None:
    sent: list[tuple[float, dict[str, Any]]] = []
    lock = threading.Lock()

    def emit(message: dict[str, Any], agent: str | None) -> None:
        with lock:
            sent.append((time.monotonic(), message))

    robot = Node("base", context=make_context("/c3po"))
    odom = robot.create_publisher("nav_msgs/msg/Odometry", "odom")
    bridge = StationBridge(make_context(), emit, pose_rate_hz=10.0)
    try:
        assert wait_until(lambda: "c3po" in bridge.agents, 10.0)
        time.sleep(0.5)  # the subscription is matched
        start = time.monotonic()
        published = 0
        while time.monotonic() - start < 2.0:  # wheel odometry at 100 Hz
            msg = message_from_dict("nav_msgs/msg/Odometry", {"pose": {"pose": {"position": {"x": 0.001 * published}}}})
            msg.pose.pose.orientation.w = 1.0
            odom.publish(msg)
            published += 1
            time.sleep(0.01)
        time.sleep(0.3)
        with lock:
            poses = [t for t, m in sent if m["type"] == "pose" and m["agent"] == "c3po" and m["source"] == "odom"]
        assert published > 100
        assert len(poses) >= 10  # the robot is still shown moving
        # 10 Hz: the bridge sends a pose 0.1 s after the last at the earliest (noted here a few µs after it decided:
        # 5 ms of slack), so at most 24 in the 2.3 s.
        assert len(poses) <= 24 and min(b - a for a, b in itertools.pairwise(poses)) >= 0.095
        assert bridge.agents["c3po"].poses["odom"]["x"] > 0.1  # the latest pose is kept for new browsers
    finally:
        bridge.close()
        robot.destroy()
