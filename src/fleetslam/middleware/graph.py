"""Graph discovery from rmw_zenoh liveliness tokens: nodes, publishers, subscribers, services, clients.

At start the graph asks for every token of the domain (``liveliness.get('@ros2_lv/<dom>/**')``) and then
follows PUT (appeared) and DELETE (gone) events with a liveliness subscriber, as rmw_zenoh does. The state is
a set of :class:`~fleetslam.middleware.wire.LivelinessToken`; every query is answered from it. Callbacks run on
Zenoh's threads; the state is guarded by a lock.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from fleetslam.errors import MessageError
from fleetslam.middleware.lifetime import declare_with_callback
from fleetslam.middleware.wire import LIVELINESS_PREFIX, EntityKind, LivelinessToken, QoSProfile

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EndpointInfo:
    """A publisher or subscriber of a topic (or server/client of a service), as `ros2 topic info -v` shows."""

    node_name: str
    node_namespace: str
    topic_type: str
    type_hash: str
    gid: bytes
    qos: QoSProfile
    kind: EntityKind
    zid: str = ""
    """Zenoh id of the session (process) the entity lives in."""

    @property
    def node_fq_name(self) -> str:
        return f"{self.node_namespace.rstrip('/')}/{self.node_name}"


@dataclass(frozen=True)
class NodeInfo:
    """A node of the graph: (zid, nid) identify it, several processes may use the same name."""

    namespace: str
    name: str
    zid: str
    nid: int

    @property
    def fq_name(self) -> str:
        return f"{self.namespace.rstrip('/')}/{self.name}"


class Graph:
    """The live graph of one domain."""

    def __init__(self, session: zenoh.Session, domain_id: int) -> None:
        self._domain_id = domain_id
        self._tokens: dict[str, LivelinessToken] = {}
        self._by_gid: dict[bytes, LivelinessToken] = {}
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._listeners: list[Callable[[str, LivelinessToken], None]] = []
        key = f"{LIVELINESS_PREFIX}/{domain_id}/**"
        self._subscriber = declare_with_callback(
            lambda: session.liveliness().declare_subscriber(key, self._on_sample, history=True)
        )
        for reply in session.liveliness().get(key, timeout=2.0):
            if reply.ok is not None:
                self._on_sample(reply.ok)

    def close(self) -> None:
        try:
            self._subscriber.undeclare()
        except Exception as err:  # already undeclared with its session
            log.debug("graph subscriber undeclare: %s", err)

    def add_listener(self, listener: Callable[[str, LivelinessToken], None]) -> None:
        """Call ``listener(event, token)`` (event 'put' or 'delete') on every change, on a Zenoh thread.

        Keep it short, or post the work to a node with :meth:`Node.call_soon`.
        """
        self._listeners.append(listener)

    def remove_listener(self, listener: Callable[[str, LivelinessToken], None]) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            token = LivelinessToken.parse(key)
        except MessageError as err:
            log.debug("ignoring liveliness token %s: %s", key, err)
            return
        event = "delete" if sample.kind == zenoh.SampleKind.DELETE else "put"
        with self._changed:
            # The initial query and the subscriber's history may both report a token: notify changes only.
            changed = (key not in self._tokens) if event == "put" else (key in self._tokens)
            if event == "put":
                self._tokens[key] = token
                if token.kind is not EntityKind.NODE:
                    self._by_gid[token.gid] = token
            else:
                self._tokens.pop(key, None)
                self._by_gid.pop(token.gid, None)
            self._changed.notify_all()
        if not changed:
            return
        for listener in list(self._listeners):
            try:
                listener(event, token)
            except Exception:
                log.exception("graph listener failed")

    # -- queries -----------------------------------------------------------------------------------------------
    def tokens(self) -> list[LivelinessToken]:
        """Every live token of the domain."""
        with self._lock:
            return list(self._tokens.values())

    def entity_by_gid(self, gid: bytes) -> LivelinessToken | None:
        """The publisher/subscriber/service/client whose GID this is (GIDs are hashes of token keys)."""
        with self._lock:
            return self._by_gid.get(gid)

    def nodes(self) -> list[NodeInfo]:
        """Every node, sorted by name then zid."""
        found = [NodeInfo(t.namespace, t.node_name, t.zid, t.nid) for t in self.tokens() if t.kind is EntityKind.NODE]
        return sorted(found, key=lambda n: (n.fq_name, n.zid, n.nid))

    def node_names(self) -> list[tuple[str, str]]:
        """(namespace, name) of every node, sorted."""
        return sorted({(t.namespace, t.node_name) for t in self.tokens() if t.kind is EntityKind.NODE})

    def node_fq_names(self) -> list[str]:
        """``/namespace/name`` of every node, sorted."""
        return [f"{ns.rstrip('/')}/{name}" for ns, name in self.node_names()]

    def _names_and_types(self, kinds: tuple[EntityKind, ...]) -> dict[str, list[str]]:
        found: dict[str, set[str]] = {}
        for token in self.tokens():
            if token.kind in kinds:
                found.setdefault(token.topic, set()).add(token.type_name)
        return {name: sorted(types) for name, types in sorted(found.items())}

    def topic_names_and_types(self) -> dict[str, list[str]]:
        """Every topic with a publisher or subscriber, with its types."""
        return self._names_and_types((EntityKind.PUBLISHER, EntityKind.SUBSCRIBER))

    def service_names_and_types(self) -> dict[str, list[str]]:
        """Every service with a server or client, with its types."""
        return self._names_and_types((EntityKind.SERVICE, EntityKind.CLIENT))

    def _endpoints(self, name: str, kind: EntityKind) -> list[EndpointInfo]:
        return [
            EndpointInfo(t.node_name, t.namespace, t.type_name, t.type_hash, t.gid, t.qos, t.kind, t.zid)
            for t in sorted(self.tokens(), key=lambda t: (t.zid, t.nid, t.eid))
            if t.kind is kind and t.topic == name
        ]

    def publishers_info(self, topic: str) -> list[EndpointInfo]:
        """Publishers of a fully qualified topic (as ``ros2 topic info -v``)."""
        return self._endpoints(topic, EntityKind.PUBLISHER)

    def subscriptions_info(self, topic: str) -> list[EndpointInfo]:
        """Subscriptions of a fully qualified topic."""
        return self._endpoints(topic, EntityKind.SUBSCRIBER)

    def services_info(self, service: str) -> list[EndpointInfo]:
        """Servers of a service."""
        return self._endpoints(service, EntityKind.SERVICE)

    def clients_info(self, service: str) -> list[EndpointInfo]:
        """Clients of a service."""
        return self._endpoints(service, EntityKind.CLIENT)

    def node_entities(self, namespace: str, node_name: str) -> list[LivelinessToken]:
        """Every entity token of the node(s) of this name."""
        namespace = namespace or "/"
        return [
            t
            for t in self.tokens()
            if t.kind is not EntityKind.NODE and t.namespace == namespace and t.node_name == node_name
        ]

    def wait_for(self, predicate: Callable[[Graph], bool], timeout_s: float) -> bool:
        """Wait until ``predicate(graph)`` holds (re-checked on every change); False on timeout."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while True:
                self._lock.release()
                try:
                    if predicate(self):
                        return True
                finally:
                    self._lock.acquire()
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._changed.wait(min(remaining, 0.1))
