"""Recordings for ROS 1 users: a rosbag2/MCAP recording rewritten as a ROS 1 bag (``rosbag info/play`` read it).

Each message is converted from CDR to ROS 1 bytes; each connection carries the ROS 1 type, md5sum and full
message definition. Messages of types ROS 1 does not know are skipped and counted per topic, not fatal.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.rosbag1 import Writer

from fleetslam.errors import DatasetError, FleetslamError
from fleetslam.middleware.recording import read_bag
from fleetslam.ros1 import messages

log = logging.getLogger(__name__)


@dataclass
class BagConversion:
    """What a conversion wrote and what it left out."""

    written: dict[str, int] = field(default_factory=dict)
    """Topic -> messages written."""
    skipped: dict[str, str] = field(default_factory=dict)
    """Topic -> why its messages were left out."""


def convert_to_rosbag1(
    source: str | Path, output: str | Path, *, progress: Callable[[int], None] | None = None
) -> BagConversion:
    """Write the rosbag2 folder ``source`` as the ROS 1 bag ``output`` (a new file); ``progress(count)`` is
    called about once a second."""
    output = Path(output)
    if output.exists():
        raise DatasetError(f"{output}: already exists; choose a new bag file")
    result = BagConversion()
    connections: dict[str, Any] = {}
    last_report = time.monotonic()
    with Writer(output) as writer:
        for message in read_bag(source):
            if message.topic in result.skipped:
                continue
            connection = connections.get(message.topic)
            try:
                if connection is None:
                    info = messages.type_info(message.type_name)
                    connection = connections[message.topic] = writer.add_connection(
                        message.topic, messages.ros2_name(message.type_name), msgdef=info.definition,
                        md5sum=info.md5sum, callerid="/fleetslam_convert",
                    )  # fmt: skip
                data = messages.cdr_to_ros1(message.data, message.type_name)
            except FleetslamError as err:
                result.skipped[message.topic] = str(err)
                log.warning("%s: leaving out %s: %s", source, message.topic, err)
                continue
            writer.write(connection, message.timestamp_ns, data)
            result.written[message.topic] = result.written.get(message.topic, 0) + 1
            if progress is not None and time.monotonic() - last_report > 1.0:
                last_report = time.monotonic()
                progress(sum(result.written.values()))
    return result
