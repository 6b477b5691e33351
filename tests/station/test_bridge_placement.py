"""The bridge follows each agent's placement in the fleet frame (latched ``slam/fleet_transform``) and gives it to
the browsers, live and in the snapshot a browser that connects later gets; a transform that is not finite is not."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import transform_msg
from fleetslam.station.bridge import StationBridge
from fleetslam.topics import FLEET_TRANSFORM

from ..support import wait_until


def test_an_agents_placement_reaches_the_browsers_and_the_snapshot(make_context: Callable[..., Context]) -> None:
    sent: list[dict[str, Any]] = []
    lock = threading.Lock()

    def emit(message: dict[str, Any], agent: str | None) -> None:
        with lock:
            sent.append(message)

    def placements() -> list[dict[str, Any]]:
        with lock:
            return [m for m in sent if m["type"] == "placement"]

    robot = Node("slam", context=make_context("/r2d2"))
    robot.create_publisher("nav_msgs/msg/Odometry", "odom")  # what makes the console find an agent
    placement = robot.create_publisher(FLEET_TRANSFORM.type, FLEET_TRANSFORM.name, FLEET_TRANSFORM.qos())
    pose = pose_from_xyz_rpy(3.0, -1.0, 0.2, 0.0, 0.0, 0.4)
    placement.publish(transform_msg(pose, "fleet", "r2d2/map", 1).transforms[0])  # before the console: latched
    bridge = StationBridge(make_context(), emit)
    try:
        assert wait_until(lambda: bool(placements()), 10.0)
        message = placements()[-1]
        assert (message["agent"], message["frame"], message["child"]) == ("r2d2", "fleet", "r2d2/map")
        np.testing.assert_allclose(np.reshape(message["matrix"], (4, 4)), pose, atol=1e-12)  # row-major
        assert message in bridge.snapshot()
        broken = transform_msg(pose, "fleet", "r2d2/map", 2).transforms[0]
        broken.transform.translation.x = float("nan")
        bridge._on_placement(bridge.agents["r2d2"], broken)  # as the subscription would (a sample may be dropped)
        assert len(placements()) == 1
        moved = pose_from_xyz_rpy(3.1, -1.0, 0.2, 0.0, 0.0, 0.4)
        placement.publish(transform_msg(moved, "fleet", "r2d2/map", 3).transforms[0])
        assert wait_until(lambda: len(placements()) >= 2, 10.0)
        np.testing.assert_allclose(np.reshape(placements()[-1]["matrix"], (4, 4)), moved, atol=1e-12)
        assert [m for m in bridge.snapshot() if m["type"] == "placement"] == [placements()[-1]]
    finally:
        bridge.close()
        robot.destroy()
