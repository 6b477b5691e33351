"""Replay: a recording's messages published again with their original relative timing (`fleetslam play`)."""

from __future__ import annotations

import time
from pathlib import Path

from fleetslam.middleware.node import Node
from fleetslam.middleware.recording import bag_topics, read_bag


def play(
    node: Node,
    path: str | Path,
    *,
    rate: float = 1.0,
    loop: bool = False,
    topics: list[str] | None = None,
    settle_s: tuple[float, float] = (0.5, 0.3),
) -> int:
    """Publish the recording's messages (all, or those of ``topics``) through ``node`` with their relative timing
    divided by ``rate``, once or in a loop; returns the count. ``settle_s``: how long discovery is given after the
    publishers are declared, and the last messages before returning."""
    if rate <= 0:
        raise ValueError(f"rate must be positive, got {rate}")
    types = bag_topics(path)
    selected = set(topics) if topics else None
    sent = 0
    publishers = {
        (topic, type_name): node.create_publisher(type_name, topic)
        for topic, type_name in types.items()
        if selected is None or topic in selected
    }
    time.sleep(settle_s[0])
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
    time.sleep(settle_s[1])
    return sent
