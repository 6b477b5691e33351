"""A base controller with the motor model behind it, printing one JSON line per 10 ms: wall time, the wheels'
forward speed and the wall time of the last command it accepted. Run inside a robot's network namespace by
``test_link_cut.py``; its stdout is a pipe, so the log still reaches the test when the robot's link is down."""

from __future__ import annotations

import json
import sys
import time

from fleetslam.middleware import Context, Node
from fleetslam.robot.config import RobotConfig
from fleetslam.robot.drive import MotorModelDrive
from fleetslam.robot.node import BaseControllerNode


def main() -> None:
    duration = float(sys.argv[1])
    config = RobotConfig()
    with Context() as ctx, Node("base_controller", context=ctx) as node:
        drive = MotorModelDrive.from_config(config)
        base = BaseControllerNode(node, drive, config=config)
        print(json.dumps({"ready": True}), flush=True)
        end = time.monotonic() + duration
        while time.monotonic() < end:
            left, right = drive.wheel_velocities()
            v = 0.5 * (left + right) * config.wheel_radius
            print(json.dumps({"t": time.time(), "v": v, "cmd": base.last_external_command}), flush=True)
            time.sleep(0.01)


if __name__ == "__main__":
    main()
