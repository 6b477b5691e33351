"""Nodes: publishers, subscriptions, services, clients, timers and typed parameters over Zenoh, rmw_zenoh style.

Threading:

- every node owns one executor thread (named ``executor:<fq node name>``). All of a node's callbacks
  (subscriptions, service handlers, timers, :meth:`Node.call_soon`) run on it, one at a time, in arrival order,
  so a node's state needs no locks. Callbacks of different nodes run concurrently.
- samples are received, checked and counted in the statistics on Zenoh's threads, and queued per subscription
  (KEEP_LAST depth: the oldest is dropped when the executor falls behind; KEEP_ALL: unbounded). They are
  deserialized on the executor just before their callback, so samples dropped by KEEP_LAST cost no decoding.
  A subscription created with ``inline=True`` skips the queue: its callback runs on Zenoh's thread (see
  :class:`Subscription`).
- zero-copy: a received payload is copied once out of Zenoh; the message's numeric arrays are read-only NumPy
  views on that copy (they keep it alive). Publishing serializes into the buffer handed to Zenoh.
- service requests are decoded on Zenoh's threads; the handler runs on the executor and the reply is sent from
  there.
- each timer has a small thread that only posts ticks; a tick is skipped while the previous one still waits.
- publishing and :meth:`Client.call` are thread-safe and may happen from any thread; ``call`` blocks its caller,
  so never call a service of the same node from one of its own callbacks.

Robustness: a malformed payload, a sample without attachment, an unknown type, a payload over the size limit or
an exception inside a callback is dropped, counted (``error_msgs`` in /statistics) and logged at a bounded rate
(the first 3 per cause, then one line per 10 s with the number suppressed); the node keeps running.
"""

from __future__ import annotations

import collections
import inspect
import itertools
import logging
import queue
import struct
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import zenoh

from fleetslam.config import ConfigModel, load_config
from fleetslam.errors import MessageError, MiddlewareError, ServiceError
from fleetslam.middleware import typesys
from fleetslam.middleware.context import MAX_MESSAGE_BYTES, Context
from fleetslam.middleware.lifetime import declare_with_callback, join_at_exit
from fleetslam.middleware.names import (
    RosArgs,
    agent_of,
    normalize_namespace,
    parse_ros_args,
    resolve_name,
    validate_node_name,
)
from fleetslam.middleware.statistics import SubscriptionStatistics
from fleetslam.middleware.wire import (
    ATTACHMENT_SIZE,
    EntityKind,
    LivelinessToken,
    QoSProfile,
    decode_attachment,
    encode_attachment,
    parse_topic_key,
    topic_key,
    topic_key_any_type,
)

log = logging.getLogger(__name__)

DEFAULT_MAX_PAYLOAD_BYTES = MAX_MESSAGE_BYTES
"""Larger samples are dropped (and cannot arrive through a default session anyway)."""
STATISTICS_TOPIC = "/statistics"
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"


class MessageInfo(NamedTuple):
    """Metadata of a received message (a named tuple: cheap to make for every sample)."""

    source_timestamp_ns: int
    """When the publisher sent it (attachment), ns since the epoch."""
    received_timestamp_ns: int
    """When this process received it, ns since the epoch."""
    sequence_number: int
    """The publisher's sequence number, from 1."""
    publisher_gid: bytes
    """16-byte GID of the publisher (the graph's ``EndpointInfo.gid``)."""
    size: int
    """Payload size in bytes (CDR with header)."""
    topic: str
    type_name: str


_ATTACHMENT = struct.Struct("<qqB")
_ATTACHMENT_GID = struct.Struct("<qqB16s")
_COPY_ON_EXECUTOR_BYTES = 1 << 16
"""Payloads from this size on are copied out of Zenoh on the executor, not on Zenoh's thread (see _receive)."""


