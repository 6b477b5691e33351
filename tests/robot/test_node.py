from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from fleetslam.middleware import Context, Node
from fleetslam.msg.typesys import get_type, header
from fleetslam.robot.config import RobotConfig
from fleetslam.robot.drive import MotorModelDrive
from fleetslam.robot.node import BaseControllerNode

from ..support import wait_until

Twist = get_type("geometry_msgs/msg/Twist")
TwistStamped = get_type("geometry_msgs/msg/TwistStamped")
Vector3 = get_type("geometry_msgs/msg/Vector3")
SetBoolRequest = get_type("std_srvs/srv/SetBool_Request")


def _twist(v: float, omega: float) -> Any:
    return Twist(linear=Vector3(x=v, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=omega))


def _drive_for(pub: Any, msg: Any, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pub.publish(msg)
        time.sleep(0.05)


def _drive_until(pub: Any, msg: Any, odoms: list[Any], predicate: Callable[[Any], bool], timeout_s: float) -> Any:
    """Publish ``msg`` at 20 Hz until the newest odometry satisfies ``predicate``; that odometry, or None.

    Looking only after a fixed drive time races the 0.3 s watchdog: one late publish on a loaded machine and the
    robot is braking when we look.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pub.publish(msg)
        time.sleep(0.05)
        if odoms and predicate(odoms[-1]):
            return odoms[-1]
    return None


def test_base_controller_node_end_to_end(make_context: Callable[..., Context]) -> None:
    robot_ctx = make_context(namespace="/c3po")
    operator_ctx = make_context()
    config = RobotConfig(cmd_vel_timeout=0.3)
    with Node("base_controller", context=robot_ctx) as robot_node, Node("operator", context=operator_ctx) as op:
        controller_node = BaseControllerNode(robot_node, MotorModelDrive.from_config(config), config=config)
        odoms: list[Any] = []
        joints: list[Any] = []
        tfs: list[Any] = []
        op.create_subscription("nav_msgs/msg/Odometry", "/c3po/odom", odoms.append)
        op.create_subscription("sensor_msgs/msg/JointState", "/c3po/joint_states", joints.append)
        op.create_subscription("tf2_msgs/msg/TFMessage", "/c3po/tf", tfs.append)
        cmd = op.create_publisher("geometry_msgs/msg/Twist", "/c3po/cmd_vel")
        cmd_stamped = op.create_publisher("geometry_msgs/msg/TwistStamped", "/c3po/cmd_vel")
        estop = op.create_client("std_srvs/srv/SetBool", "/c3po/e_stop")
        assert wait_until(lambda: len(odoms) > 5 and cmd.matched_subscriptions > 0, 10.0)

        # 0.4 m/s at 0.8 m/s² takes 0.5 s plus the PI lag; 5 s is ample on a loaded machine
        last = _drive_until(
            cmd, _twist(0.4, 0.3), odoms, lambda o: o.twist.twist.linear.x > 0.3 and o.pose.pose.position.x > 0.1, 5.0
        )
        assert last is not None, odoms[-1].twist.twist.linear
        assert last.header.frame_id == "odom" and last.child_frame_id == "base_link"
        assert len(last.pose.covariance) == 36
        assert list(joints[-1].name) == ["left_wheel_joint", "right_wheel_joint"]
        assert joints[-1].velocity[1] > joints[-1].velocity[0]  # turning left: right wheel faster
        assert tfs[-1].transforms[0].child_frame_id == "base_link"

        # commands stop: the watchdog brakes the robot (0.3 s timeout + 0.4/1.5 s braking)
        assert wait_until(lambda: abs(odoms[-1].twist.twist.linear.x) < 0.02, 2.0)

        # a TwistStamped that is already too old on arrival is dropped
        stale = TwistStamped(header=header("base_link", time.time_ns() - 2_000_000_000), twist=_twist(0.4, 0.0))
        dropped_before = controller_node.controller.dropped_commands
        cmd_stamped.publish(stale)
        assert wait_until(lambda: controller_node.controller.dropped_commands > dropped_before, 3.0)

        # a fresh TwistStamped drives; the e-stop stops and refuses further commands until released
        fresh = TwistStamped(header=header("base_link", time.time_ns()), twist=_twist(0.3, 0.0))
        cmd_stamped.publish(fresh)
        assert wait_until(lambda: odoms[-1].twist.twist.linear.x > 0.05, 2.0)  # 0.05 m/s is 62 ms at 0.8 m/s²
        response = estop.call(SetBoolRequest(data=True), timeout=5.0)
        assert response.success
        _drive_for(cmd, _twist(0.4, 0.0), 0.8)
        assert abs(odoms[-1].twist.twist.linear.x) < 0.05  # refused: ~1e-5 m/s measured; obeyed: 0.4 m/s
        assert controller_node.last_output is not None and controller_node.last_output.estopped
        assert estop.call(SetBoolRequest(data=False), timeout=5.0).success
        # released: 0.2 m/s is 0.25 s of acceleration
        assert _drive_until(cmd, _twist(0.4, 0.0), odoms, lambda o: o.twist.twist.linear.x > 0.2, 5.0) is not None


def test_base_brakes_at_once_when_the_driving_publisher_leaves(make_context: Callable[..., Context]) -> None:
    """Issue 18, item 5: the teleop source's liveliness disappearing (its process ended, its link cut) stops the
    base without waiting for the command timeout."""
    config = RobotConfig(cmd_vel_timeout=5.0)  # long: only the liveliness can explain a prompt stop
    with Node("base_controller", context=make_context(namespace="/c3po")) as robot_node:
        controller_node = BaseControllerNode(robot_node, MotorModelDrive.from_config(config), config=config)
        odoms: list[Any] = []
        observer = Node("observer", context=make_context())
        observer.create_subscription("nav_msgs/msg/Odometry", "/c3po/odom", odoms.append)
        teleop_ctx = make_context()
        bystander = Node("bystander", context=make_context()).create_publisher("geometry_msgs/msg/Twist", "/c3po/x")
        cmd = Node("teleop", context=teleop_ctx).create_publisher("geometry_msgs/msg/Twist", "/c3po/cmd_vel")
        assert wait_until(lambda: len(odoms) > 5 and cmd.matched_subscriptions > 0, 10.0)
        last = _drive_until(cmd, _twist(0.4, 0.0), odoms, lambda o: o.twist.twist.linear.x > 0.3, 5.0)
        assert last is not None
        bystander.destroy()  # another publisher leaving changes nothing
        time.sleep(0.3)
        assert controller_node.sources_lost == 0 and odoms[-1].twist.twist.linear.x > 0.3
        left = time.monotonic()
        teleop_ctx.close()
        assert wait_until(lambda: controller_node.sources_lost == 1, 2.0)
        # 0.4 m/s at 1.5 m/s² is 0.27 s of braking; the 5 s timeout would keep it driving for seconds
        assert wait_until(lambda: abs(odoms[-1].twist.twist.linear.x) < 0.01, 2.0)
        assert time.monotonic() - left < 2.0
