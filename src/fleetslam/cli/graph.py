"""`fleetslam node list | info NAME`: the nodes of the running system, as ros2 node does."""

from __future__ import annotations

import argparse

from fleetslam.cli.common import cli_node, wait_for_graph
from fleetslam.errors import MiddlewareError
from fleetslam.middleware.wire import EntityKind


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    listing = sub.add_parser("list", help="list nodes")
    listing.add_argument("--wait", type=float, default=1.0, help="seconds to wait for discovery")
    listing.set_defaults(func=run_list)
    info = sub.add_parser("info", help="publishers, subscribers, services and clients of a node")
    info.add_argument("name", help="fully qualified node name, e.g. /c3po/slam")
    info.add_argument("--wait", type=float, default=1.0, help="seconds to wait for discovery")
    info.set_defaults(func=run_info)


def run_list(args: argparse.Namespace) -> int:
    with cli_node("node") as node:
        graph = node.context.graph
        wait_for_graph(node, lambda: False, args.wait)
        for name in graph.node_fq_names():
            if "/_fleetslam_" not in name:
                print(name)
    return 0


def run_info(args: argparse.Namespace) -> int:
    with cli_node("node") as node:
        graph = node.context.graph
        wait_for_graph(node, lambda: args.name in graph.node_fq_names(), args.wait)
        if args.name not in graph.node_fq_names():
            raise MiddlewareError(f"node '{args.name}' not found; see `fleetslam node list`")
        namespace, _, base = args.name.rpartition("/")
        entities = graph.node_entities(namespace or "/", base)
        print(args.name)
        for title, kind in (
            ("Subscribers", EntityKind.SUBSCRIBER),
            ("Publishers", EntityKind.PUBLISHER),
            ("Service Servers", EntityKind.SERVICE),
            ("Service Clients", EntityKind.CLIENT),
        ):
            print(f"  {title}:")
            for token in sorted((t for t in entities if t.kind is kind), key=lambda t: t.topic):
                print(f"    {token.topic}: {token.type_name}")
    return 0
