"""`fleetslam record -o PATH [TOPICS… | --all] [--duration S]`: record to rosbag2 (MCAP storage)."""

from __future__ import annotations

import argparse
import contextlib
import time
from typing import Any

from fleetslam.cli.common import cli_node
from fleetslam.errors import ConfigError
from fleetslam.middleware.recorder import Recorder
from fleetslam.middleware.recording import BagWriter


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("topics", nargs="*", help="topics to record")
    parser.add_argument("-o", "--output", required=True, help="new rosbag2 folder")
    parser.add_argument("-a", "--all", action="store_true", help="record every topic, also those appearing later")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    parser.set_defaults(func=run)


def record(output: str, topics: list[str], *, all_topics: bool, duration: float) -> int:
    """Record until ``duration`` passes or Ctrl-C; returns the number of messages written."""
    if not topics and not all_topics:
        raise ConfigError("record: give topics to record, or --all")
    # The node goes first on the way out: no callback may write into a closed bag.
    with BagWriter(output) as writer, cli_node("record") as node:
        recorder = Recorder(node, writer, topics, all_topics=all_topics)
        print(f"recording to {output} (Ctrl-C to stop)", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            recorder.run(duration)
        time.sleep(0.1)
        count = writer.count
    print(f"recorded {count} messages on {len(recorder.subscribed)} topics to {output}", flush=True)
    return count


def run(args: argparse.Namespace) -> Any:
    record(args.output, args.topics, all_topics=args.all, duration=args.duration)
    return 0
