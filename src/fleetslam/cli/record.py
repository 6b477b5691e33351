"""`fleetslam record -o PATH [TOPICS… | --all] [--duration S]`: record to rosbag2 (MCAP storage)."""

from __future__ import annotations

import argparse
import time
from typing import Any

from fleetslam.cli.common import cli_node
from fleetslam.errors import ConfigError
from fleetslam.middleware import MessageInfo, QoSProfile
from fleetslam.middleware.names import expand_name
from fleetslam.middleware.recording import BagWriter


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("topics", nargs="*", help="topics to record")
    parser.add_argument("-o", "--output", required=True, help="new rosbag2 folder")
    parser.add_argument("-a", "--all", action="store_true", help="record every topic, also those appearing later")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    parser.set_defaults(func=run)


def recording_qos(offered: list[QoSProfile]) -> QoSProfile:
    """The subscription that gets every publisher's messages, as `ros2 bag record` adapts it: transient local
    when all publishers keep their last messages for late joiners (``tf_static``, a map: published once, maybe
    before the recorder started), best effort when any publisher is best effort."""
    keeps_last = bool(offered) and all(q.durability == "transient_local" for q in offered)
    best_effort = any(q.reliability == "best_effort" for q in offered)
    return QoSProfile(
        depth=1000,
        reliability="best_effort" if best_effort else "reliable",
        durability="transient_local" if keeps_last else "volatile",
    )


def record(output: str, topics: list[str], *, all_topics: bool, duration: float) -> int:
    """Record until ``duration`` passes or Ctrl-C; returns the number of messages written."""
    if not topics and not all_topics:
        raise ConfigError("record: give topics to record, or --all")
    wanted = {expand_name(t, namespace="/", node_name="_") for t in topics}
    # The node goes first on the way out: no callback may write into a closed bag.
    with BagWriter(output) as writer, cli_node("record") as node:
        subscribed: set[tuple[str, str]] = set()

        def on_data(data: bytes, info: MessageInfo) -> None:
            writer.write(info.topic, info.type_name, info.received_timestamp_ns, data)

        def follow() -> None:
            for topic, types in node.context.graph.topic_names_and_types().items():
                if not (all_topics or topic in wanted):
                    continue
                for type_name in types:
                    publishers = node.context.graph.publishers_info(topic)
                    if (topic, type_name) not in subscribed and publishers:
                        subscribed.add((topic, type_name))
                        qos = recording_qos([p.qos for p in publishers])
                        node.create_subscription(type_name, topic, on_data, qos, raw=True)

        start = time.monotonic()
        print(f"recording to {output} (Ctrl-C to stop)", flush=True)
        try:
            while not duration or time.monotonic() - start < duration:
                follow()
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
        time.sleep(0.1)
        count = writer.count
    print(f"recorded {count} messages on {len(subscribed)} topics to {output}", flush=True)
    return count


def run(args: argparse.Namespace) -> Any:
    record(args.output, args.topics, all_topics=args.all, duration=args.duration)
    return 0
