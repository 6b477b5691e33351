"""`fleetslam fleet node`: fuse every agent's map into the fleet map."""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    node = sub.add_parser("node", help="run the fleet map node (agents' map/octomap -> /fleet/map/*)")
    node.add_argument("--config", type=Path, default=None, help="YAML parameters (resolution, start_poses, ...)")
    node.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    node.set_defaults(func=run_node)


def run_node(args: argparse.Namespace) -> int:
    from fleetslam.cli.common import run_adapter_node
    from fleetslam.fusion.node import FleetMapConfig, FleetMapNode

    return run_adapter_node(args, "fleet_map", FleetMapConfig, FleetMapNode, namespace="/")
