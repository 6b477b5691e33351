"""`fleetslam fleet node`: fuse every agent's map into the fleet map; `fleetslam fleet backend`: the joint
optimisation of every agent's keyframe graph (placements and corrected paths in the fleet frame)."""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    node = sub.add_parser("node", help="run the fleet map node (agents' map/octomap -> /fleet/map/*)")
    node.add_argument("--config", type=Path, default=None, help="YAML parameters (resolution, start_poses, ...)")
    node.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    node.set_defaults(func=run_node)
    backend = sub.add_parser(
        "backend", help="run the fleet back-end (agents' graph_updates -> /fleet/placements, <agent>/fleet_path)"
    )
    backend.add_argument("--config", type=Path, default=None, help="YAML parameters (reference, agents, rate, ...)")
    backend.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    backend.set_defaults(func=run_backend)


def run_node(args: argparse.Namespace) -> int:
    from fleetslam.cli.common import run_adapter_node
    from fleetslam.fusion.node import FleetMapConfig, FleetMapNode

    return run_adapter_node(args, "fleet_map", FleetMapConfig, FleetMapNode, namespace="/")


def run_backend(args: argparse.Namespace) -> int:
    from fleetslam.cli.common import run_adapter_node
    from fleetslam.fusion.fleet_graph_node import FleetGraphConfig, FleetGraphNode

    return run_adapter_node(args, "fleet_backend", FleetGraphConfig, FleetGraphNode, namespace="/")
