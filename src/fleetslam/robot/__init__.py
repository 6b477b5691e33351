"""The robot base: diff-drive kinematics and wheel odometry (pure), PID and speed limits, the base controller,
routes and the autopilot, keyboard and joystick teleoperation, and their nodes.

Names are loaded on first use; pygame (the ``teleop`` extra) only when a joystick is opened.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.robot.autopilot import ROUTES, Autopilot, Route, get_route, register_route
    from fleetslam.robot.autopilot_node import AutopilotNode
    from fleetslam.robot.config import PidGains, RobotConfig, SpeedLimits
    from fleetslam.robot.controller import BaseController, ControllerOutput
    from fleetslam.robot.drive import MotorModelDrive
    from fleetslam.robot.interfaces import WheelInterface
    from fleetslam.robot.kinematics import body_increment, body_twist, wheel_speeds
    from fleetslam.robot.limits import SpeedLimiter
    from fleetslam.robot.node import BaseControllerNode
    from fleetslam.robot.odometry import Odometry, OdometryState
    from fleetslam.robot.pid import Pid
    from fleetslam.robot.teleop import JoyMapper, JoyPreset, JoyTeleop, KeyboardTeleop, load_joy_preset
    from fleetslam.robot.teleop_node import TwistPublisher, run_joystick, run_keyboard

__all__ = [
    "ROUTES",
    "Autopilot",
    "AutopilotNode",
    "BaseController",
    "BaseControllerNode",
    "ControllerOutput",
    "JoyMapper",
    "JoyPreset",
    "JoyTeleop",
    "KeyboardTeleop",
    "MotorModelDrive",
    "Odometry",
    "OdometryState",
    "Pid",
    "PidGains",
    "RobotConfig",
    "Route",
    "SpeedLimiter",
    "SpeedLimits",
    "TwistPublisher",
    "WheelInterface",
    "body_increment",
    "body_twist",
    "get_route",
    "load_joy_preset",
    "register_route",
    "run_joystick",
    "run_keyboard",
    "wheel_speeds",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "config": ["PidGains", "RobotConfig", "SpeedLimits"],
            "kinematics": ["body_increment", "body_twist", "wheel_speeds"],
            "odometry": ["Odometry", "OdometryState"],
            "pid": ["Pid"],
            "limits": ["SpeedLimiter"],
            "controller": ["BaseController", "ControllerOutput"],
            "interfaces": ["WheelInterface"],
            "drive": ["MotorModelDrive"],
            "autopilot": ["ROUTES", "Autopilot", "Route", "get_route", "register_route"],
            "teleop": ["JoyMapper", "JoyPreset", "JoyTeleop", "KeyboardTeleop", "load_joy_preset"],
            "node": ["BaseControllerNode"],
            "autopilot_node": ["AutopilotNode"],
            "teleop_node": ["TwistPublisher", "run_joystick", "run_keyboard"],
        },
    )
