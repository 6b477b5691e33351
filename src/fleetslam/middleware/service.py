"""Service servers: a complete queryable whose handler runs on the node's executor."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zenoh

from fleetslam.errors import MessageError
from fleetslam.middleware.entity import Entity
from fleetslam.middleware.lifetime import declare_with_callback
from fleetslam.middleware.wire import EntityKind, QoSProfile, decode_attachment, encode_attachment, topic_key
from fleetslam.msg import typesys

if TYPE_CHECKING:
    from fleetslam.middleware.node import Node

log = logging.getLogger("fleetslam.middleware.node")


class Service(Entity):
    """Answers requests: a complete queryable whose handler runs on the node's executor."""

    def __init__(self, node: Node, type_name: str, name: str, handler: Callable[[Any], Any], qos: QoSProfile) -> None:
        if not typesys.is_service_type(type_name):
            raise MessageError(f"'{type_name}' is not a service type (pkg/srv/Name)")
        super().__init__(node, EntityKind.SERVICE, name, type_name, qos)
        self.request_type, self.response_type = typesys.service_types(type_name)
        self.handler = handler
        self.key = topic_key(node.context.domain_id, name, type_name)
        session = node.context.session
        self._queryable = declare_with_callback(
            lambda: session.declare_queryable(self.key, self._on_query, complete=True)
        )
        self._declare_token()

    def _on_query(self, query: zenoh.Query) -> None:
        errors = self.node.error_log
        if query.attachment is None:
            errors.warning(f"{self.name}:noatt", "service %s: rejected a request without attachment", self.name)
            query.reply_err(b"request without attachment")
            query.drop()  # finishes the query now; the client would otherwise wait for its timeout
            return
        try:
            attachment = decode_attachment(query.attachment.to_bytes())
            if attachment.sequence_number < 0 or attachment.source_timestamp_ns < 0:
                raise MessageError("negative sequence number or timestamp")
            payload = query.payload.to_bytes() if query.payload is not None else b""
            request = typesys.deserialize(payload, self.request_type)
        except MessageError as err:
            errors.warning(f"{self.name}:bad", "service %s: rejected a request: %s", self.name, err)
            query.reply_err(str(err).encode())
            query.drop()
            return

        def answer() -> None:
            try:
                response = self.handler(request)
                data = typesys.serialize(response, self.response_type)
            except Exception as err:
                errors.warning(
                    f"{self.name}:cb", "service %s: handler raised %s: %s", self.name, type(err).__name__, err
                )
                query.reply_err(f"{type(err).__name__}: {err}".encode())
                query.drop()
                return
            reply_attachment = encode_attachment(attachment.sequence_number, time.time_ns(), attachment.gid)
            query.reply(self.key, data, attachment=reply_attachment)
            query.drop()

        self.node.call_soon(answer)

    def _undeclare(self) -> None:
        try:
            self._queryable.undeclare()
        except Exception as err:
            log.debug("queryable undeclare: %s", err)
