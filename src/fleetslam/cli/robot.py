"""`fleetslam robot`: run a base controller node, drive a route with the autopilot, list routes."""

from __future__ import annotations

import argparse

from fleetslam.cli.common import stop_on_sigterm, wait_until_stopped
from fleetslam.config import load_config
from fleetslam.middleware import Context, Node
from fleetslam.robot.autopilot import ROUTES, get_route
from fleetslam.robot.config import RobotConfig


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="robot_command", required=True, metavar="<command>")

    run_parser = sub.add_parser("run", help="run the base controller: cmd_vel -> wheels, odom, joint_states, tf")
    run_parser.add_argument("--robot", help="agent namespace (default $FLEETSLAM_AGENT)")
    run_parser.add_argument("--config", help="robot YAML file (see config/robot.yaml)")
    run_parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a key")
    run_parser.add_argument(
        "--drive",
        choices=["model"],
        default="model",
        help="drive train: 'model' is a modelled pair of motors (the simulator runs its own controller)",
    )
    run_parser.add_argument("--name", default="base_controller", help="node name")
    run_parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    run_parser.set_defaults(func=run_base)

    pilot = sub.add_parser("autopilot", help="follow a named route, publishing cmd_vel from odom")
    pilot.add_argument("--robot", help="agent namespace (default $FLEETSLAM_AGENT)")
    pilot.add_argument("--route", default="loop", help=f"route name ({', '.join(sorted(ROUTES))})")
    pilot.add_argument("--max-speed", type=float, default=0.5, help="cruise speed, m/s")
    pilot.add_argument("--lookahead", type=float, default=0.6, help="pure-pursuit lookahead, m")
    pilot.add_argument("--stamped", action="store_true", help="publish TwistStamped instead of Twist")
    pilot.set_defaults(func=run_autopilot)

    routes = sub.add_parser("routes", help="list the named routes")
    routes.set_defaults(func=run_routes)


def _namespace(robot: str | None) -> str | None:
    return f"/{robot.strip('/')}" if robot else None


def run_base(args: argparse.Namespace) -> int:
    from fleetslam.robot.drive import MotorModelDrive
    from fleetslam.robot.node import BaseControllerNode

    config = load_config(RobotConfig, args.config, overrides=args.set, env_prefix="robot")
    stop = stop_on_sigterm()
    with Context(namespace=_namespace(args.robot)) as ctx, Node(args.name, context=ctx) as node:
        BaseControllerNode(node, MotorModelDrive.from_config(config), config=config)
        print(f"base controller {node.fq_name}: cmd_vel -> {args.drive} drive (Ctrl-C to stop)", flush=True)
        wait_until_stopped(stop, args.duration)
    return 0


def run_autopilot(args: argparse.Namespace) -> int:
    from fleetslam.robot.autopilot_node import AutopilotNode

    route = get_route(args.route)
    with Context(namespace=_namespace(args.robot)) as ctx, Node("autopilot", context=ctx) as node:
        pilot = AutopilotNode(node, route, stamped=args.stamped, max_speed=args.max_speed, lookahead=args.lookahead)
        print(f"autopilot {node.fq_name}: route {route.name!r} (Ctrl-C to stop)", flush=True)
        try:
            while not pilot.done.wait(0.2):
                pass
            print("route done", flush=True)
        except KeyboardInterrupt:
            pilot.publisher.publish(0.0, 0.0)
    return 0


def run_routes(args: argparse.Namespace) -> int:
    for name in sorted(ROUTES):
        route = ROUTES[name]
        kind = "closed" if route.closed else "open"
        print(f"{name}: {len(route.waypoints)} waypoints, {kind}, frame {route.frame}")
    return 0
