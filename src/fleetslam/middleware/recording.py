"""Recording and replay: rosbag2 folders with MCAP storage (ROS 2 CDR profile), via rosbags.

A recording holds the raw CDR bytes as received, stamped with the receive time (ns), plus each connection's
type, message definition and RIHS01 hash, so that ROS 2 tools, rosbags' AnyReader and Foxglove can read it.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from fleetslam.errors import DatasetError
from fleetslam.msg.typesys import get_typestore, type_hash

ROSBAG2_VERSION: Literal[8, 9] = 9


class BagWriter:
    """Writes messages into a new rosbag2 folder with MCAP storage; thread-safe."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise DatasetError(f"{self.path}: already exists; choose a new output folder")
        self._writer = Writer(self.path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[tuple[str, str], object] = {}
        self._lock = threading.Lock()
        self.count = 0

    def write(self, topic: str, type_name: str, timestamp_ns: int, data: bytes) -> None:
        with self._lock:
            connection = self._connections.get((topic, type_name))
            if connection is None:
                connection = self._writer.add_connection(
                    topic, type_name, typestore=get_typestore(), rihs01=type_hash(type_name)
                )
                self._connections[(topic, type_name)] = connection
            self._writer.write(connection, timestamp_ns, data)  # type: ignore[arg-type]
            self.count += 1

    def close(self) -> None:
        with self._lock:
            self._writer.close()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class BagMessage:
    topic: str
    type_name: str
    timestamp_ns: int
    data: bytes


def read_bag(path: str | Path, topics: set[str] | None = None) -> Iterator[BagMessage]:
    """Messages of a rosbag2 folder in time order (optionally only some topics)."""
    path = Path(path)
    if not (path / "metadata.yaml").is_file():
        raise DatasetError(f"{path}: not a rosbag2 folder (no metadata.yaml)")
    try:
        with Reader(path) as reader:
            connections = [c for c in reader.connections if topics is None or c.topic in topics]
            for connection, timestamp, data in reader.messages(connections=connections):
                yield BagMessage(connection.topic, connection.msgtype, int(timestamp), bytes(data))
    except DatasetError:
        raise
    except Exception as err:  # rosbags' ReaderError and storage errors
        raise DatasetError(f"{path}: cannot read recording: {err}") from err


def bag_topics(path: str | Path) -> dict[str, str]:
    """Topic → type of a recording."""
    path = Path(path)
    try:
        with Reader(path) as reader:
            return {c.topic: c.msgtype for c in reader.connections}
    except Exception as err:
        raise DatasetError(f"{path}: cannot read recording: {err}") from err
