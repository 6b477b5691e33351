"""What publishers, subscriptions, services and clients share: entity id, liveliness token, GID."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import zenoh

from fleetslam.middleware.wire import EntityKind, LivelinessToken, QoSProfile
from fleetslam.msg import typesys

if TYPE_CHECKING:
    from fleetslam.middleware.node import Node

log = logging.getLogger("fleetslam.middleware.node")


class Entity:
    """Common part of publishers, subscriptions, services and clients: id, liveliness token, GID."""

    def __init__(self, node: Node, kind: EntityKind, name: str, type_name: str, qos: QoSProfile) -> None:
        self.node = node
        self.name = name
        self.type_name = type_name
        self.qos = qos
        self.entity_id = node.context.next_entity_id()
        self.token_info = LivelinessToken(
            domain_id=node.context.domain_id,
            zid=node.context.zid,
            nid=node.node_id,
            eid=self.entity_id,
            kind=kind,
            namespace=node.namespace,
            node_name=node.name,
            topic=name,
            type_name=type_name,
            type_hash=typesys.type_hash(type_name),
            qos=qos,
        )
        self.gid = self.token_info.gid
        self._token: zenoh.LivelinessToken | None = None
        self._destroyed = False

    def _declare_token(self) -> None:
        self._token = self.node.context.session.liveliness().declare_token(self.token_info.key())

    def destroy(self) -> None:
        if self._destroyed:
            return
        self._destroyed = True
        self._undeclare()
        if self._token is not None:
            try:
                self._token.undeclare()
            except Exception as err:
                log.debug("token undeclare: %s", err)

    def _undeclare(self) -> None:
        raise NotImplementedError
