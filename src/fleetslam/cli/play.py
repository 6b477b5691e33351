"""`fleetslam play PATH [--rate R] [--loop] [--topics …]`: republish a recording with its original timing."""

from __future__ import annotations

import argparse
import time

from fleetslam.cli.common import cli_node, settle
from fleetslam.middleware.recording import bag_topics, read_bag


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="rosbag2 folder")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    parser.add_argument("--loop", action="store_true", help="start again at the end")
    parser.add_argument("--topics", nargs="+", help="only these topics")
    parser.set_defaults(func=run)


def play(path: str, *, rate: float = 1.0, loop: bool = False, topics: list[str] | None = None) -> int:
    """Publish the recording's messages with their relative timing divided by ``rate``; returns the count."""
    if rate <= 0:
        raise ValueError(f"rate must be positive, got {rate}")
    types = bag_topics(path)
    selected = set(topics) if topics else None
    sent = 0
    with cli_node("play") as node:
        publishers = {
            (topic, type_name): node.create_publisher(type_name, topic)
            for topic, type_name in types.items()
            if selected is None or topic in selected
        }
        settle(0.5)
        while True:
            first_stamp = None
            start = time.monotonic()
            for message in read_bag(path, selected):
                if first_stamp is None:
                    first_stamp = message.timestamp_ns
                due = start + (message.timestamp_ns - first_stamp) / 1e9 / rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                publishers[(message.topic, message.type_name)].publish_raw(message.data)
                sent += 1
            if not loop:
                break
        settle(0.3)
    return sent


def run(args: argparse.Namespace) -> int:
    try:
        count = play(args.path, rate=args.rate, loop=args.loop, topics=args.topics)
    except KeyboardInterrupt:
        return 0
    print(f"played {count} messages from {args.path}", flush=True)
    return 0
