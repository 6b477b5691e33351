"""`fleetslam fleet node`: fuse every agent's map into the fleet map."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    node = sub.add_parser("node", help="run the fleet map node (agents' map/octomap -> /fleet/map/*)")
    node.add_argument("--config", type=Path, default=None, help="YAML parameters (resolution, start_poses, ...)")
    node.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    node.set_defaults(func=run_node)


def run_node(args: argparse.Namespace) -> int:
    from fleetslam.fusion.node import FleetMapConfig, FleetMapNode
    from fleetslam.middleware import Context, Node

    with Context() as ctx:
        node = Node(
            "fleet_map", context=ctx, namespace="/", parameters=FleetMapConfig, parameter_file=args.config,
            parameter_overrides=args.set, ros_args=getattr(args, "ros_args", None),
        )  # fmt: skip
        with node:
            FleetMapNode(node, node.parameters)
            print("fleet map node running (Ctrl-C to stop)", flush=True)
            with contextlib.suppress(KeyboardInterrupt):
                node.spin()
    return 0