class _RateLimitedLogger:
    """Logs the first few occurrences of each cause, then at most one line per interval with a count."""

    def __init__(self, first: int = 3, interval_s: float = 10.0) -> None:
        self._first = first
        self._interval = interval_s
        self._state: dict[str, list[float]] = {}
        self._lock = threading.Lock()

    def warning(self, cause: str, message: str, *args: object) -> None:
        now = time.monotonic()
        with self._lock:
            count, last, suppressed = self._state.get(cause, [0, 0.0, 0])
            count += 1
            emit = count <= self._first or now - last >= self._interval
            self._state[cause] = [count, now if emit else last, 0 if emit else suppressed + 1]
        if emit:
            more = f" ({int(suppressed)} more suppressed)" if suppressed else ""
            log.warning(message + more, *args)


class _Executor:
    """One thread running a node's callbacks in order."""

    def __init__(self, name: str, on_error: Callable[[str, BaseException], None]) -> None:
        self._queue: queue.SimpleQueue[Callable[[], None] | None] = queue.SimpleQueue()
        self._on_error = on_error
        self._thread = threading.Thread(target=self._run, name=f"executor:{name}", daemon=True)
        self._thread.start()

    def post(self, work: Callable[[], None]) -> None:
        self._queue.put(work)

    def _run(self) -> None:
        while True:
            work = self._queue.get()
            if work is None:
                return
            try:
                work()
            except Exception as err:
                self._on_error(getattr(work, "__qualname__", "callback"), err)

    def stop(self, timeout_s: float = 2.0) -> None:
        self._queue.put(None)
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        if self._thread.is_alive():  # a long callback: the exit must still wait for it (see lifetime)
            join_at_exit(self._thread)


class _Entity:
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


class Publisher(_Entity):
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
        self._lock = threading.Lock()
        self._declare_token()

    @property
    def topic(self) -> str:
        return self.name

    def publish(self, msg: object) -> None:
        """Serialize (CDR) and publish a message; ``bytes`` are taken as already serialized CDR (with header).

        The message is serialized straight into the buffer handed to Zenoh (one copy of its arrays, none more).
        """
        if isinstance(msg, bytes | bytearray):
            self.publish_raw(msg)
        elif isinstance(msg, memoryview):
            self.publish_raw(bytes(msg))
        else:
            self.publish_raw(typesys.serialize_buffer(msg, self.type_name))

    @property
    def matched_subscriptions(self) -> int:
        """How many subscriptions of this topic and type the graph knows (0 until discovery has seen them)."""
        return sum(1 for i in self.node.context.graph.subscriptions_info(self.topic) if i.topic_type == self.type_name)

    def publish_raw(self, payload: bytes | bytearray, *, source_timestamp_ns: int | None = None) -> None:
        """Publish already serialized CDR bytes (with header); the attachment gets the next sequence number."""
        if self._destroyed:
            raise MiddlewareError(f"publisher of {self.topic} was destroyed")
        with self._lock:
            seq = next(self._sequence)
        stamp = time.time_ns() if source_timestamp_ns is None else source_timestamp_ns
        try:
            attachment = _ATTACHMENT_GID.pack(seq, stamp, 16, self.gid)  # encode_attachment's bytes, in one call
        except struct.error:
            attachment = encode_attachment(seq, stamp, self.gid)  # raises MessageError naming the value
        self._publisher.put(payload, attachment=attachment)

    def _undeclare(self) -> None:
        try:
            self._publisher.undeclare()
        except Exception as err:
            log.debug("publisher undeclare: %s", err)


def _accepts_info(callback: Callable[..., Any]) -> bool:
    """Whether a callback wants ``(msg, info)``: a second positional parameter without a default, or ``*args``.

    Parameters with defaults do not count, so closures binding loop variables (``lambda m, k=key: ...``) get
    only the message.
    """
    try:
        params = [
            p
            for p in inspect.signature(callback).parameters.values()
            if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL)
        ]
    except (TypeError, ValueError):
        return False
    required = [p for p in params if p.kind is not p.VAR_POSITIONAL and p.default is p.empty]
    return len(required) >= 2 or any(p.kind is p.VAR_POSITIONAL for p in params)


