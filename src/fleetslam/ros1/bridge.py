"""The fleet ↔ ROS 1 bridge: topics and services chosen by rules, converted between CDR and ROS 1 bytes, in both
directions.

A rule is a pattern (``fnmatch``, ``*`` for all) or an exact name remapped with ``from:=to``. Every second the
bridge looks at both graphs (the fleet's liveliness tokens, the master's published topics and services) and
bridges each new topic or service a rule selects, unless its only publisher or provider is the bridge itself
(no echo loops). A fleet topic whose publisher is transient-local becomes a latched ROS 1 topic. Fleet
subscriptions report statistics like any other; the ROS 1 side counts messages and conversion errors per topic
(:meth:`Ros1Bridge.topic_counts`) and calls and failures per service (:meth:`Ros1Bridge.service_counts`).

Services are bridged where their type exists on both sides (:data:`messages.ROS1_SERVICES` and fleetslam_msgs);
a service of another type is skipped with one log line naming it. A bridged call waits for the far side at most
``service_timeout_s``; a call that fails or times out there is a failed call here (ROS 1: an error answer with
the reason; fleet: the middleware's error reply), never a hung bridge. Fleet services provided for ROS 1
services are served by a second node, ``<name>_services``, so a slow ROS 1 service cannot hold up the topics
that the bridge's own node forwards.
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
from fleetslam.middleware.node import Client, Publisher
from fleetslam.msg import typesys
from fleetslam.ros1 import messages
from fleetslam.ros1.messages import Ros1ServiceType
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
    """Bridges ``node``'s fleet and ``ros1``'s master: topics by ``to_ros1`` and ``from_ros1`` rules, services by
    ``services_to_ros1`` and ``services_from_ros1`` rules."""

    def __init__(
        self,
        node: Node,
        ros1: Ros1Node,
        *,
        to_ros1: Sequence[TopicRule] = (),
        from_ros1: Sequence[TopicRule] = (),
        services_to_ros1: Sequence[TopicRule] = (),
        services_from_ros1: Sequence[TopicRule] = (),
        service_timeout_s: float = 10.0,
        scan_period_s: float = 1.0,
    ) -> None:
        self.node = node
        self.ros1 = ros1
        self.to_ros1 = list(to_ros1)
        self.from_ros1 = list(from_ros1)
        self.services_to_ros1 = list(services_to_ros1)
        self.services_from_ros1 = list(services_from_ros1)
        self.service_timeout_s = service_timeout_s
        self.scan_period_s = scan_period_s
        self.bridged_to_ros1: dict[str, str] = {}
        """Fleet topic -> ROS 1 topic."""
        self.bridged_from_ros1: dict[str, str] = {}
        """ROS 1 topic -> fleet topic."""
        self.services_bridged_to_ros1: dict[str, str] = {}
        """Fleet service -> ROS 1 service."""
        self.services_bridged_from_ros1: dict[str, str] = {}
        """ROS 1 service -> fleet service."""
        self.fleet_service_calls: dict[str, dict[str, int]] = {}
        """Per fleet service provided for a ROS 1 service: calls answered and failed."""
        self.service_node: Node | None = None
        """The node that provides the fleet services standing for ROS 1 services (made on first need)."""
        self.errors: dict[str, int] = {}
        self._refused: set[tuple[str, str]] = set()
        self._skipped_services: set[str] = set()
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
        if self.service_node is not None:
            self.service_node.destroy()

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
        if self.services_to_ros1:
            self._scan_fleet_services()
        if self.services_from_ros1:
            self._scan_ros1_services()

    def _own_fleet_nodes(self) -> set[str]:
        own = {self.node.fq_name}
        if self.service_node is not None:
            own.add(self.service_node.fq_name)
        return own

    def _refuse_once(self, topic: str, type_name: str, err: Exception) -> None:
        if (topic, type_name) not in self._refused:
            self._refused.add((topic, type_name))
            log.warning("not bridging %s [%s]: %s", topic, type_name, err)

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

    def service_counts(self) -> dict[str, dict[str, int]]:
        """Per bridged service, named on the side that is called: calls answered and failed."""
        counts = {name: {"calls": srv.calls, "errors": srv.errors} for name, srv in self.ros1.services.items()}
        counts.update({name: dict(c) for name, c in self.fleet_service_calls.items()})
        return counts

    # -- services: fleet -> ROS 1 ---------------------------------------------------------------------------
    def _service_type(self, name: str, type_name: str) -> Ros1ServiceType | None:
        """The service type both sides know, or None (logged once) when one side lacks it."""
        try:
            srv_type = messages.service_info(type_name)
            typesys.service_types(srv_type.name)
        except FleetslamError as err:
            self._refuse_once(name, type_name, err)
            return None
        return srv_type

    def _scan_fleet_services(self) -> None:
        graph = self.node.context.graph
        own = self._own_fleet_nodes()
        for name, types in graph.service_names_and_types().items():
            target = select(self.services_to_ros1, name)
            if target is None or name in self.services_bridged_to_ros1:
                continue
            if target in self.services_bridged_from_ros1 or target in self.ros1.services:
                continue  # that ROS 1 name is taken by a ROS 1 service bridged the other way
            servers = [s for s in graph.services_info(name) if s.node_fq_name not in own]
            if not servers or len(types) != 1:
                continue
            srv_type = self._service_type(name, types[0])
            if srv_type is None:
                continue
            client = self.node.create_client(srv_type.name, name)
            try:
                self.ros1.advertise_service(target, srv_type, self._to_fleet_call(client, srv_type))
            except FleetslamError:
                client.destroy()  # the master may be restarting; the next scan tries again
                raise
            self.services_bridged_to_ros1[name] = target
            log.info("bridging fleet service %s -> ROS 1 %s [%s]", name, target, srv_type.ros1_name)

    def _to_fleet_call(self, client: Client, srv_type: Ros1ServiceType) -> Any:
        def call(raw: bytes, caller: str) -> bytes:
            request = messages.ros1_to_message(raw, srv_type.request_name)
            response = client.call(request, timeout=self.service_timeout_s)
            return messages.message_to_ros1(response, srv_type.response_name)

        return call

    # -- services: ROS 1 -> fleet ---------------------------------------------------------------------------
    def _scan_ros1_services(self) -> None:
        for name, providers in self.ros1.services_of().items():
            target = select(self.services_from_ros1, name)
            if target is None or name in self.services_bridged_from_ros1:
                continue
            if target in self.services_bridged_to_ros1 or not [p for p in providers if p != self.ros1.caller_id]:
                continue
            if name in self._skipped_services:
                continue  # its type was refused once; the probe would only say so again
            try:
                header = self.ros1.probe_service(name)
            except FleetslamError as err:
                log.debug("ROS 1 service %s: %s (next scan tries again)", name, err)
                continue
            ros1_type = header.get("type", "?")
            srv_type = self._service_type(name, ros1_type)
            if srv_type is not None and header.get("md5sum") != srv_type.md5sum:
                mismatch = MiddlewareError(f"its md5 {header.get('md5sum')} is not {ros1_type}'s {srv_type.md5sum}")
                self._refuse_once(name, ros1_type, mismatch)
                srv_type = None
            if srv_type is None:
                self._skipped_services.add(name)
                continue
            if self.service_node is None:
                self.service_node = Node(
                    f"{self.node.name}_services", context=self.node.context, namespace=self.node.namespace
                )
            self.service_node.create_service(srv_type.name, target, self._to_ros1_call(name, srv_type, target))
            self.services_bridged_from_ros1[name] = target
            log.info("bridging ROS 1 service %s -> fleet %s [%s]", name, target, srv_type.name)

    def _to_ros1_call(self, name: str, srv_type: Ros1ServiceType, target: str) -> Any:
        counts = self.fleet_service_calls.setdefault(target, {"calls": 0, "errors": 0})

        def call(request: Any) -> Any:
            try:
                raw = messages.message_to_ros1(request, srv_type.request_name)
                answer = self.ros1.call_service(name, srv_type, raw, timeout_s=self.service_timeout_s)
                response = messages.ros1_to_message(answer, srv_type.response_name)
            except FleetslamError:
                counts["errors"] += 1
                raise  # the fleet service replies with the error, naming the ROS 1 service and why
            counts["calls"] += 1
            return response

        return call
