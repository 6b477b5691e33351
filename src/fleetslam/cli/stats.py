"""`fleetslam stats`: a live table of network statistics per agent and topic, from /statistics."""

from __future__ import annotations

import argparse
import json
import threading
import time
from typing import Any

from fleetslam.cli.common import cli_node
from fleetslam.middleware.stats_table import StatsTable, format_table
from fleetslam.topics import STATISTICS


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--agent", help="only this agent (as publisher or subscriber)")
    parser.add_argument("--json", action="store_true", help="one JSON object per row and window")
    parser.add_argument("--once", action="store_true", help="print one snapshot after --wait seconds and exit")
    parser.add_argument("--wait", type=float, default=2.5, help="seconds to collect before a --once snapshot")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    parser.add_argument("--interval", type=float, default=1.0, help="refresh period of the table")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    table = StatsTable()
    lock = threading.Lock()

    def on_statistics(msg: Any) -> None:
        with lock:
            row = table.update(msg)
        if args.json and not args.once and (not args.agent or args.agent in (row.agent, row.node_sub.split("/")[1])):
            print(json.dumps(row.as_dict()), flush=True)

    with cli_node("stats") as node:
        node.create_subscription(STATISTICS.type, STATISTICS.name, on_statistics, STATISTICS.qos(depth=1000))
        start = time.monotonic()
        if args.once:
            time.sleep(args.wait)
            with lock:
                rows = table.rows(agent=args.agent, now_ns=time.time_ns())
            if args.json:
                for row in rows:
                    print(json.dumps(row.as_dict()))
            else:
                print(format_table(rows) if rows else "no statistics received (is anything subscribed?)")
            return 0 if rows else 1
        try:
            while not args.duration or time.monotonic() - start < args.duration:
                time.sleep(args.interval)
                if not args.json:
                    with lock:
                        rows = table.rows(agent=args.agent, now_ns=time.time_ns())
                    print("\033[2J\033[H" + time.strftime("%H:%M:%S") + "\n" + format_table(rows), flush=True)
        except KeyboardInterrupt:
            pass
    return 0
