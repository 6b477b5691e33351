"""`fleetslam station [--port 8080]`: the operator console in the browser."""

from __future__ import annotations

import argparse
import contextlib
import signal
import threading

from fleetslam.middleware import Context
from fleetslam.station.protocol import TeleopLimits
from fleetslam.station.server import StationServer


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=int, default=8080, help="HTTP port")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    parser.add_argument("--max-linear", type=float, default=0.5, help="speed limit for teleoperation (m/s)")
    parser.add_argument("--max-angular", type=float, default=1.2, help="turn-rate limit (rad/s)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    limits = TeleopLimits(max_linear=args.max_linear, max_angular=args.max_angular)
    with Context() as ctx, StationServer(ctx, host=args.host, port=args.port, limits=limits) as server:
        print(f"operator console: {server.url}", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            stop.wait()
    return 0
