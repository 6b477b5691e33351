"""`fleetslam convert`: a recording (rosbag2 folder, MCAP) as a ROS 1 bag for rosbag, RViz and ROS 1 tools."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", type=Path, help="rosbag2 folder written by 'fleetslam record'")
    parser.add_argument("output", type=Path, help="ROS 1 bag file to write (e.g. run.bag)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fleetslam.ros1.bag import convert_to_rosbag1

    result = convert_to_rosbag1(
        args.source, args.output, progress=lambda n: print(f"\rconverted {n} messages", end="", file=sys.stderr)
    )
    total = sum(result.written.values())
    print(f"\nwrote {args.output}: {total} messages on {len(result.written)} topics", file=sys.stderr)
    for topic, why in result.skipped.items():
        print(f"left out {topic}: {why}", file=sys.stderr)
    return 0 if result.written or not result.skipped else 1