class Subscription(_Entity):
    """Receives messages of a topic; the callback runs on the node's executor.

    ``type_name=None`` subscribes to any type (the type is read from each sample's key); with ``raw=True`` the
    callback gets the CDR bytes instead of a message (for recorders and bridges).

    With ``inline=True`` the callback runs directly on Zenoh's receive thread, with no queue and no hand-off to
    the executor (the lowest latency and cost per message). Such a callback runs concurrently with the node's
    executor callbacks, so what it shares with them needs a lock, and it must return quickly: Zenoh delivers
    the next sample only after it. There is no local queue (no KEEP_LAST drops here, ``queue_overflows`` stays
    0); a slow callback holds back reception instead.

    A message's numeric arrays are read-only views on the received payload (see :func:`typesys.deserialize`):
    keeping the message, or any of its arrays, keeps the payload alive; copy an array to modify it.
    """

    def __init__(
        self,
        node: Node,
        type_name: str | None,
        topic: str,
        callback: Callable[..., Any],
        qos: QoSProfile,
        *,
        raw: bool = False,
        max_payload_bytes: int = DEFAULT_MAX_PAYLOAD_BYTES,
        inline: bool = False,
    ) -> None:
        self.any_type = type_name is None
        if type_name is not None:
            super().__init__(node, EntityKind.SUBSCRIBER, topic, type_name, qos)
        else:
            self._init_untyped(node, topic, qos)
        self.callback = callback
        self.raw = raw
        self.max_payload_bytes = max_payload_bytes
        self.inline = inline
        self._with_info = _accepts_info(callback)
        self._pending: collections.deque[tuple[Any, MessageInfo]] = collections.deque(
            maxlen=None if qos.history == "keep_all" else max(1, qos.depth)
        )
        # One executor post per queued sample: the executor's queue stays bounded by the KEEP_LAST depth.
        self._pending_lock = threading.Lock()
        self.queue_overflows = 0
        """Samples dropped from the local queue because the executor fell behind (KEEP_LAST)."""
        self.statistics = SubscriptionStatistics(time.time_ns())
        self.publisher_types: dict[bytes, str] = {}
        session = node.context.session
        domain = node.context.domain_id
        self.key = topic_key_any_type(domain, topic) if self.any_type else topic_key(domain, topic, self.type_name)
        if qos.durability == "transient_local":
            history = zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=max(1, qos.depth))
            recovery = (
                zenoh.ext.RecoveryConfig(heartbeat=True, periodic_queries=None)
                if qos.reliability == "reliable"
                else None
            )
            self._subscriber: Any = declare_with_callback(
                lambda: zenoh.ext.declare_advanced_subscriber(
                    session, self.key, self._on_sample, history=history, recovery=recovery, subscriber_detection=True
                )
            )
        else:
            self._subscriber = declare_with_callback(lambda: session.declare_subscriber(self.key, self._on_sample))
        if not self.any_type:
            self._declare_token()

    def _init_untyped(self, node: Node, topic: str, qos: QoSProfile) -> None:
        # A subscription of unknown type announces no token (its type chunk would be a lie).
        self.node = node
        self.name = topic
        self.type_name = ""
        self.qos = qos
        self.entity_id = node.context.next_entity_id()
        self.gid = b"\x00" * 16
        self._token = None
        self._destroyed = False

    @property
    def topic(self) -> str:
        return self.name

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Runs on a Zenoh thread: whatever arrives, nothing may escape from here.
        if self._destroyed:
            return
        try:
            self._receive(sample)
        except Exception as err:
            self.statistics.on_error(None)
            self.node._error_log.warning(
                f"{self.topic}:internal", "%s: dropped a sample: %s: %s", self.topic, type(err).__name__, err
            )

    def _receive(self, sample: zenoh.Sample) -> None:
        # Hot path (every sample, on a Zenoh thread): checks, statistics and queueing only. Deserialization waits
        # for the executor, so samples that KEEP_LAST drops before their turn cost no decoding.
        received = time.time_ns()
        errors = self.node._error_log
        attachment = sample.attachment
        zpayload = sample.payload
        size = len(zpayload)
        if attachment is None:
            self.statistics.on_error(None, size)
            errors.warning(f"{self.topic}:noatt", "%s: dropped a sample without attachment", self.topic)
            return
        raw_attachment = attachment.to_bytes()
        if len(raw_attachment) == ATTACHMENT_SIZE and raw_attachment[16] == 16:
            seq, stamp, _ = _ATTACHMENT.unpack_from(raw_attachment)
            gid = raw_attachment[17:]
        else:
            try:
                decoded = decode_attachment(raw_attachment)  # also the labelled form of Jazzy ≤ 0.2.3
            except MessageError as err:
                self.statistics.on_error(None, size)
                errors.warning(f"{self.topic}:att", "%s: dropped a sample: %s", self.topic, err)
                return
            seq, stamp, gid = decoded.sequence_number, decoded.source_timestamp_ns, decoded.gid
        if size > self.max_payload_bytes:
            self.statistics.on_error(gid, size)
            errors.warning(
                f"{self.topic}:size",
                "%s: dropped a %d-byte sample over the %d-byte limit",
                self.topic,
                size,
                self.max_payload_bytes,
            )
            return
        type_name = self.type_name
        if self.any_type:
            try:
                type_name = parse_topic_key(str(sample.key_expr))[2]
            except MessageError as err:
                self.statistics.on_error(gid, size)
                errors.warning(f"{self.topic}:key", "%s: dropped a sample: %s", self.topic, err)
                return
            types = self.publisher_types  # as bounded as the statistics: GIDs are forgeable
            if gid not in types and len(types) >= self.statistics.max_publishers:
                del types[next(iter(types))]
            types[gid] = type_name
        self.statistics.on_sample(gid, seq, stamp, received, size)
        info = MessageInfo(stamp, received, seq, gid, size, self.topic, type_name)
        if self.inline:
            self._deliver(zpayload.to_bytes(), info)  # the one copy out of Zenoh; the message's arrays view it
            return
        # A large payload leaves Zenoh on the executor, where its copy is also freed: a buffer made on one thread
        # and freed on another made glibc return and fault in its pages for every sample (1 MB: 2x the CPU of
        # the receiving end). Zenoh reassembled it into a buffer of its own, so holding it pins nothing else.
        payload: bytes | zenoh.ZBytes = zpayload if size >= _COPY_ON_EXECUTOR_BYTES else zpayload.to_bytes()
        with self._pending_lock:
            full = len(self._pending) == self._pending.maxlen
            self._pending.append((payload, info))  # drops the oldest when full; its post serves this one
            if full:
                self.queue_overflows += 1
        if not full:
            self.node._executor.post(self._dispatch)

    def _dispatch(self) -> None:
        with self._pending_lock:
            if not self._pending:
                return
            payload, info = self._pending.popleft()
        self._deliver(payload, info)

    def _deliver(self, payload: bytes | zenoh.ZBytes, info: MessageInfo) -> None:
        if not isinstance(payload, bytes):
            payload = payload.to_bytes()
        message: Any = payload
        if not self.raw:
            try:
                message = typesys.deserialize(payload, info.type_name)
            except MessageError as err:
                self.statistics.on_malformed(info.publisher_gid)
                self.node._error_log.warning(f"{self.topic}:cdr", "%s: dropped a malformed sample: %s", self.topic, err)
                return
        try:
            if self._with_info:
                self.callback(message, info)
            else:
                self.callback(message)
        except Exception as err:
            self.statistics.on_error(info.publisher_gid)
            self.node._error_log.warning(
                f"{self.topic}:cb", "%s: callback %s raised %s: %s", self.topic, self.callback, type(err).__name__, err
            )

    def _undeclare(self) -> None:
        try:
            self._subscriber.undeclare()
        except Exception as err:
            log.debug("subscriber undeclare: %s", err)


