"""`fleetslam teleop`: drive a robot with the keyboard (terminal) or a joystick (SDL via pygame)."""

from __future__ import annotations

import argparse
import contextlib

from fleetslam.middleware import Context, Node
from fleetslam.topics import CMD_VEL


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="teleop_command", required=True, metavar="<command>")

    keyboard = sub.add_parser("keyboard", help="u i o / j k l / m , . keys, as teleop_twist_keyboard")
    keyboard.add_argument("--robot", help="publish /<ROBOT>/cmd_vel (default: cmd_vel in $FLEETSLAM_AGENT)")
    keyboard.add_argument("--speed", type=float, default=0.3, help="initial linear speed, m/s")
    keyboard.add_argument("--turn", type=float, default=0.8, help="initial angular speed, rad/s")
    keyboard.add_argument("--max-speed", type=float, default=0.8, help="largest linear speed, m/s")
    keyboard.add_argument("--max-turn", type=float, default=1.5, help="largest angular speed, rad/s")
    keyboard.add_argument("--rate", type=float, default=10.0, help="publication rate while a key is held, Hz")
    keyboard.add_argument("--repeat-timeout", type=float, default=0.2, help="key-release detection, s")
    keyboard.add_argument("--stamped", action="store_true", help="publish TwistStamped instead of Twist")
    keyboard.set_defaults(func=run_keyboard)

    joy = sub.add_parser("joy", help="a gamepad with deadman and turbo buttons, as teleop_twist_joy")
    joy.add_argument("--robot", help="publish /<ROBOT>/cmd_vel (default: cmd_vel in $FLEETSLAM_AGENT)")
    joy.add_argument(
        "--preset", default="xbox", help="xbox, ps, a preset YAML file, or FILE:NAME (config/joy_presets.yaml:ps)"
    )
    joy.add_argument("--device", type=int, default=0, help="joystick index")
    joy.add_argument("--stamped", action="store_true", help="publish TwistStamped instead of Twist")
    joy.set_defaults(func=run_joy)


def _topic(robot: str | None) -> str:
    return CMD_VEL.of(robot) if robot else CMD_VEL.name


def run_keyboard(args: argparse.Namespace) -> int:
    from fleetslam.robot.teleop import KeyboardTeleop
    from fleetslam.robot.teleop_node import TwistPublisher
    from fleetslam.robot.teleop_node import run_keyboard as drive

    teleop = KeyboardTeleop(
        speed=args.speed,
        turn=args.turn,
        max_speed=args.max_speed,
        max_turn=args.max_turn,
        repeat_timeout=args.repeat_timeout,
    )
    with Context(statistics=False) as ctx, Node("teleop_keyboard", context=ctx) as node:
        drive(TwistPublisher(node, _topic(args.robot), stamped=args.stamped), teleop, rate=args.rate)
    return 0


def run_joy(args: argparse.Namespace) -> int:
    from fleetslam.robot.teleop import load_joy_preset
    from fleetslam.robot.teleop_node import TwistPublisher, run_joystick

    preset = load_joy_preset(args.preset)
    with Context(statistics=False) as ctx, Node("teleop_joy", context=ctx) as node:
        publisher = TwistPublisher(node, _topic(args.robot), stamped=args.stamped)
        print(f"teleop joy: publishing on {publisher.topic}; hold button {preset.enable_button} to drive", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            run_joystick(publisher, preset, device_index=args.device)
    return 0
