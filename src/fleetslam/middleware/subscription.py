"""Subscriptions: samples checked and counted on a receive thread, decoded and handed to the callback on the node's
executor (or inline, on Zenoh's thread); see :class:`Subscription`."""

from __future__ import annotations

import collections
import inspect
import logging
import struct
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

import zenoh

from fleetslam.errors import MessageError
from fleetslam.middleware.context import MAX_MESSAGE_BYTES
from fleetslam.middleware.entity import Entity
from fleetslam.middleware.lifetime import declare_with_callback, note_callback_thread
from fleetslam.middleware.statistics import SubscriptionStatistics
from fleetslam.middleware.wire import (
    EntityKind,
    QoSProfile,
    decode_attachment,
    parse_topic_key,
    topic_key,
    topic_key_any_type,
)
from fleetslam.msg import typesys

if TYPE_CHECKING:
    from fleetslam.middleware.node import Node

log = logging.getLogger("fleetslam.middleware.node")

DEFAULT_MAX_PAYLOAD_BYTES = MAX_MESSAGE_BYTES
"""Larger samples are dropped (and cannot arrive through a default session anyway)."""


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


_unpack_attachment = struct.Struct("<qqB16s").unpack
"""The 33-byte attachment (sequence number, source timestamp, GID length 16, GID) in one call."""
_new_info = tuple.__new__
"""Makes a MessageInfo without the named tuple's Python-level ``__new__`` (a third of its cost)."""
_time_ns = time.time_ns
_deserialize = typesys.deserialize
RECEIVE_RING_CAPACITY = 256
"""Samples Zenoh keeps for a KEEP_LAST subscription's receive thread (the oldest dropped when it falls behind, never
blocking Zenoh's thread); Zenoh's own channel size, the most a subscription held before it reached Python before."""
DRAIN_BATCH = RECEIVE_RING_CAPACITY
"""Samples a KEEP_LAST subscription delivers per turn of the executor; then the node's other work (timers, other
topics, services) takes its turn before the drain goes on."""
PARK_S = 0.005
"""How long the receive thread leaves the ring to an executor that takes nothing from it (a long callback, other
work of the node) before it takes the ring back and goes on counting and queueing on its own."""
LARGE_SAMPLE_BYTES = 1 << 16
"""Payloads from this size on are copied out of Zenoh where they are decoded, not on Zenoh's thread (see _receive),
and a KEEP_LAST subscription's receive thread delivers (or queues) each of them alone, as it arrives, never taking
the samples behind it from the ring first (see _receive_loop): the copy out of Zenoh then reads a payload still in
the cache, where the flood path saves a sample's fixed costs, which only a small one feels."""
QUICK_CALLBACK_S = 0.001
"""A KEEP_LAST subscription's receive thread delivers samples itself (a lone one, or a burst), when the executor is
idle, while the callback takes less than this per sample (see :meth:`Subscription._drain`): meanwhile nothing
counts the samples that arrive, so a slower callback's samples go to the executor's thread."""
_perf_counter = time.perf_counter


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