class Service(_Entity):
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
        errors = self.node._error_log
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

        self.node._executor.post(answer)

    def _undeclare(self) -> None:
        try:
            self._queryable.undeclare()
        except Exception as err:
            log.debug("queryable undeclare: %s", err)


class Client(_Entity):
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


class Timer:
    """Calls a callback on the node's executor every ``period_s`` (skips ticks while one is still queued)."""

    def __init__(self, node: Node, period_s: float, callback: Callable[[], Any]) -> None:
        if period_s <= 0:
            raise MiddlewareError(f"timer period must be positive, got {period_s}")
        self.period_s = period_s
        self.callback = callback
        self._node = node
        self._stop = threading.Event()
        self._queued = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"timer:{node.name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_tick = time.monotonic() + self.period_s
        while not self._stop.wait(max(0.0, next_tick - time.monotonic())):
            next_tick += self.period_s
            if time.monotonic() - next_tick > self.period_s:  # fell far behind: don't burst
                next_tick = time.monotonic() + self.period_s
            if not self._queued.is_set():
                self._queued.set()
                self._node._executor.post(self._fire)

    def _fire(self) -> None:
        self._queued.clear()
        if not self._stop.is_set():
            self.callback()

    def cancel(self) -> None:
        self._stop.set()


class Node:
    """A named participant of the graph, a context manager.

    Args:
        name: node base name.
        context: the process's context.
        namespace: overrides the context's namespace (``FLEETSLAM_AGENT``).
        remaps: name remapping rules ``{from: to}``.
        parameters: the node's parameter model (a ConfigModel subclass); validated into ``node.parameters``.
        parameter_file: YAML file of parameter values (the whole file, or its ``<node name>`` key if present).
        parameter_overrides: ``key=value`` overrides.
        ros_args: a command line with ``--ros-args`` sections (remaps, ``__ns``, ``__node``, ``-p``).
        statistics_period_s: window of the /statistics reports (0 disables them for this node).
        use_sim_time: :meth:`now_ns` follows ``/clock`` (rosgraph_msgs/msg/Clock) instead of the wall clock.
    """

    def __init__(
        self,
        name: str,
        *,
        context: Context,
        namespace: str | None = None,
        remaps: Mapping[str, str] | None = None,
        parameters: type[ConfigModel] | None = None,
        parameter_file: str | Path | None = None,
        parameter_overrides: Sequence[str] = (),
        ros_args: Sequence[str] | RosArgs | None = None,
        statistics_period_s: float = 1.0,
        use_sim_time: bool = False,
    ) -> None:
        parsed = ros_args if isinstance(ros_args, RosArgs) else parse_ros_args(ros_args or [])
        self.context = context
        self.name = validate_node_name(parsed.node_name or name)
        self.namespace = normalize_namespace(parsed.namespace or namespace or context.namespace)
        self.remaps = {**dict(remaps or {}), **parsed.remaps}
        self.fq_name = f"{self.namespace.rstrip('/')}/{self.name}"
        self.agent = agent_of(f"{self.fq_name}/x")
        self._error_log = _RateLimitedLogger()
        self.callback_errors = 0
        self.parameters: Any = self._load_parameters(
            parameters, parameter_file or (parsed.params_files[-1] if parsed.params_files else None),
            [*parameter_overrides, *(f"{k}={v}" for k, v in parsed.parameters.items())],
        )  # fmt: skip
        self.node_id = context.next_entity_id()
        self._token_info = LivelinessToken(
            domain_id=context.domain_id,
            zid=context.zid,
            nid=self.node_id,
            eid=self.node_id,
            kind=EntityKind.NODE,
            namespace=self.namespace,
            node_name=self.name,
        )
        self._executor = _Executor(self.fq_name, self._on_executor_error)
        self._entities: list[_Entity] = []
        self._timers: list[Timer] = []
        self._subscriptions: list[Subscription] = []
        self._statistics_publisher: Publisher | None = None
        self._on_destroy: list[Callable[[], None]] = []
        self._destroyed = False
        self._token = context.session.liveliness().declare_token(self._token_info.key())
        context._register(self)
        if statistics_period_s > 0 and context.statistics_enabled:
            self._timers.append(Timer(self, statistics_period_s, self._publish_statistics))
        self.use_sim_time = use_sim_time
        self._sim_time_ns = 0
        if use_sim_time:
            self._clock = Subscription(self, CLOCK_TYPE, "/clock", self._on_clock, QoSProfile(depth=1))
            self._entities.append(self._clock)

    def _load_parameters(self, model: type[ConfigModel] | None, path: str | Path | None, overrides: list[str]) -> Any:
        if model is None:
            if overrides or path:
                log.warning("%s: parameters given but the node declares none; ignored", self.fq_name)
            return None
        section = None
        if path is not None:
            from fleetslam.config import read_yaml

            data = read_yaml(path)
            section = self.name if self.name in data and isinstance(data[self.name], dict) else None
        return load_config(model, path, overrides=overrides, section=section)

    def _on_executor_error(self, what: str, err: BaseException) -> None:
        self.callback_errors += 1
        self._error_log.warning(f"exec:{what}", "%s: %s raised %s: %s", self.fq_name, what, type(err).__name__, err)

    # -- names -------------------------------------------------------------------------------------------------
    def resolve(self, name: str) -> str:
        """Fully qualified name of a topic/service name as this node sees it (namespace, ~, remaps)."""
        return resolve_name(name, namespace=self.namespace, node_name=self.name, remaps=self.remaps)

    # -- entities ----------------------------------------------------------------------------------------------
    def _add(self, entity: Any) -> Any:
        if self._destroyed:
            entity.destroy()
            raise MiddlewareError(f"node {self.fq_name} was destroyed")
        self._entities.append(entity)
        return entity

    def create_publisher(self, type_name: str, topic: str, qos: QoSProfile | None = None) -> Publisher:
        typesys.get_type(type_name)
        publisher: Publisher = self._add(Publisher(self, type_name, self.resolve(topic), qos or QoSProfile()))
        return publisher

    def create_subscription(
        self,
        type_name: str | None,
        topic: str,
        callback: Callable[..., Any],
        qos: QoSProfile | None = None,
        *,
        raw: bool = False,
        max_payload_bytes: int = DEFAULT_MAX_PAYLOAD_BYTES,
        inline: bool = False,
    ) -> Subscription:
        """Subscribe; ``callback(msg)`` or ``callback(msg, info: MessageInfo)`` runs on the executor.

        ``inline=True`` runs it on Zenoh's receive thread instead (no queue, no hand-off; see :class:`Subscription`
        for what that asks of the callback).
        """
        if type_name is not None:
            typesys.get_type(type_name)
        subscription: Subscription = self._add(
            Subscription(
                self,
                type_name,
                self.resolve(topic),
                callback,
                qos or QoSProfile(),
                raw=raw,
                max_payload_bytes=max_payload_bytes,
                inline=inline,
            )
        )
        self._subscriptions.append(subscription)
        return subscription

    def create_service(
        self, type_name: str, name: str, handler: Callable[[Any], Any], qos: QoSProfile | None = None
    ) -> Service:
        """Serve requests; ``handler(request) -> response`` runs on the executor."""
        service: Service = self._add(Service(self, type_name, self.resolve(name), handler, qos or QoSProfile()))
        return service

    def create_client(self, type_name: str, name: str, qos: QoSProfile | None = None) -> Client:
        client: Client = self._add(Client(self, type_name, self.resolve(name), qos or QoSProfile()))
        return client

    def create_timer(self, period_s: float, callback: Callable[[], Any]) -> Timer:
        timer = Timer(self, period_s, callback)
        self._timers.append(timer)
        return timer

    def call_soon(self, callback: Callable[[], Any]) -> None:
        """Run a callback on this node's executor (from any thread)."""
        self._executor.post(callback)

    # -- time --------------------------------------------------------------------------------------------------
    def now_ns(self) -> int:
        """Wall-clock ns since the epoch; with ``use_sim_time`` the last /clock value (0 before the first)."""
        return self._sim_time_ns if self.use_sim_time else time.time_ns()

    def _on_clock(self, msg: Any) -> None:
        self._sim_time_ns = typesys.ns_from_stamp(msg.clock)

    # -- statistics --------------------------------------------------------------------------------------------
    def _publish_statistics(self) -> None:
        subscriptions = [s for s in self._subscriptions if s.topic != STATISTICS_TOPIC and not s._destroyed]
        if not subscriptions:
            return
        if self._statistics_publisher is None:
            self._statistics_publisher = self.create_publisher(
                "fleetslam_msgs/msg/TopicStatistics", STATISTICS_TOPIC, QoSProfile(depth=100)
            )
        stats_type = typesys.get_type("fleetslam_msgs/msg/TopicStatistics")
        now = time.time_ns()
        graph = self.context.graph
        for subscription in subscriptions:
            for report in subscription.statistics.close_window(now):
                publisher = graph.entity_by_gid(report.publisher_gid)
                node_pub = publisher.node_fq_name if publisher is not None else ""
                msg = stats_type(
                    topic=subscription.topic,
                    type=subscription.publisher_types.get(report.publisher_gid, subscription.type_name),
                    node_pub=node_pub,
                    node_sub=self.fq_name,
                    agent_pub=agent_of(f"{node_pub}/x") if node_pub else agent_of(subscription.topic),
                    agent_sub=self.agent,
                    publisher_gid=_gid_array(report.publisher_gid),
                    window_start=typesys.stamp_from_ns(report.window_start_ns),
                    window_stop=typesys.stamp_from_ns(report.window_stop_ns),
                    delivered_msgs=report.delivered,
                    dropped_msgs=report.dropped,
                    error_msgs=report.errors,
                    traffic=report.traffic_bytes,
                    period_mean=typesys.duration_from_ns(int(report.period_mean_ns)),
                    period_stddev=typesys.duration_from_ns(int(report.period_stddev_ns)),
                    period_max=typesys.duration_from_ns(int(report.period_max_ns)),
                    stamp_age_mean=typesys.duration_from_ns(int(report.age_mean_ns)),
                    stamp_age_stddev=typesys.duration_from_ns(int(report.age_stddev_ns)),
                    stamp_age_max=typesys.duration_from_ns(int(report.age_max_ns)),
                )
                self._statistics_publisher.publish(msg)

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def spin(self, timeout_s: float | None = None) -> None:
        """Block until the context closes, ``timeout_s`` passes, or Ctrl-C (callbacks run on the executor)."""
        self.context.spin(timeout_s)

    def add_on_destroy(self, callback: Callable[[], None]) -> None:
        """Call ``callback`` when the node is destroyed, before its entities go (an adapter's worker threads stop
        there, while they can still publish)."""
        self._on_destroy.append(callback)

    def destroy(self) -> None:
        """Undeclare every entity and the node's token; stop its timers and executor."""
        if self._destroyed:
            return
        self._destroyed = True
        for callback in self._on_destroy:
            try:
                callback()
            except Exception as err:
                log.warning("%s: on-destroy callback failed: %s", self.fq_name, err)
        for timer in self._timers:
            timer.cancel()
        for entity in self._entities:
            entity.destroy()
        try:
            self._token.undeclare()
        except Exception as err:
            log.debug("node token undeclare: %s", err)
        self._executor.stop()
        self.context._unregister(self)

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.destroy()


def _gid_array(gid: bytes) -> Any:
    import numpy as np

    return np.frombuffer(gid.ljust(16, b"\x00")[:16], dtype=np.uint8).copy()
