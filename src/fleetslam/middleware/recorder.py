"""Live recording: a node subscribes to the wanted topics as their publishers appear, with the QoS that gets every
publisher's messages, and writes the CDR bytes as received into a rosbag2 folder (`fleetslam record`)."""

from __future__ import annotations

import time
from collections.abc import Iterable

from fleetslam.middleware.names import expand_name
from fleetslam.middleware.node import MessageInfo, Node
from fleetslam.middleware.recording import BagWriter
from fleetslam.middleware.wire import QoSProfile


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


class Recorder:
    """Records ``topics`` (absolute, or relative to ``/``), or every topic with ``all_topics``, through ``node``
    into ``writer``; :meth:`follow` subscribes to what the graph shows since the last call.

    Destroy the node before closing the writer: no callback may write into a closed bag.
    """

    def __init__(self, node: Node, writer: BagWriter, topics: Iterable[str], *, all_topics: bool = False) -> None:
        self.node = node
        self.writer = writer
        self.all_topics = all_topics
        self.wanted = {expand_name(t, namespace="/", node_name="_") for t in topics}
        self.subscribed: set[tuple[str, str]] = set()
        """(topic, type) pairs recorded so far."""

    def _on_data(self, data: bytes, info: MessageInfo) -> None:
        self.writer.write(info.topic, info.type_name, info.received_timestamp_ns, data)

    def follow(self) -> None:
        """Subscribe to every wanted (topic, type) that has publishers now and no subscription yet."""
        graph = self.node.context.graph
        for topic, types in graph.topic_names_and_types().items():
            if not (self.all_topics or topic in self.wanted):
                continue
            for type_name in types:
                publishers = graph.publishers_info(topic)
                if (topic, type_name) not in self.subscribed and publishers:
                    self.subscribed.add((topic, type_name))
                    qos = recording_qos([p.qos for p in publishers])
                    self.node.create_subscription(type_name, topic, self._on_data, qos, raw=True)

    def run(self, duration_s: float = 0.0, *, poll_s: float = 0.2) -> None:
        """Follow the graph every ``poll_s`` until ``duration_s`` passes (0: until interrupted)."""
        start = time.monotonic()
        while not duration_s or time.monotonic() - start < duration_s:
            self.follow()
            time.sleep(poll_s)
