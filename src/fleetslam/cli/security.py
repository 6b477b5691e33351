"""`fleetslam security init DIR --agents c3po,r2d2 [--station NAME]`: a fleet's keystore; `fleetslam security
rotate DIR HOST`: a new password for one host (see docs/security.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from fleetslam.middleware.context import MAX_MESSAGE_BYTES
from fleetslam.security.keystore import init_keystore, rotate_password


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    init = sub.add_parser("init", help="make a CA, each host's key, certificate and password, and the Zenoh configs")
    init.add_argument("directory", type=Path, help="new (or empty) folder of the keystore")
    init.add_argument("--agents", required=True, help="robots, comma separated (c3po,r2d2)")
    init.add_argument(
        "--station",
        action="append",
        default=[],
        metavar="NAME",
        help="operator hosts that may drive every robot and call every service (default: station)",
    )
    init.add_argument(
        "--router-host",
        action="append",
        default=[],
        metavar="NAME",
        help="name or address the hosts reach the router at, repeatable (default: localhost, 127.0.0.1)",
    )
    init.add_argument("--port", type=int, default=7447, help="router port (default 7447)")
    init.set_defaults(func=run_init)  # fmt: skip
    rotate = sub.add_parser("rotate", help="give one host a new password (its config and the router's dictionary)")
    rotate.add_argument("directory", type=Path, help="the keystore made by 'security init' (the whole folder)")
    rotate.add_argument("host", help="the agent or station whose password changes")
    rotate.set_defaults(func=run_rotate)


def run_init(args: argparse.Namespace) -> int:
    agents = [a.strip() for a in args.agents.split(",") if a.strip()]
    made = init_keystore(
        args.directory, agents=agents, stations=args.station or ["station"],
        router_hosts=args.router_host or ["localhost", "127.0.0.1"], router_port=args.port,
        max_message_bytes=MAX_MESSAGE_BYTES,
    )  # fmt: skip
    print(f"keystore in {args.directory}: {', '.join(made)}")
    print(f"  router:  fleetslam router --security {args.directory}")
    print(f"  a host:  copy {args.directory}/<host>/ to it; FLEETSLAM_SECURITY=<that folder> fleetslam ...")
    print(f"  keep {args.directory}/ca.key offline: whoever has it can make certificates for the fleet")
    print(f"  passwords: each host's in its zenoh.json5, all of them in {args.directory}/router/passwords")
    return 0


def run_rotate(args: argparse.Namespace) -> int:
    folder = rotate_password(args.directory, args.host)
    print(f"new password for {args.host} in {folder}/zenoh.json5 and {args.directory}/router/passwords")
    print(f"  1. copy {folder}/zenoh.json5 to {args.host}'s keys folder (and router/passwords to the router's)")
    print("  2. restart the router (it reads its passwords when it starts), then the nodes on " + args.host)
    return 0
