"""`fleetslam bridge ros1`: a fleet (FLEETSLAM_ROUTER) and a ROS 1 master (ROS_MASTER_URI) see each other's topics
and services."""

from __future__ import annotations

import argparse
import os
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    ros1 = sub.add_parser(
        "ros1",
        help="bridge topics and services to and from a ROS 1 master (ROS_MASTER_URI, ROS_IP/ROS_HOSTNAME)",
        description="Rules are absolute topic or service names, fnmatch patterns ('/c3po/*', '*' for all) or "
        "remaps ('/c3po/cmd_vel:=/cmd_vel'). Without rules nothing is bridged. Services are bridged where their "
        "type exists on both sides (std_srvs Empty, SetBool, Trigger; fleetslam_msgs SaveMap, ClearBbx).",
    )
    ros1.add_argument("--to-ros1", action="append", default=[], metavar="RULE", help="fleet topics to publish in ROS 1")
    ros1.add_argument(
        "--from-ros1", action="append", default=[], metavar="RULE", help="ROS 1 topics to publish in the fleet"
    )
    ros1.add_argument(
        "--service-to-ros1", action="append", default=[], metavar="RULE", help="fleet services to provide in ROS 1"
    )
    ros1.add_argument(
        "--service-from-ros1",
        action="append",
        default=[],
        metavar="RULE",
        help="ROS 1 services to serve in the fleet",
    )
    ros1.add_argument(
        "--all", action="store_true", help="bridge every topic and service both ways (same as '*' for each rule)"
    )
    ros1.add_argument(
        "--service-timeout", type=float, default=10.0, metavar="S", help="seconds a bridged call waits for the far side"
    )
    ros1.add_argument("--name", default="fleetslam_bridge", help="node name on both sides")
    ros1.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: Ctrl-C)")
    ros1.set_defaults(func=run_ros1)

    rviz = sub.add_parser("rviz-config", help="write an RViz 1 configuration showing the agents' maps, paths, poses")
    rviz.add_argument("agents", nargs="+", help="agent names, e.g. c3po r2d2")
    rviz.add_argument("--fixed-frame", default="map", help="RViz fixed frame (the fused map is in 'fleet')")
    rviz.add_argument("-o", "--output", type=Path, default=None, help="file to write (default: standard output)")
    rviz.set_defaults(func=run_rviz_config)


def run_rviz_config(args: argparse.Namespace) -> int:
    from fleetslam.ros1.rviz import rviz_config

    text = rviz_config(args.agents, fixed_frame=args.fixed_frame)
    if args.output is None:
        print(text, end="")
    else:
        args.output.write_text(text, encoding="utf-8")
        print(f"wrote {args.output}; open it with: rviz -d {args.output}")
    return 0


def run_ros1(args: argparse.Namespace) -> int:
    from fleetslam.cli.common import stop_on_sigterm, wait_until_stopped
    from fleetslam.middleware import Context, Node
    from fleetslam.ros1.bridge import Ros1Bridge, TopicRule
    from fleetslam.ros1.node import Ros1Node, master_from_env

    to_ros1 = [TopicRule.parse(r) for r in args.to_ros1 + ["*"] * args.all]
    from_ros1 = [TopicRule.parse(r) for r in args.from_ros1 + ["*"] * args.all]
    services_to_ros1 = [TopicRule.parse(r) for r in args.service_to_ros1 + ["*"] * args.all]
    services_from_ros1 = [TopicRule.parse(r) for r in args.service_from_ros1 + ["*"] * args.all]
    master, host = master_from_env(os.environ)
    stop = stop_on_sigterm()
    with (
        Ros1Node(args.name, master_uri=master, host=host) as ros1,
        Context() as ctx,
        Node(args.name, context=ctx) as node,
        Ros1Bridge(
            node,
            ros1,
            to_ros1=to_ros1,
            from_ros1=from_ros1,
            services_to_ros1=services_to_ros1,
            services_from_ros1=services_from_ros1,
            service_timeout_s=args.service_timeout,
        ),
    ):
        print(f"bridge {node.fq_name}: fleet <-> ROS 1 master {master} (Ctrl-C to stop)", flush=True)
        wait_until_stopped(stop, args.duration)
    return 0
