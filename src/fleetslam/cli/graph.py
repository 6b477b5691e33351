"""`fleetslam node list | info NAME`: the nodes of the running system, printed as `ros2 node` does."""

from __future__ import annotations

import argparse
import sys

from fleetslam.cli.common import cli_node, wait_for_graph
from fleetslam.errors import MiddlewareError
from fleetslam.middleware.wire import EntityKind

_SECTIONS = (
    ("Subscribers", EntityKind.SUBSCRIBER),
    ("Publishers", EntityKind.PUBLISHER),
    ("Service Servers", EntityKind.SERVICE),
    ("Service Clients", EntityKind.CLIENT),
)


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    listing = sub.add_parser("list", help="list nodes")
    listing.add_argument("-a", "--all", action="store_true", help="also hidden nodes (base name starting with _)")
    listing.add_argument("-c", "--count-nodes", action="store_true", help="only print the number of nodes")
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
        names = [n.fq_name for n in graph.nodes() if args.all or not n.name.startswith("_")]
        if args.count_nodes:
            print(len(set(names)))
            return 0
        if len(names) != len(set(names)):
            print("WARNING: Be aware that there are nodes in the graph that share an exact name, "
                  "which can have unintended side effects.", file=sys.stderr)  # fmt: skip
        for name in sorted(set(names)):
            print(name)
    return 0


def run_info(args: argparse.Namespace) -> int:
    name = args.name if args.name.startswith("/") else f"/{args.name}"
    with cli_node("node") as node:
        graph = node.context.graph
        wait_for_graph(node, lambda: name in graph.node_fq_names(), args.wait)
        if name not in graph.node_fq_names():
            raise MiddlewareError(f"Unable to find node '{name}'; see `fleetslam node list`")
        namespace, _, base = name.rpartition("/")
        entities = graph.node_entities(namespace or "/", base)
        print(name)
        for title, kind in _SECTIONS:
            print(f"  {title}:")
            rows = sorted({(t.topic, t.type_name) for t in entities if t.kind is kind})
            for topic, type_name in rows:
                print(f"    {topic}: {type_name}")
    return 0
