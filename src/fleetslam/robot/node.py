"""The base controller node: cmd_vel in; odom, joint_states and tf out; an e_stop service.

Wraps the pure :class:`~fleetslam.robot.controller.BaseController` around any
:class:`~fleetslam.robot.interfaces.WheelInterface` (the simulator passes its own in-process). Time comes from
``clock`` (seconds): the node's clock by default (wall time, or /clock with ``use_sim_time``); the simulator
passes its simulated time and calls :meth:`BaseControllerNode.step` itself after each physics step instead of
letting the node run its own timer.

Topics (relative to the node's namespace, e.g. ``/c3po``):
``cmd_vel`` geometry_msgs/msg/Twist and geometry_msgs/msg/TwistStamped (two subscriptions, one per type);
``odom`` nav_msgs/msg/Odometry; ``joint_states`` sensor_msgs/msg/JointState; ``tf`` tf2_msgs/msg/TFMessage
(``odom`` → ``base_link``; per agent, as in docs/architecture.md, so the frame names need no prefix);
service ``e_stop`` std_srvs/srv/SetBool (true engages, false releases).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from fleetslam import topics
from fleetslam.middleware import MessageInfo, Node
from fleetslam.middleware.wire import EntityKind, LivelinessToken
from fleetslam.msg.conversions import odometry_msg, planar_pose_msg, tf_msg
from fleetslam.msg.typesys import get_type, header, ns_from_stamp
from fleetslam.robot.config import RobotConfig
from fleetslam.robot.controller import BaseController, ControllerOutput
from fleetslam.robot.interfaces import WheelInterface

log = logging.getLogger(__name__)


class BaseControllerNode:
    """Runs a base controller on a middleware node.

    Args:
        node: the node to publish and subscribe on.
        wheels: the drive.
        config: robot parameters (defaults if None).
        clock: seconds now; default ``node.now_ns() / 1e9``.
        run_timer: run the control loop on a timer at ``config.control_rate``; False when the owner calls
            :meth:`step` (the simulator).
        frame_prefix: prefix of the odom/base_link frame ids (e.g. ``"c3po/"`` for a shared tf tree).
    """

    def __init__(
        self,
        node: Node,
        wheels: WheelInterface,
        *,
        config: RobotConfig | None = None,
        clock: Callable[[], float] | None = None,
        run_timer: bool = True,
        frame_prefix: str = "",
    ) -> None:
        self.node = node
        self.wheels = wheels
        self.config = config if config is not None else RobotConfig()
        self.controller = BaseController(self.config)
        self.clock: Callable[[], float] = clock if clock is not None else (lambda: node.now_ns() * 1e-9)
        self.odom_frame = frame_prefix + self.config.odom_frame
        self.base_frame = frame_prefix + self.config.base_frame
        self._lock = threading.Lock()
        self._last_publish: float | None = None
        self.last_output: ControllerOutput | None = None
        self._types = {
            name: get_type(name)
            for name in (
                "sensor_msgs/msg/JointState",
                "std_srvs/srv/SetBool_Response",
            )
        }
        odom, joints, tf = topics.ODOM, topics.JOINT_STATES, topics.TF
        self.odom_pub = node.create_publisher(odom.type, odom.name, odom.qos())
        self.joint_pub = node.create_publisher(joints.type, joints.name, joints.qos())
        # A deeper queue than the contract's: odometry at 50 Hz and tf with it, not to be dropped in a burst.
        self.tf_pub = node.create_publisher(tf.type, tf.name, tf.qos(depth=100)) if self.config.publish_tf else None
        self.last_external_command: float | None = None
        """Clock time of the last accepted `cmd_vel` (an operator or another node driving the robot)."""
        self._commander: bytes | None = None
        """GID of the publisher whose command is being followed."""
        self.sources_lost = 0
        """Times the commanding publisher's liveliness disappeared while it was driving, and the base braked."""
        node.context.graph.add_listener(self._on_graph_change)
        node.add_on_destroy(lambda: node.context.graph.remove_listener(self._on_graph_change))
        for command, callback in ((topics.CMD_VEL, self._on_twist), (topics.CMD_VEL_STAMPED, self._on_twist_stamped)):
            node.create_subscription(command.type, command.name, callback, command.qos(depth=1))
        node.create_service("std_srvs/srv/SetBool", "e_stop", self._on_estop)
        self.timer = node.create_timer(1.0 / self.config.control_rate, self._on_timer) if run_timer else None

    # -- inputs ------------------------------------------------------------------------------------------------
    def _on_twist(self, msg: Any, info: MessageInfo) -> None:
        now = self.clock()
        with self._lock:
            if self.controller.command(float(msg.linear.x), float(msg.angular.z), now, now):
                self.last_external_command = now
                self._commander = info.publisher_gid

    def _on_twist_stamped(self, msg: Any, info: MessageInfo) -> None:
        now = self.clock()
        stamp_ns = ns_from_stamp(msg.header.stamp)
        stamp = now if stamp_ns == 0 else stamp_ns * 1e-9
        with self._lock:
            if self.controller.command(float(msg.twist.linear.x), float(msg.twist.angular.z), stamp, now):
                self.last_external_command = now
                self._commander = info.publisher_gid

    def _on_graph_change(self, event: str, token: LivelinessToken) -> None:
        """On a Zenoh thread: the publisher being followed left the graph (stopped, crashed, or its link was cut)."""
        if event != "delete" or token.kind is not EntityKind.PUBLISHER:
            return
        with self._lock:
            if self._commander is None or token.gid != self._commander:
                return
            self._commander = None
            self.controller.source_lost()
            self.sources_lost += 1
        log.warning("%s: the publisher driving the base (%s) is gone; braking", self.node.fq_name, token.node_name)

    def _on_estop(self, request: Any) -> Any:
        engaged = bool(request.data)
        with self._lock:
            self.controller.estop(engaged)
        state = "engaged" if engaged else "released"
        return self._types["std_srvs/srv/SetBool_Response"](success=True, message=f"e-stop {state}")

    def _on_timer(self) -> None:
        self.step(self.clock())

    # -- control -----------------------------------------------------------------------------------------------
    def step(self, now: float) -> ControllerOutput:
        """One control step at ``now`` (s); publishes odometry, joint states and tf at ``odom_rate``."""
        with self._lock:
            output = self.controller.update(now, self.wheels)
        self.last_output = output
        period = 1.0 / self.config.odom_rate
        # a small tolerance keeps a 50 Hz loop from skipping every other 50 Hz publication through jitter
        if self._last_publish is None or now - self._last_publish >= 0.9 * period or now < self._last_publish:
            self._last_publish = now
            self.publish(output, now)
        return output

    def publish(self, output: ControllerOutput, now: float) -> None:
        """Publish odom, joint_states and tf for ``output`` stamped ``now``."""
        t = self._types
        stamp_ns = round(now * 1e9)
        odom = output.odometry
        pose = planar_pose_msg(odom.x, odom.y, odom.theta)
        msg = odometry_msg(
            pose, frame_id=self.odom_frame, child_frame_id=self.base_frame, stamp_ns=stamp_ns,
            linear=(odom.v, 0.0, 0.0), angular=(0.0, 0.0, odom.omega),
            pose_covariance=odom.pose_covariance, twist_covariance=odom.twist_covariance,
        )  # fmt: skip
        self.odom_pub.publish(msg)
        self.joint_pub.publish(
            t["sensor_msgs/msg/JointState"](
                header=header("", stamp_ns),
                name=[self.config.left_wheel_joint, self.config.right_wheel_joint],
                position=np.array(output.joint_positions, dtype=np.float64),
                velocity=np.array(output.joint_velocities, dtype=np.float64),
                effort=np.array(output.efforts, dtype=np.float64),
            )
        )
        if self.tf_pub is not None:
            self.tf_pub.publish(tf_msg(pose, self.odom_frame, self.base_frame, stamp_ns))
