"""`fleetslam launch FILE`: start and supervise a fleet on this host, or print per-host instructions."""

from __future__ import annotations

import argparse
import socket
import sys

from fleetslam.launch.description import format_host_instructions, load_fleet, resolve_processes
from fleetslam.launch.supervisor import Supervisor


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="fleet description (YAML)")
    parser.add_argument(
        "--print-hosts", action="store_true", help="print, per host, the environment and command to run there"
    )
    parser.add_argument(
        "--host",
        action="append",
        help="run only the processes of this host (repeatable; default: every process, as on one machine)",
    )
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a key")
    parser.add_argument("--grace", type=float, default=5.0, help="seconds to wait for each shutdown signal")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    fleet = load_fleet(args.file, overrides=args.set)
    if args.print_hosts:
        print(format_host_instructions(fleet), end="")
        return 0
    processes = resolve_processes(fleet)
    if args.host:
        wanted = set(args.host)
        if "self" in wanted:
            wanted |= {socket.gethostname(), "localhost"}
        processes = [p for p in processes if p.host in wanted]
    if not processes:
        print(f"fleetslam launch: no process to run on host(s) {args.host}", file=sys.stderr)
        return 2
    supervisor = Supervisor(processes, output=sys.stdout, grace_s=args.grace)
    supervisor.run()
    return 0
