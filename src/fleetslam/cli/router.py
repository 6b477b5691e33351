"""`fleetslam router`: run the fleet's Zenoh router (the discovery service, rmw_zenohd's role) until Ctrl-C."""

from __future__ import annotations

import argparse
from pathlib import Path

from fleetslam.cli.common import stop_on_sigterm, wait_until_stopped
from fleetslam.middleware.router import DEFAULT_ROUTER_LISTEN, Router


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to listen on, repeatable (default {DEFAULT_ROUTER_LISTEN[0]})",
    )
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="other routers")
    parser.add_argument(
        "--security", type=Path, metavar="DIR",
        help="keystore of 'fleetslam security init': mutual TLS on its tls/ endpoint and the fleet's access control",
    )  # fmt: skip
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    stop = stop_on_sigterm()
    listen = args.listen or (None if args.security else list(DEFAULT_ROUTER_LISTEN))
    with Router(listen, connect=args.connect, security=args.security) as router:
        print(f"fleetslam router {router.zid} listening on {', '.join(router.listen)} (Ctrl-C to stop)", flush=True)
        wait_until_stopped(stop)
    print("router stopped", flush=True)
    return 0
