"""Publishers: CDR messages on one topic, with the rmw_zenoh attachment (sequence number, timestamp, GID)."""

from __future__ import annotations

import itertools
import logging
import struct
import threading
import time
from typing import TYPE_CHECKING, Any

import zenoh

from fleetslam.errors import MiddlewareError
from fleetslam.middleware.entity import Entity
from fleetslam.middleware.wire import EntityKind, QoSProfile, encode_attachment, topic_key
from fleetslam.msg import typesys
from fleetslam.msg.loan import Loan, fill_loan, loan_message

if TYPE_CHECKING:
    from fleetslam.middleware.node import Node

log = logging.getLogger("fleetslam.middleware.node")

_pack_attachment = struct.Struct("<qqB16s").pack
_time_ns = time.time_ns
_serialize_payload = typesys.serialize_payload
_BUFFERS = (bytes, bytearray, memoryview)


class Publisher(Entity):
    """Publishes messages of one type on one topic; thread-safe."""

    def __init__(self, node: Node, type_name: str, topic: str, qos: QoSProfile) -> None:
        super().__init__(node, EntityKind.PUBLISHER, topic, type_name, qos)
        session = node.context.session
        self.key = topic_key(node.context.domain_id, topic, type_name)
        congestion = (
            zenoh.CongestionControl.BLOCK
            if qos.reliability == "reliable" and qos.history == "keep_all"
            else zenoh.CongestionControl.DROP
        )
        reliability = zenoh.Reliability.RELIABLE if qos.reliability == "reliable" else zenoh.Reliability.BEST_EFFORT
        self._advanced = qos.durability == "transient_local"
        if self._advanced:
            miss = (
                zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5)
                if qos.reliability == "reliable"
                else None
            )
            self._publisher: Any = zenoh.ext.declare_advanced_publisher(
                session,
                self.key,
                congestion_control=congestion,
                reliability=reliability,
                cache=zenoh.ext.CacheConfig(max_samples=max(1, qos.depth)),
                publisher_detection=True,
                sample_miss_detection=miss,
            )
        else:
            self._publisher = session.declare_publisher(
                self.key, congestion_control=congestion, reliability=reliability
            )
        self._sequence = itertools.count(1)
        self._put = self._publisher.put
        self._scratch = bytearray()
        """The serialized message for Zenoh when it ends in a large array, reused (see :meth:`publish`)."""
        self._trailing = typesys.trailing_array(type_name)
        self._scratch_lock = threading.Lock() if self._trailing is not None else None
        self._loans: dict[int, Loan] = {}
        """Loans not published yet, and the last one published (it may be published again), by ``id`` of array."""
        self._loan_lock = threading.Lock()
        self._returned: Loan | None = None
        """The loan published last: the next :meth:`loan` of its size takes its payload."""
        self._declare_token()

    @property
    def topic(self) -> str:
        return self.name

    def publish(self, msg: object, *, source_timestamp_ns: int | None = None) -> None:
        """Serialize (CDR) and publish a message; ``bytes`` are taken as already serialized CDR (with header).
        ``source_timestamp_ns``: the send time in the attachment (default: now).

        The message is serialized straight into the buffer handed to Zenoh (one copy of its arrays, none more). A
        message ending in a large array (an Image's ``data``) is written into this publisher's own buffer, reused
        from one message to the next (Zenoh copies what it is given before ``put`` returns): a fresh megabyte per
        frame pays page faults whenever the allocator has given the last one back to the system
        (:func:`~fleetslam.msg.typesys.serialize_payload`). Another thread publishing meanwhile gets a new buffer.
        """
        if not isinstance(msg, _BUFFERS):  # a message: one check (a union built per call and two checks: 0.1 µs)
            if self._loans and self._publish_loaned(msg, source_timestamp_ns):
                return
            if self._scratch_lock is not None and self._scratch_lock.acquire(blocking=False):
                try:
                    payload = _serialize_payload(msg, self.type_name, self._scratch)
                    self.publish_raw(payload, source_timestamp_ns=source_timestamp_ns)
                finally:
                    self._scratch_lock.release()
            else:
                self.publish_raw(_serialize_payload(msg, self.type_name), source_timestamp_ns=source_timestamp_ns)
        elif isinstance(msg, memoryview):
            self.publish_raw(bytes(msg), source_timestamp_ns=source_timestamp_ns)
        else:
            self.publish_raw(msg, source_timestamp_ns=source_timestamp_ns)

    MAX_LOANS = 8
    """Loans a publisher keeps track of; a message loaned before the last eight is published as any other."""

    def loan(self, template: object, count: int) -> Any:
        """A copy of ``template`` whose trailing byte array (an Image's or a PointCloud2's ``data``) is a writable
        array of ``count`` elements that already lies in the payload this publisher hands to Zenoh: fill it in
        place (capture into it, ``np.copyto``), set the other fields, and :meth:`publish` copies none of its bytes
        before Zenoh's own copy (a 1 MB frame saves one copy, ~40 µs and a megabyte of cache).

        The message may be published any number of times, its fields changed in between; a change that moves the
        array (a longer ``frame_id`` or ``encoding``) or replaces it is published the usual way. Once a loaned
        message is published, its payload is the publisher's again: the next loan of the same size reuses it
        without clearing it (the new array holds the last message's bytes until filled; the old message's array
        is the new one's); copy what must outlive the next loan. A first loan's array is zeroed.

        Raises MessageError for a type that does not end in a byte array (``std_msgs/msg/String``) or a template
        of another type."""
        with self._loan_lock:
            returned, self._returned = self._returned, None
            if returned is not None:
                self._loans.pop(id(returned.array), None)
        loan = loan_message(template, self.type_name, count, returned.payload if returned is not None else None)
        with self._loan_lock:
            while len(self._loans) >= self.MAX_LOANS:
                del self._loans[next(iter(self._loans))]
            self._loans[id(loan.array)] = loan
        return loan.message

    def _publish_loaned(self, msg: object, source_timestamp_ns: int | None) -> bool:
        """Publish a loaned message from its own payload; False for any other message (or a loan it outgrew)."""
        trailing = self._trailing
        array = getattr(msg, trailing.field, None) if trailing is not None else None
        loan = self._loans.get(id(array))
        if loan is None or loan.array is not array or not fill_loan(loan, msg, self.type_name):
            return False
        self.publish_raw(loan.payload, source_timestamp_ns=source_timestamp_ns)
        with self._loan_lock:
            self._returned = loan
        return True

    @property
    def matched_subscriptions(self) -> int:
        """How many subscriptions of this topic and type the graph knows (0 until discovery has seen them)."""
        return sum(1 for i in self.node.context.graph.subscriptions_info(self.topic) if i.topic_type == self.type_name)

    def publish_raw(self, payload: bytes | bytearray, *, source_timestamp_ns: int | None = None) -> None:
        """Publish already serialized CDR bytes (with header); the attachment gets the next sequence number."""
        if self._destroyed:
            raise MiddlewareError(f"publisher of {self.topic} was destroyed")
        seq = next(self._sequence)  # itertools.count is atomic (one C call under the GIL): no lock needed
        stamp = _time_ns() if source_timestamp_ns is None else source_timestamp_ns
        try:
            attachment = _pack_attachment(seq, stamp, 16, self.gid)  # encode_attachment's bytes, in one call
        except struct.error:
            attachment = encode_attachment(seq, stamp, self.gid)  # raises MessageError naming the value
        self._put(payload, attachment=attachment)

    def _undeclare(self) -> None:
        try:
            self._publisher.undeclare()
        except Exception as err:
            log.debug("publisher undeclare: %s", err)
