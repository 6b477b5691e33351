"""Each agent's map and marker in real Chromium: in its own labelled frame, beside the fleet frame, until its SLAM
places it (``slam/fleet_transform``), then in the fleet frame by that placement, drawn upright through the camera's
mounting (``tf_static``); a console opened later gets both at once (latched)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from fleetslam.geometry import invert, pose_from_xyz_rpy
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import odometry_msg, pose_msg, transform_msg
from fleetslam.station.server import StationServer
from fleetslam.topics import FLEET_TRANSFORM, SLAM_ODOM, TF_STATIC

from ..support import wait_until
from .conftest import RobotUnderTest, pointcloud2

#: Where r2d2's map frame lies in the fleet frame, and its camera on its base (ahead, 30 cm up, 5° down: the map
#: frame, its camera's at start, has z ahead and y down).
R2D2_PLACEMENT = pose_from_xyz_rpy(3.0, -1.0, 0.0, 0.0, 0.0, np.pi / 2)
R2D2_MOUNTING = pose_from_xyz_rpy(0.1, 0.0, 0.3, -np.pi / 2 - np.radians(5.0), 0.0, -np.pi / 2)
#: The fleet frame as drawn: seen from r2d2's base at its start (the first placed agent with a known mounting).
FLEET_DRAWN = R2D2_MOUNTING @ invert(R2D2_PLACEMENT)


def _frame(page: Any, agent: str, point: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict[str, Any]:
    info: dict[str, Any] = page.evaluate(f"window.fleetslam.frameOf({agent!r}, {list(point)})")
    return info


def _drawn(transform: np.ndarray, point: tuple[float, float, float]) -> list[float]:
    return [float(v) for v in (transform @ np.array([*point, 1.0]))[:3]]


def _placement_publisher(node: Node) -> Any:
    return node.create_publisher(FLEET_TRANSFORM.type, FLEET_TRANSFORM.name, FLEET_TRANSFORM.qos())


def test_agents_are_drawn_in_their_own_frame_until_placed_then_by_their_placement(
    browser_page,
    make_context: Callable[..., Context],
    test_robot: RobotUnderTest,  # type: ignore[no-untyped-def]
) -> None:
    page, errors = browser_page
    r2d2 = Node("slam", context=make_context("r2d2"))
    latched = QoSProfile(depth=1, durability="transient_local")
    r2d2_map = r2d2.create_publisher("sensor_msgs/msg/PointCloud2", "map/occupied", latched)
    r2d2_map.publish(pointcloud2(np.array([[1.025, 0.025, 0.025], [1.075, 0.025, 0.025]])))
    mounting = r2d2.create_publisher(TF_STATIC.type, TF_STATIC.name, TF_STATIC.qos())
    mounting.publish(transform_msg(R2D2_MOUNTING, "base_link", "camera_optical_frame", 0))
    r2d2_placement, c3po_placement = _placement_publisher(r2d2), _placement_publisher(test_robot.node)
    # Placed before the console starts: the bridge gets it latched, the page with its first snapshot.
    r2d2_placement.publish(transform_msg(R2D2_PLACEMENT, "fleet", "r2d2/map", 1).transforms[0])
    slam_odom = r2d2.create_publisher(SLAM_ODOM.type, SLAM_ODOM.name, SLAM_ODOM.qos())
    with StationServer(make_context(), port=0) as server:
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.frameOf('c3po')?.cloudInFrame", timeout=20000)
        page.wait_for_function("window.fleetslam.frameOf('r2d2')?.placed", timeout=20000)
        # r2d2 is placed: a point of its map (1 m ahead of its camera at start) is drawn where the placement puts it,
        # the fleet frame upright.
        r2d2_view = _frame(page, "r2d2", (0.0, 0.0, 1.0))
        assert r2d2_view["label"] == "r2d2" and r2d2_view["cloudInFrame"]
        assert r2d2_view["world"] == pytest.approx(_drawn(FLEET_DRAWN @ R2D2_PLACEMENT, (0.0, 0.0, 1.0)), abs=1e-5)
        tilt = np.radians(5.0)
        assert r2d2_view["world"] == pytest.approx([0.1 + np.cos(tilt), 0.0, 0.3 - np.sin(tilt)], abs=1e-5)
        # Its SLAM pose at start (the camera at its map's origin): the robot's marker upright at the fleet origin.
        for _ in range(20):
            slam_odom.publish(odometry_msg(pose_msg(np.eye(4)), frame_id="map", child_frame_id="camera_optical_frame",
                                           stamp_ns=1))  # fmt: skip
            if wait_until(lambda: _frame(page, "r2d2")["marker"] is not None, 0.25):
                break
        r2d2_view = _frame(page, "r2d2")
        assert r2d2_view["marker"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-5)
        assert r2d2_view["markerUp"] == pytest.approx([0.0, 0.0, 1.0], abs=1e-5)
        # c3po is not placed: its own frame, labelled, beside the fleet frame; its marker (wheel odometry) and map
        # with it.
        c3po_view = _frame(page, "c3po")
        assert c3po_view["label"] == "c3po (own frame, not merged)" and not c3po_view["placed"]
        assert c3po_view["world"] == pytest.approx([0.0, -40.0, 0.0])
        assert c3po_view["marker"] is not None and c3po_view["marker"][1] == pytest.approx(-40.0)
        # Its SLAM places it: the map and the marker move into the fleet frame together.
        placement = pose_from_xyz_rpy(0.5, 0.25, 0.0, 0.0, 0.0, np.pi)
        c3po_placement.publish(transform_msg(placement, "fleet", "c3po/map", 2).transforms[0])
        page.wait_for_function("window.fleetslam.frameOf('c3po').placed", timeout=10000)
        c3po_view = _frame(page, "c3po", (1.0, 0.0, 0.0))
        assert c3po_view["label"] == "c3po" and c3po_view["cloudInFrame"]
        assert c3po_view["world"] == pytest.approx(_drawn(FLEET_DRAWN @ placement, (1.0, 0.0, 0.0)), abs=1e-5)
        assert wait_until(lambda: _frame(page, "c3po")["marker"] is not None, 5.0)
        # The odometry's pose is (x, 0, 0) in c3po's frame: the marker is on that line as drawn.
        marker = np.array(_frame(page, "c3po")["marker"])
        origin, ahead = np.array(_drawn(FLEET_DRAWN @ placement, (0.0, 0.0, 0.0))), (FLEET_DRAWN @ placement)[:3, 0]
        offset = marker - origin
        assert np.linalg.norm(offset - (offset @ ahead) * ahead) < 1e-4 and offset @ ahead >= 0.0
    r2d2.destroy()
    assert not errors, errors
