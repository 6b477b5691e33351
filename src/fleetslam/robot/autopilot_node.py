"""The autopilot as an operator: follows a named route from odometry, publishing cmd_vel like a teleop."""

from __future__ import annotations

import logging
import math
import threading
from typing import Any

from fleetslam.middleware import Node
from fleetslam.msg.typesys import ns_from_stamp
from fleetslam.robot.autopilot import Autopilot, Route
from fleetslam.robot.teleop import CommandGate
from fleetslam.robot.teleop_node import TwistPublisher
from fleetslam.topics import CMD_VEL, ODOM

log = logging.getLogger(__name__)


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class AutopilotNode:
    """Subscribes ``odom``, publishes ``cmd_vel`` at ``rate`` Hz; the route is placed at the first odom pose.

    ``done`` is set once the route is completed (the robot was stopped with a few zero commands).
    """

    def __init__(
        self,
        node: Node,
        route: Route,
        *,
        rate: float = 10.0,
        odom_topic: str = ODOM.name,
        cmd_topic: str = CMD_VEL.name,
        stamped: bool = False,
        **pursuit: float,
    ) -> None:
        self.node = node
        self.route = route
        self.pursuit: dict[str, Any] = pursuit
        self.publisher = TwistPublisher(node, cmd_topic, stamped=stamped)
        self.pilot: Autopilot | None = None
        self.pose: tuple[float, float, float] | None = None
        self.done = threading.Event()
        self._gate = CommandGate()
        self._odom_time = 0.0
        node.create_subscription(ODOM.type, odom_topic, self._on_odom, ODOM.qos(depth=1))
        self.timer = node.create_timer(1.0 / rate, self._on_timer)

    def _on_odom(self, msg: Any) -> None:
        p = msg.pose.pose
        self.pose = (float(p.position.x), float(p.position.y), _yaw(p.orientation))
        self._odom_time = ns_from_stamp(msg.header.stamp) * 1e-9

    def _on_timer(self) -> None:
        if self.pose is None or self.done.is_set():
            return
        if self.pilot is None:
            self.pilot = Autopilot.for_route(self.route, self.pose, **self.pursuit)
            log.info("autopilot: following route %r from %s", self.route.name, self.pose)
        v, omega, finished = self.pilot.step(self.pose, self._odom_time)
        command = self._gate.filter((v, omega))
        if command is not None:
            self.publisher.publish(*command)
        elif finished:
            log.info("autopilot: route %r done", self.route.name)
            self.done.set()
