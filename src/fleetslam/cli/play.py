"""`fleetslam play PATH [--rate R] [--loop] [--topics …]`: republish a recording with its original timing."""

from __future__ import annotations

import argparse

from fleetslam.cli.common import cli_node
from fleetslam.middleware.player import play as play_recording


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="rosbag2 folder")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    parser.add_argument("--loop", action="store_true", help="start again at the end")
    parser.add_argument("--topics", nargs="+", help="only these topics")
    parser.set_defaults(func=run)


def play(path: str, *, rate: float = 1.0, loop: bool = False, topics: list[str] | None = None) -> int:
    """Publish the recording's messages with their relative timing divided by ``rate``; returns the count."""
    if rate <= 0:  # before joining the fleet
        raise ValueError(f"rate must be positive, got {rate}")
    with cli_node("play") as node:
        return play_recording(node, path, rate=rate, loop=loop, topics=topics)


def run(args: argparse.Namespace) -> int:
    try:
        count = play(args.path, rate=args.rate, loop=args.loop, topics=args.topics)
    except KeyboardInterrupt:
        return 0
    print(f"played {count} messages from {args.path}", flush=True)
    return 0
