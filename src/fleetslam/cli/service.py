"""`fleetslam service list | call`, as ros2 service does."""

from __future__ import annotations

import argparse

import yaml

from fleetslam.cli.common import cli_node, to_yaml, wait_for_graph
from fleetslam.errors import ConfigError
from fleetslam.middleware.names import expand_name
from fleetslam.msg.typesys import message_from_dict, message_to_dict, service_types


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    listing = sub.add_parser("list", help="list services")
    listing.add_argument("-t", "--show-types", action="store_true")
    listing.add_argument("--wait", type=float, default=1.0)
    listing.set_defaults(func=run_list)
    call = sub.add_parser("call", help="call a service with a request given as YAML")
    call.add_argument("service")
    call.add_argument("type", help="service type, e.g. std_srvs/srv/SetBool")
    call.add_argument("values", nargs="?", default="{}", help="request as YAML, e.g. '{data: true}'")
    call.add_argument("--timeout", type=float, default=10.0)
    call.set_defaults(func=run_call)


def run_list(args: argparse.Namespace) -> int:
    with cli_node("service") as node:
        wait_for_graph(node, lambda: False, args.wait)
        for name, types in node.context.graph.service_names_and_types().items():
            print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def run_call(args: argparse.Namespace) -> int:
    name = expand_name(args.service, namespace="/", node_name="_")
    request_type, _ = service_types(args.type)
    try:
        values = yaml.safe_load(args.values)
    except yaml.YAMLError as err:
        raise ConfigError(f"request {args.values!r} is not valid YAML: {err}") from err
    request = message_from_dict(request_type, values)
    with cli_node("call") as node:
        client = node.create_client(args.type, name)
        client.wait_for_service(min(args.timeout, 3.0))
        print(f"requester: making request: {message_to_dict(request)}\n", flush=True)
        response = client.call(request, timeout=args.timeout)
        print("response:")
        print(to_yaml(message_to_dict(response)), end="")
    return 0
