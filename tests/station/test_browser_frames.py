"""Each agent's map and marker in real Chromium: in its own labelled frame, beside the fleet frame, until its SLAM
places it (``slam/fleet_transform``), then in the fleet frame by that placement; a console opened later gets the
placement at once (latched)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import transform_msg
from fleetslam.station.server import StationServer
from fleetslam.topics import FLEET_TRANSFORM

from ..support import wait_until
from .conftest import RobotUnderTest, pointcloud2

#: Where r2d2's map frame lies in the fleet frame (c3po's map), and c3po's: the reference, at the origin.
R2D2_PLACEMENT = pose_from_xyz_rpy(3.0, -1.0, 0.0, 0.0, 0.0, np.pi / 2)


def _frame(page: Any, agent: str, point: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict[str, Any]:
    info: dict[str, Any] = page.evaluate(f"window.fleetslam.frameOf({agent!r}, {list(point)})")
    return info


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
    r2d2_placement, c3po_placement = _placement_publisher(r2d2), _placement_publisher(test_robot.node)
    # Placed before the console starts: the bridge gets it latched, the page with its first snapshot.
    r2d2_placement.publish(transform_msg(R2D2_PLACEMENT, "fleet", "r2d2/map", 1).transforms[0])
    with StationServer(make_context(), port=0) as server:
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.frameOf('c3po')?.cloudInFrame", timeout=20000)
        page.wait_for_function("window.fleetslam.frameOf('r2d2')?.placed", timeout=20000)
        # r2d2 is placed: its map's point (1, 0, 0) is drawn where its placement puts it.
        r2d2_view = _frame(page, "r2d2", (1.0, 0.0, 0.0))
        assert r2d2_view["label"] == "r2d2" and r2d2_view["cloudInFrame"]
        assert r2d2_view["world"] == pytest.approx([3.0, 0.0, 0.0], abs=1e-5)
        # c3po is not: its own frame, labelled, beside the fleet frame; its marker (wheel odometry) and map with it.
        c3po_view = _frame(page, "c3po")
        assert c3po_view["label"] == "c3po (own frame, not merged)" and not c3po_view["placed"]
        assert c3po_view["world"] == pytest.approx([0.0, -40.0, 0.0])
        assert c3po_view["marker"] is not None and c3po_view["marker"][1] == pytest.approx(-40.0)
        # Its SLAM places it (at the fleet origin): the map and the marker move into the fleet frame together.
        placement = pose_from_xyz_rpy(0.5, 0.25, 0.0, 0.0, 0.0, np.pi)
        c3po_placement.publish(transform_msg(placement, "fleet", "c3po/map", 2).transforms[0])
        page.wait_for_function("window.fleetslam.frameOf('c3po').placed", timeout=10000)
        c3po_view = _frame(page, "c3po", (1.0, 0.0, 0.0))
        assert c3po_view["label"] == "c3po" and c3po_view["cloudInFrame"]
        assert c3po_view["world"] == pytest.approx([-0.5, 0.25, 0.0], abs=1e-5)
        assert wait_until(lambda: _frame(page, "c3po")["marker"] is not None, 5.0)
        marker = np.array(_frame(page, "c3po")["marker"])  # odometry at (x, 0, 0) in c3po's frame: x ≥ 0
        assert marker[1] == pytest.approx(0.25, abs=1e-5) and marker[0] <= 0.5
    r2d2.destroy()
    assert not errors, errors
