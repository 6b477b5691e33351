from __future__ import annotations

import os
import pty
import threading
import time
from collections.abc import Callable
from typing import Any

from fleetslam.middleware import Context, Node
from fleetslam.robot.autopilot import Route
from fleetslam.robot.autopilot_node import AutopilotNode
from fleetslam.robot.config import RobotConfig
from fleetslam.robot.drive import MotorModelDrive
from fleetslam.robot.node import BaseControllerNode
from fleetslam.robot.teleop import KeyboardTeleop
from fleetslam.robot.teleop_node import TwistPublisher, run_keyboard

from ..support import wait_until


def test_keyboard_teleop_over_a_pseudo_terminal(make_context: Callable[..., Context]) -> None:
    ctx = make_context()
    master, slave = pty.openpty()
    received: list[tuple[float, float, float]] = []
    with (
        Node("teleop", context=ctx) as node,
        Node("listener", context=ctx) as listener,
        open(slave, closefd=True) as tty_in,
        open(os.devnull, "w") as sink,
    ):
        listener.create_subscription(
            "geometry_msgs/msg/Twist",
            "/c3po/cmd_vel",
            lambda m: received.append((time.monotonic(), m.linear.x, m.angular.z)),
        )
        publisher = TwistPublisher(node, "/c3po/cmd_vel")
        assert wait_until(lambda: publisher.publisher.matched_subscriptions > 0, 5.0)
        stop = threading.Event()
        teleop = KeyboardTeleop(speed=0.5, turn=1.0, repeat_timeout=0.2, initial_repeat_delay=0.3)
        worker = threading.Thread(
            target=run_keyboard, args=(publisher, teleop), kwargs={"rate": 20.0, "stdin": tty_in, "out": sink,
                                                                    "stop": stop},
        )  # fmt: skip
        worker.start()
        try:
            for _ in range(15):  # hold "u" (forward-left) with a 40 ms auto-repeat
                os.write(master, b"u")
                time.sleep(0.04)
            released = time.monotonic()
            assert wait_until(lambda: any(t > released and v == 0.0 for t, v, _ in received), 3.0)
            moving = [(v, w) for _, v, w in received if v != 0.0]
            assert len(moving) >= 5  # ~0.6 s at 20 Hz, fewer on a loaded machine
            assert all((v, w) == (0.5, 1.0) for v, w in moving)
            first_zero = min(t for t, v, _ in received if t > released and v == 0.0)
            assert first_zero - released < 0.2 + 0.3  # release seen after the repeat timeout (+ a tick, + load)
            count = len(received)
            time.sleep(0.5)
            assert len(received) <= count + 3  # then silent: a few zeros at most
            os.write(master, b"\x03")  # Ctrl-C in raw mode ends the loop
            worker.join(5.0)
            assert not worker.is_alive()
        finally:
            stop.set()
            worker.join(5.0)
            os.close(master)


def test_autopilot_node_drives_the_base_controller_along_a_route(make_context: Callable[..., Context]) -> None:
    robot_ctx = make_context(namespace="/r2d2")
    config = RobotConfig()
    with Node("base_controller", context=robot_ctx) as base, Node("autopilot", context=robot_ctx) as pilot_node:
        controller = BaseControllerNode(base, MotorModelDrive.from_config(config), config=config)
        route = Route("short", ((0.0, 0.0), (0.8, 0.0), (0.8, 0.5)))
        pilot = AutopilotNode(pilot_node, route, rate=20.0, max_speed=0.5, lookahead=0.3, arrival_tolerance=0.12)
        assert pilot.done.wait(20.0)
        out: Any = controller.last_output
        assert out is not None
        # done within arrival_tolerance (0.12) of the end, approached along +y: braking only brings it closer
        # (x 0.03, y 0.105 off measured); 0.15 leaves 3 cm for overshoot past the end
        assert abs(out.odometry.x - 0.8) < 0.15 and abs(out.odometry.y - 0.5) < 0.15
        # braking from ≤ 0.5 m/s at 1.5 m/s² takes ≤ 0.33 s
        assert wait_until(lambda: abs(controller.last_output.odometry.v) < 0.02, 2.0)  # type: ignore[union-attr]


def test_joystick_driver_without_a_device_publishes_only_the_final_zero(
    make_context: Callable[..., Context],
) -> None:
    import pytest

    pytest.importorskip("pygame")
    from fleetslam.robot.teleop import JOY_PRESETS
    from fleetslam.robot.teleop_node import run_joystick

    ctx = make_context()
    received: list[float] = []
    with Node("teleop", context=ctx) as node, Node("listener", context=ctx) as listener:
        listener.create_subscription("geometry_msgs/msg/Twist", "/c3po/cmd_vel", lambda m: received.append(m.linear.x))
        publisher = TwistPublisher(node, "/c3po/cmd_vel")
        assert wait_until(lambda: publisher.publisher.matched_subscriptions > 0, 5.0)
        stop = threading.Event()
        worker = threading.Thread(target=run_joystick, args=(publisher, JOY_PRESETS["xbox"]),
                                  kwargs={"device_index": 99, "stop": stop})  # fmt: skip
        worker.start()
        time.sleep(0.5)
        assert received == []
        stop.set()
        worker.join(5.0)
        assert not worker.is_alive()
        assert wait_until(lambda: received == [0.0], 3.0)
