"""The fleet ↔ ROS 1 bridge: topics chosen by rules, converted between CDR and ROS 1 bytes, in both directions.

A rule is a pattern (``fnmatch``, ``*`` for all) or an exact name remapped with ``from:=to``. Every second the
bridge looks at both graphs (the fleet's liveliness tokens, the master's published topics) and bridges each
new topic a rule selects, unless its only publisher is the bridge itself (no echo loops). A fleet topic whose
publisher is transient-local becomes a latched ROS 1 topic. Fleet subscriptions report statistics like any
other; the ROS 1 side counts messages and conversion errors per topic (:meth:`Ros1Bridge.topic_counts`).
"""

from __future__ import annotations

import fnmatch
import logging
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from fleetslam.errors import FleetslamError, MiddlewareError
from fleetslam.middleware import Node, QoSProfile
from fleetslam.middleware.node import Publisher
from fleetslam.ros1 import messages
from fleetslam.ros1.node import Ros1Node, Ros1Publisher

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TopicRule:
    """Selects topics of one side: ``pattern`` (fnmatch) or an exact name with its name on the other side."""

    pattern: str
    target: str | None = None

    @classmethod
    def parse(cls, text: str) -> TopicRule:
        source, sep, target = text.partition(":=")
        if not source.startswith("/") and source != "*":
            raise MiddlewareError(f"topic rule {text!r}: names are absolute (start with '/') or '*' for all")
        if sep and (not target.startswith("/") or any(c in source for c in "*?[")):
            raise MiddlewareError(f"topic rule {text!r}: a remap maps one absolute name to another (/a:=/b)")
        return cls(source, target if sep else None)

    def match(self, topic: str) -> str | None:
        """The name on the other side, or None when this rule does not select ``topic``."""
        if self.target is not None:
            return self.target if topic == self.pattern else None
        return topic if fnmatch.fnmatchcase(topic, self.pattern) else None


def select(rules: Sequence[TopicRule], topic: str) -> str | None:
    for rule in rules:
        target = rule.match(topic)
        if target is not None:
            return target
    return None


class Ros1Bridge:
    """Bridges ``node``'s fleet and ``ros1``'s master by ``to_ros1`` and ``from_ros1`` rules."""

    def __init__(
        self,
        node: Node,
        ros1: Ros1Node,
        *,
        to_ros1: Sequence[TopicRule] = (),
        from_ros1: Sequence[TopicRule] = (),
        scan_period_s: float = 1.0,
    ) -> None:
        self.node = node
        self.ros1 = ros1
        self.to_ros1 = list(to_ros1)
        self.from_ros1 = list(from_ros1)
        self.scan_period_s = scan_period_s
        self.bridged_to_ros1: dict[str, str] = {}
        """Fleet topic -> ROS 1 topic."""
        self.bridged_from_ros1: dict[str, str] = {}
        """ROS 1 topic -> fleet topic."""
        self.errors: dict[str, int] = {}
        self._refused: set[tuple[str, str]] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ros1-bridge-scan", daemon=True)

    def start(self) -> Ros1Bridge:
        self.scan()
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def __enter__(self) -> Ros1Bridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self) -> None:
        while not self._stop.wait(self.scan_period_s):
            try:
                self.scan()
            except FleetslamError as err:  # the master may be restarting; the next scan tries again
                log.warning("ROS 1 bridge scan failed: %s", err)

    def scan(self) -> None:
        """Bridge every topic a rule selects that is not bridged yet."""
        if self.to_ros1:
            self._scan_fleet()
        if self.from_ros1:
            self._scan_ros1()

    def _refuse_once(self, topic: str, type_name: str, err: Exception) -> None:
        if (topic, type_name) not in self._refused:
            self._refused.add((topic, type_name))
            log.warning("not bridging %s: %s", topic, err)

    # -- fleet -> ROS 1 -------------------------------------------------------------------------------------
    def _scan_fleet(self) -> None:
        graph = self.node.context.graph
        for topic, types in graph.topic_names_and_types().items():
            target = select(self.to_ros1, topic)
            if target is None or topic in self.bridged_to_ros1 or target in self.bridged_from_ros1.values():
                continue
            publishers = [p for p in graph.publishers_info(topic) if p.node_fq_name != self.node.fq_name]
            if not publishers or len(types) != 1:
                continue
            type_name = types[0]
            try:
                msg_type = messages.type_info(type_name)
            except FleetslamError as err:
                self._refuse_once(topic, type_name, err)
                continue
            latch = any(p.qos.durability == "transient_local" for p in publishers)
            pub = self.ros1.advertise(target, msg_type, latch=latch)
            qos = QoSProfile(durability="transient_local", depth=1) if latch else QoSProfile(depth=2)
            self.node.create_subscription(type_name, topic, self._to_ros1_callback(pub, type_name), qos, raw=True)
            self.bridged_to_ros1[topic] = target
            log.info("bridging fleet %s -> ROS 1 %s [%s]%s", topic, target, msg_type.ros1_name, " latched" * latch)

    def _to_ros1_callback(self, pub: Ros1Publisher, type_name: str) -> Any:
        def forward(cdr: bytes) -> None:
            if not pub.connections and not pub.latch:
                return  # no ROS 1 subscriber: spare the conversion
            try:
                pub.publish(messages.cdr_to_ros1(cdr, type_name))
            except FleetslamError as err:
                self.errors[pub.topic] = self.errors.get(pub.topic, 0) + 1
                log.warning("fleet %s: message dropped: %s", pub.topic, err)

        return forward

    # -- ROS 1 -> fleet -------------------------------------------------------------------------------------
    def _scan_ros1(self) -> None:
        published = self.ros1.published_topics()
        publishers = self.ros1.publishers_of()
        for topic, ros1_type in published.items():
            target = select(self.from_ros1, topic)
            if target is None or topic in self.bridged_from_ros1 or target in self.bridged_to_ros1:
                continue
            if not [p for p in publishers.get(topic, []) if p != self.ros1.caller_id]:
                continue
            try:
                type_name = messages.ros2_name(ros1_type)
                msg_type = messages.type_info(type_name)
                fleet_pub = self.node.create_publisher(type_name, target)
            except FleetslamError as err:
                self._refuse_once(topic, ros1_type, err)
                continue
            self.ros1.subscribe(topic, msg_type, self._from_ros1_callback(fleet_pub, topic, type_name))
            self.bridged_from_ros1[topic] = target
            log.info("bridging ROS 1 %s -> fleet %s [%s]", topic, target, type_name)

    def _from_ros1_callback(self, pub: Publisher, topic: str, type_name: str) -> Any:
        def forward(raw: bytes, publisher: str) -> None:
            try:
                pub.publish_raw(messages.ros1_to_cdr(raw, type_name))
            except FleetslamError as err:
                self.errors[topic] = self.errors.get(topic, 0) + 1
                log.warning("ROS 1 %s from %s: message dropped: %s", topic, publisher, err)

        return forward

    def topic_counts(self) -> dict[str, dict[str, int]]:
        """Per bridged ROS 1 topic: messages received or published there, and conversion errors."""
        counts: dict[str, dict[str, int]] = {}
        for topic, sub in self.ros1.subscriptions.items():
            counts[topic] = {"received": sub.received, "errors": self.errors.get(topic, 0)}
        for topic, pub in self.ros1.publishers.items():
            counts[topic] = {"published": pub.published, "errors": self.errors.get(topic, 0)}
        return counts
