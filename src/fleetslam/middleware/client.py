"""Service clients: a query to every complete queryable of the service, replies matched by sequence number."""

from __future__ import annotations

import itertools
import threading
import time
from typing import TYPE_CHECKING, Any

import zenoh

from fleetslam.errors import MessageError, ServiceError
from fleetslam.middleware.entity import Entity
from fleetslam.middleware.wire import EntityKind, QoSProfile, decode_attachment, encode_attachment, topic_key
from fleetslam.msg import typesys

if TYPE_CHECKING:
    from fleetslam.middleware.node import Node


class Client(Entity):
    """Calls a service: a query to every complete queryable, replies matched by sequence number."""

    def __init__(self, node: Node, type_name: str, name: str, qos: QoSProfile) -> None:
        if not typesys.is_service_type(type_name):
            raise MessageError(f"'{type_name}' is not a service type (pkg/srv/Name)")
        super().__init__(node, EntityKind.CLIENT, name, type_name, qos)
        self.request_type, self.response_type = typesys.service_types(type_name)
        self.key = topic_key(node.context.domain_id, name, type_name)
        self._sequence = itertools.count(1)
        self._lock = threading.Lock()
        self._declare_token()

    def service_is_ready(self) -> bool:
        graph = self.node.context.graph
        return any(info.topic_type == self.type_name for info in graph.services_info(self.name))

    def wait_for_service(self, timeout_s: float = 5.0) -> bool:
        """Wait until a server of this name and type is in the graph (the hash is not compared, as in rmw)."""
        return self.node.context.graph.wait_for(lambda g: self.service_is_ready(), timeout_s)

    def call(self, request: object, timeout: float = 10.0) -> Any:
        """Send a request and wait for its response; raises ServiceError on timeout or a server error.

        Blocks the calling thread. A fresh session may not know the server's queryable yet: when a query finds
        no server at all, the call waits (within ``timeout``) for one to appear in the graph and asks once more.
        Don't call a service of the same node from one of its callbacks: the handler would wait for the executor
        that the caller blocks.
        """
        deadline = time.monotonic() + timeout
        payload = typesys.serialize(request, self.request_type)
        for attempt in range(2):
            found, response, errors = self._query(payload, max(0.05, deadline - time.monotonic()))
            if found:
                return response
            remaining = deadline - time.monotonic()
            if errors or attempt or remaining < 0.1:
                break
            if not self.wait_for_service(remaining):
                break
            time.sleep(0.02)  # the queryable's declaration travels just behind its token
        detail = f": {'; '.join(errors)}" if errors else f" within {timeout} s (is a server running?)"
        raise ServiceError(f"service {self.name} ({self.type_name}) gave no response{detail}")

    def _query(self, payload: bytes, timeout: float) -> tuple[bool, Any, list[str]]:
        with self._lock:
            seq = next(self._sequence)
        replies = self.node.context.session.get(
            self.key,
            payload=payload,
            attachment=encode_attachment(seq, time.time_ns(), self.gid),
            target=zenoh.QueryTarget.ALL_COMPLETE,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout,
        )
        errors = []
        for reply in replies:
            if reply.ok is None:
                errors.append(reply.err.payload.to_bytes().decode(errors="replace") if reply.err else "error")
                continue
            sample = reply.ok
            try:
                # rclcpp matches replies by the sequence number echoed in the attachment
                if sample.attachment is None or decode_attachment(sample.attachment.to_bytes()).sequence_number != seq:
                    continue
                return True, typesys.deserialize(sample.payload.to_bytes(), self.response_type), []
            except MessageError as err:
                errors.append(str(err))
        return False, None, errors

    def _undeclare(self) -> None:
        pass
