"""`fleetslam bridge ros1`: a fleet (FLEETSLAM_ROUTER) and a ROS 1 master (ROS_MASTER_URI) see each other's topics."""

from __future__ import annotations

import argparse
import os
import signal
import threading
import time


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    ros1 = sub.add_parser(
        "ros1",
        help="bridge topics to and from a ROS 1 master (ROS_MASTER_URI, ROS_IP/ROS_HOSTNAME)",
        description="Rules are absolute topic names, fnmatch patterns ('/c3po/*', '*' for all) or remaps "
        "('/c3po/cmd_vel:=/cmd_vel'). Without rules nothing is bridged.",
    )
    ros1.add_argument("--to-ros1", action="append", default=[], metavar="RULE", help="fleet topics to publish in ROS 1")
    ros1.add_argument(
        "--from-ros1", action="append", default=[], metavar="RULE", help="ROS 1 topics to publish in the fleet"
    )
    ros1.add_argument("--all", action="store_true", help="bridge every topic both ways (same as '*' both ways)")
    ros1.add_argument("--name", default="fleetslam_bridge", help="node name on both sides")
    ros1.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: Ctrl-C)")
    ros1.set_defaults(func=run_ros1)


def run_ros1(args: argparse.Namespace) -> int:
    from fleetslam.middleware import Context, Node
    from fleetslam.ros1.bridge import Ros1Bridge, TopicRule
    from fleetslam.ros1.node import Ros1Node, master_from_env

    to_ros1 = [TopicRule.parse(r) for r in args.to_ros1 + ["*"] * args.all]
    from_ros1 = [TopicRule.parse(r) for r in args.from_ros1 + ["*"] * args.all]
    master, host = master_from_env(os.environ)
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():  # signals reach the main thread only
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with (
        Ros1Node(args.name, master_uri=master, host=host) as ros1,
        Context() as ctx,
        Node(args.name, context=ctx) as node,
        Ros1Bridge(node, ros1, to_ros1=to_ros1, from_ros1=from_ros1),
    ):
        print(f"bridge {node.fq_name}: fleet <-> ROS 1 master {master} (Ctrl-C to stop)", flush=True)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        try:
            while not stop.wait(0.2) and (deadline is None or time.monotonic() < deadline):
                pass
        except KeyboardInterrupt:
            pass
    return 0
