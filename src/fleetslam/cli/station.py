"""`fleetslam station [--port 8080]`: the operator console in the browser."""

from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path

from fleetslam.cli.common import stop_on_sigterm, wait_until_stopped
from fleetslam.errors import ConfigError
from fleetslam.middleware import Context
from fleetslam.station.access import ConsoleAccess
from fleetslam.station.protocol import TeleopLimits
from fleetslam.station.server import StationServer


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=int, default=8080, help="HTTP port")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    parser.add_argument("--max-linear", type=float, default=0.5, help="speed limit for teleoperation (m/s)")
    parser.add_argument("--max-angular", type=float, default=1.2, help="turn-rate limit (rad/s)")
    parser.add_argument(
        "--token",
        default=os.environ.get("FLEETSLAM_STATION_TOKEN"),
        help="secret the WebSocket asks for, part of the printed URL (default: $FLEETSLAM_STATION_TOKEN, else random)",
    )
    parser.add_argument(
        "--allow-origin", action="append", default=[], metavar="URL",
        help="another origin (scheme://host:port) whose pages may use the console, e.g. behind a reverse proxy",
    )  # fmt: skip
    parser.add_argument(
        "--findings", type=Path, metavar="DIR",
        help="serve the fleet's findings from this console, kept in DIR (findings.json and photos); without it, "
        "another process (the demo) serves them",
    )  # fmt: skip
    parser.add_argument(
        "--session", type=Path, metavar="DIR",
        help="review a finished run (a demo's results folder): its maps, trajectories (a time slider replays them), "
        "findings, and its recorded camera if the recording holds images; no robot, no network",
    )  # fmt: skip
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    stop = stop_on_sigterm()
    limits = TeleopLimits(max_linear=args.max_linear, max_angular=args.max_angular)
    try:
        access = ConsoleAccess.create(args.token, args.allow_origin)
    except ValueError as err:
        raise ConfigError(f"--token / FLEETSLAM_STATION_TOKEN: {err}") from err
    with contextlib.ExitStack() as stack:
        if args.session is not None:
            server = stack.enter_context(
                StationServer(None, host=args.host, port=args.port, limits=limits, access=access, session=args.session)
            )
            print(f"operator console (reviewing {args.session}): {server.url}", flush=True)
            wait_until_stopped(stop)
            return 0
        ctx = stack.enter_context(Context())
        if args.findings is not None:
            from fleetslam.inspection.node import FindingsNode

            stack.enter_context(FindingsNode(ctx, args.findings))
        server = stack.enter_context(StationServer(ctx, host=args.host, port=args.port, limits=limits, access=access))
        print(f"operator console: {server.url}", flush=True)
        wait_until_stopped(stop)
    return 0