class Subscription(Entity):
    """Receives messages of a topic; the callback runs on the node's executor, one callback of the node at a time.

    A volatile KEEP_LAST subscription takes its samples from a Zenoh ring channel (:data:`RECEIVE_RING_CAPACITY`):
    Zenoh's threads never wait for Python. A receive thread of its own waits for a sample. While the node's
    executor is idle and this subscription's callback is quick (under :data:`QUICK_CALLBACK_S` per sample the
    last time it ran), the receive thread delivers the sample itself, and under a flood of small samples goes on
    taking them from the ring as the executor would (:meth:`Executor.run_here`: no thread woken for them); a large
    sample (:data:`LARGE_SAMPLE_BYTES`) is always delivered or queued alone, as it arrives. Otherwise it checks,
    counts and queues a lone sample for the executor; under a flood it hands the ring to the executor, which then
    takes the samples itself, checks, counts, decodes them and runs the callback, at most :data:`DRAIN_BATCH` per
    turn (one thread doing all the Python work of a sample, no hand-off per sample), until it finds the ring empty
    and the receive thread waits again. While the executor is busy (a long callback, other work) the receive thread
    checks, counts and queues the samples itself (KEEP_LAST ``depth``), so the callback gets the newest. While a
    callback runs on the receive thread, the samples that arrive wait in the ring and are counted when it returns;
    one that took longer than :data:`QUICK_CALLBACK_S` sends the next samples to the executor's thread. When
    neither keeps up with the ring, Zenoh drops the oldest samples before they are counted: /statistics sees them
    as sequence gaps (``dropped``), not as ``queue_overflows``.
    KEEP_ALL and transient-local subscriptions get each sample from Zenoh's callback thread (a FIFO channel that
    holds back reception when full) and hand it to the executor one by one.

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
        self._post = node.executor_post
        self._run_here = node.executor_run_here
        self._quick = False
        """The last drain took less than QUICK_CALLBACK_S per sample: the receive thread may run the next itself
        (unknown before the first, which therefore runs on the executor's thread)."""
        self._dispatch_bound = self._dispatch
        """Posted once per queued sample (one bound method for all of them, not one made per sample)."""
        self._pending: collections.deque[tuple[Any, MessageInfo]] = collections.deque(
            maxlen=None if qos.history == "keep_all" else max(1, qos.depth)
        )
        # One executor post per queued sample: the executor's queue stays bounded by the KEEP_LAST depth.
        self._pending_lock = threading.Lock()
        self._drain_bound = self._drain
        self._posted = False
        """A drain of the queue is posted to the executor and has not started yet (batched hand-off only)."""
        self._batched = False
        self._ring_lock = threading.Lock()
        """Held by the executor while it takes samples from the ring, and by either thread to pass the ring on."""
        self._executor_pulls = False
        """The executor takes the samples from the ring (the receive thread is parked), batched subscriptions."""
        self._handback = threading.Event()
        """Set by the executor when it found the ring empty: the receive thread waits in ``recv`` again."""
        self._pulled = 0
        """Samples the executor took from the ring."""
        self._turns = 0
        """Drains and pulls the executor ran (the parked receive thread's sign of its progress)."""
        self._try_recv: Callable[[], zenoh.Sample | None] | None = None
        self._receiver: threading.Thread | None = None
        """The receive thread of a batched subscription (it ends when the subscriber is undeclared)."""
        self.queue_overflows = 0
        """Samples dropped from the local queue because the executor fell behind (KEEP_LAST)."""
        self.statistics = SubscriptionStatistics(time.time_ns())
        self._on_stats = self.statistics.on_sample
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
        elif inline or qos.history == "keep_all":
            self._subscriber = declare_with_callback(lambda: session.declare_subscriber(self.key, self._on_sample))
        else:
            self._batched = True
            self._subscriber = session.declare_subscriber(self.key, zenoh.handlers.RingChannel(RECEIVE_RING_CAPACITY))
            self._receiver = threading.Thread(
                target=self._receive_loop, args=(self._subscriber.handler,), name=f"receive:{self.key}"
            )
            note_callback_thread(self._receiver)  # like Zenoh's callback threads: it ends when the session closes
            self._receiver.start()
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

    def _receive_loop(self, handler: zenoh.handlers.Handler[zenoh.Sample]) -> None:
        # The receive thread of a batched subscription. ``recv`` waits without the GIL (and gives it up even when a
        # sample is waiting; ``try_recv`` does not). A lone sample is checked, counted and queued here and a drain
        # posted to the executor. When more are waiting (a flood), this thread hands the executor the ring: the
        # executor delivers what is queued, then takes the samples itself, checks, counts, decodes them and runs the
        # callback, one thread doing all the Python work, while this one sleeps (``_park``) until the executor
        # finds the ring empty. An executor that makes no progress for PARK_S (a long callback, other work) gets
        # the ring taken back: until it runs a drain again, this thread takes what is waiting itself (without
        # giving up the GIL), so KEEP_LAST keeps the newest and the statistics count the samples as they come.
        recv, try_recv, take = handler.recv, handler.try_recv, self._take
        self._try_recv = try_recv
        ring_lock, handback, pending, post, drain, run_here = (
            self._ring_lock, self._handback, self._pending, self._post, self._drain_bound, self._run_here
        )  # fmt: skip
        stalled_at = -1
        """The executor's turns when it last stalled with the ring (it gets the ring again once it moves on)."""
        try:
            while not self._destroyed:
                # A large sample is delivered at once, alone, while its payload is fresh in the cache: taking the
                # samples waiting behind it first (the flood path below) leaves each payload to be copied out cold
                # (1 MB images, publisher flooding: 0.79 -> 0.89 of raw Zenoh's throughput, measured interleaved).
                sample = None if take(recv()) >= LARGE_SAMPLE_BYTES else try_recv()
                if sample is not None:
                    take(sample)
                    if self._turns != stalled_at:
                        with ring_lock:  # a drain may start at once: it must find the ring its own
                            handback.clear()
                            self._executor_pulls = True
                        if not self._posted and self._quick and run_here(drain) and not self._executor_pulls:
                            continue  # the executor was idle: this thread delivered the burst and emptied the ring
                        if not self._posted:
                            self._posted = True
                            post(drain)
                        if self._park():
                            stalled_at = self._turns
                        continue
                    for _ in range(RECEIVE_RING_CAPACITY):
                        sample = try_recv()
                        if sample is None:
                            break
                        take(sample)
                if pending and not self._posted and not (self._quick and run_here(drain)):
                    self._posted = True
                    post(drain)
        except zenoh.ZError:
            pass  # undeclared, or its session closed: the ring is gone
        except Exception as err:  # nothing may end a node's reception silently
            log.warning("%s: receive thread stopped: %s: %s", self.topic, type(err).__name__, err)

    def _park(self) -> bool:
        """Sleep while the executor takes the samples: until it hands the ring back (False), or makes no progress
        for PARK_S (a long callback, other work of the node), when this thread takes the ring back (True)."""
        handback, ring_lock = self._handback, self._ring_lock
        while not self._destroyed:
            seen = self._turns
            if handback.wait(PARK_S):
                return False
            with ring_lock:
                if not self._executor_pulls:
                    return False
                if self._turns == seen:
                    self._executor_pulls = False
                    return True
        return False

    def _take(self, sample: zenoh.Sample) -> int:
        """Check, count and queue a sample (batched subscriptions: posting is the caller's); its payload's size, 0
        for a sample dropped. The size is the sample's own: the queue may already be drained by the executor."""
        if self._destroyed:
            return 0
        try:
            checked = self._check(sample)
            if checked is None:
                return 0
            self._queue(*checked)
            return checked[1].size
        except Exception as err:  # whatever arrives, nothing may escape from here
            self._internal_error(err)
            return 0

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Zenoh's callback (KEEP_ALL, transient local, inline): whatever arrives, nothing may escape from here.
        if self._destroyed:
            return
        try:
            due = self._receive(sample)
        except Exception as err:
            self._internal_error(err)
            return
        if not due:
            return
        if self._batched:
            if not self._posted:  # one drain serves all that is queued before it starts
                self._posted = True
                self._post(self._drain_bound)
        else:
            self._post(self._dispatch_bound)

    def _internal_error(self, err: Exception) -> None:
        self.statistics.on_error(None)
        self.node.error_log.warning(
            f"{self.topic}:internal", "%s: dropped a sample: %s: %s", self.topic, type(err).__name__, err
        )

    def _receive(self, sample: zenoh.Sample) -> bool:
        # Every sample the receive thread or Zenoh's thread takes: checked, counted and queued (or, inline,
        # delivered); True when it queued the sample and, unless KEEP_LAST dropped one for it, a hand-off is due.
        # Deserialization waits for the executor, so samples that KEEP_LAST drops before their turn cost no decoding.
        checked = self._check(sample)
        if checked is None:
            return False
        zpayload, info = checked
        if self.inline:
            self._deliver(zpayload.to_bytes(), info)  # the one copy out of Zenoh; the message's arrays view it
            return False
        return self._queue(zpayload, info)

    def _queue(self, zpayload: zenoh.ZBytes, info: MessageInfo) -> bool:
        """Queue a checked sample for delivery; True unless KEEP_LAST dropped one for it outside a batched
        subscription (a hand-off is then due)."""
        # A large payload leaves Zenoh where it is decoded (the executor, or this thread delivering it itself), where
        # its copy is also freed: a buffer made on one thread and freed on another made glibc return and fault in
        # its pages for every sample (1 MB: 2x the CPU of the receiving end). Zenoh reassembled it into a buffer of
        # its own, so holding it pins nothing else.
        payload: bytes | zenoh.ZBytes = zpayload if info.size >= LARGE_SAMPLE_BYTES else zpayload.to_bytes()
        pending = self._pending
        with self._pending_lock:
            full = len(pending) == pending.maxlen
            pending.append((payload, info))  # drops the oldest when full; its post serves this one
            if full:
                self.queue_overflows += 1
        return self._batched or not full

    def _check(self, sample: zenoh.Sample, count: bool = True) -> tuple[zenoh.ZBytes, MessageInfo] | None:
        # Hot path (every sample, whichever thread takes it from Zenoh): the attachment, the checks, the statistics
        # (unless the caller counts a batch itself) and the MessageInfo; None for a sample dropped (counted and
        # logged). Every line here costs a 64-byte message's throughput (see benchmarks/middleware_throughput.py's
        # table of layers).
        received = _time_ns()
        attachment = sample.attachment
        zpayload = sample.payload
        size = len(zpayload)
        if attachment is None:
            self._drop(None, size, "noatt", "%s: dropped a sample without attachment", self.topic)
            return None
        raw_attachment = attachment.to_bytes()
        try:
            seq, stamp, gid_length, gid = _unpack_attachment(raw_attachment)  # the 33-byte form in one call
        except struct.error:
            gid_length = 0
        if gid_length != 16:
            try:
                decoded = decode_attachment(raw_attachment)  # also the labelled form of Jazzy ≤ 0.2.3
            except MessageError as err:
                self._drop(None, size, "att", "%s: dropped a sample: %s", self.topic, err)
                return None
            seq, stamp, gid = decoded.sequence_number, decoded.source_timestamp_ns, decoded.gid
        if size > self.max_payload_bytes:
            self._drop(
                gid,
                size,
                "size",
                "%s: dropped a %d-byte sample over the %d-byte limit",
                self.topic,
                size,
                self.max_payload_bytes,
            )
            return None
        type_name = self.type_name
        if self.any_type:
            try:
                type_name = parse_topic_key(str(sample.key_expr))[2]
            except MessageError as err:
                self._drop(gid, size, "key", "%s: dropped a sample: %s", self.topic, err)
                return None
            types = self.publisher_types  # as bounded as the statistics: GIDs are forgeable
            if gid not in types and len(types) >= self.statistics.max_publishers:
                del types[next(iter(types))]
            types[gid] = type_name
        if count:
            self._on_stats(gid, seq, stamp, received, size)
        return zpayload, _new_info(MessageInfo, (stamp, received, seq, gid, size, self.name, type_name))

    def _drop(self, gid: bytes | None, size: int, cause: str, message: str, *args: object) -> None:
        """Count a sample dropped on arrival as an error of its publisher (if known) and log it, rate-limited."""
        self.statistics.on_error(gid, size)
        self.node.error_log.warning(f"{self.topic}:{cause}", message, *args)

    def _drain(self) -> None:
        # On the executor (or, while the executor is idle, on the receive thread: run_here), timed:
        # a callback slower than QUICK_CALLBACK_S per sample is left to the executor's thread from then on.
        started = _perf_counter()
        taken = self._drain_batch()
        if taken:
            self._quick = _perf_counter() - started < taken * QUICK_CALLBACK_S

    def _drain_batch(self) -> int:
        # Delivers what is queued, then, while the ring is the executor's, takes the samples from the ring itself;
        # at most DRAIN_BATCH per turn, so the node's other callbacks (timers, services, other topics) still take
        # their turns under a flood. Returns how many samples it took.
        self._posted = False  # cleared before looking at the queue: a sample queued after this posts again
        self._turns += 1
        pending, lock, deliver = self._pending, self._pending_lock, self._deliver
        budget = DRAIN_BATCH
        while budget > 0:
            with lock:
                item = pending.popleft() if pending else None
            if item is not None:
                deliver(*item)
                budget -= 1
                continue
            if not self._executor_pulls:
                return DRAIN_BATCH - budget
            taken = self._pull(budget)
            if not taken:
                return DRAIN_BATCH - budget
            budget -= taken
        if not self._posted and (pending or self._executor_pulls):
            self._posted = True
            self._post(self._drain_bound)
        return DRAIN_BATCH

    def _pull(self, budget: int) -> int:
        """On the executor: take up to ``budget`` samples from the ring, check, count and deliver them (KEEP_LAST:
        the newest ``depth`` of them); returns how many it took. Taking none hands the ring back to the receive
        thread."""
        checked: list[tuple[zenoh.ZBytes, MessageInfo]] = []
        taken = 0
        with self._ring_lock:
            if not self._executor_pulls:
                return 0
            try_recv, check, keep = self._try_recv, self._check, checked.append
            try:
                while taken < budget and not self._destroyed and try_recv is not None:
                    sample = try_recv()  # holds the GIL (recv would give it up even with a sample waiting)
                    if sample is None:
                        break
                    taken += 1
                    try:
                        item = check(sample, False)
                    except Exception as err:  # whatever arrives, nothing may escape from here
                        self._internal_error(err)
                        continue
                    if item is not None:
                        keep(item)
            except zenoh.ZError:
                pass  # undeclared, or its session closed: the ring is gone
            if checked:
                self._count(checked)
            self._pulled += taken
            self._turns += 1
            if not taken:
                self._executor_pulls = False
                self._handback.set()
        overflow = len(checked) - (self._pending.maxlen or len(checked))
        if overflow > 0:
            with self._pending_lock:  # the receive thread counts its own under it
                self.queue_overflows += overflow
            del checked[:overflow]
        deliver = self._deliver
        for payload, info in checked:
            if self._destroyed:
                break
            deliver(payload, info)
        return taken

    def _count(self, checked: list[tuple[zenoh.ZBytes, MessageInfo]]) -> None:
        """Count the samples of one pull in the statistics, a run of one publisher's in one call."""
        infos = [info for _, info in checked]
        # The infos' fields as columns, in C (per-field list comprehensions cost 0.05 µs more per sample).
        stamps, receives, sequences, gids, sizes, _, _ = zip(*infos, strict=True)
        gid = gids[0]
        if gids.count(gid) == len(gids):  # one publisher (the usual case)
            self.statistics.on_samples(gid, sequences, stamps, receives, sum(sizes))
            return
        for stamp, received, seq, publisher_gid, size, *_ in infos:
            self._on_stats(publisher_gid, seq, stamp, received, size)

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
                message = _deserialize(payload, info.type_name)
            except MessageError as err:
                self.statistics.on_malformed(info.publisher_gid)
                self.node.error_log.warning(f"{self.topic}:cdr", "%s: dropped a malformed sample: %s", self.topic, err)
                return
        try:
            if self._with_info:
                self.callback(message, info)
            else:
                self.callback(message)
        except Exception as err:
            self.statistics.on_error(info.publisher_gid)
            self.node.error_log.warning(
                f"{self.topic}:cb", "%s: callback %s raised %s: %s", self.topic, self.callback, type(err).__name__, err
            )

    def _undeclare(self) -> None:
        try:
            self._subscriber.undeclare()
        except Exception as err:
            log.debug("subscriber undeclare: %s", err)
