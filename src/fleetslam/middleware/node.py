"""Nodes: publishers, subscriptions, services, clients, timers and typed parameters over Zenoh, rmw_zenoh style.

:class:`Node` composes the entities, one module each: :mod:`~fleetslam.middleware.publisher`,
:mod:`~fleetslam.middleware.subscription`, :mod:`~fleetslam.middleware.service` (servers),
:mod:`~fleetslam.middleware.client`, :mod:`~fleetslam.middleware.timer` and :mod:`~fleetslam.middleware.parameters`,
on the executor of :mod:`~fleetslam.middleware.executor`; they are re-exported here.

Threading:

- every node owns one executor (a thread named ``executor:<fq node name>``). All of a node's callbacks
  (subscriptions, service handlers, timers, :meth:`Node.call_soon`) run one at a time, in arrival order, so a
  node's state needs no locks; they run on the executor's thread, except a KEEP_LAST subscription's samples that
  arrive while the executor is idle, whose receive thread runs a quick callback itself (see below). Callbacks of
  different nodes run concurrently.
- samples are received, checked and counted in the statistics on a receive thread per volatile KEEP_LAST
  subscription (fed by a Zenoh ring channel that drops the oldest when the thread falls behind, so Zenoh never
  waits for Python; handed to the executor in batches, or, while the executor is idle and the subscription's
  callback takes under 1 ms, delivered by the receive thread itself: no thread is woken for them) or on Zenoh's
  callback thread (KEEP_ALL, transient local), and queued per subscription (KEEP_LAST depth: the oldest is dropped
  when the executor falls behind; KEEP_ALL: unbounded). They are deserialized just before their callback, so
  samples dropped by KEEP_LAST cost no decoding.
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

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from fleetslam.config import ConfigModel
from fleetslam.errors import MiddlewareError
from fleetslam.middleware.client import Client
from fleetslam.middleware.context import Context
from fleetslam.middleware.entity import Entity
from fleetslam.middleware.executor import Executor, RateLimitedLogger
from fleetslam.middleware.names import (
    RosArgs,
    agent_of,
    normalize_namespace,
    parse_ros_args,
    resolve_name,
    validate_node_name,
)
from fleetslam.middleware.parameters import load_parameters
from fleetslam.middleware.publisher import Publisher
from fleetslam.middleware.service import Service
from fleetslam.middleware.subscription import DEFAULT_MAX_PAYLOAD_BYTES, MessageInfo, Subscription
from fleetslam.middleware.timer import Timer
from fleetslam.middleware.wire import EntityKind, LivelinessToken, QoSProfile
from fleetslam.msg import typesys

__all__ = [
    "CLOCK_TYPE",
    "DEFAULT_MAX_PAYLOAD_BYTES",
    "STATISTICS_TOPIC",
    "Client",
    "MessageInfo",
    "Node",
    "Publisher",
    "Service",
    "Subscription",
    "Timer",
]

log = logging.getLogger(__name__)

STATISTICS_TOPIC = "/statistics"
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"


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
        self.error_log = RateLimitedLogger()
        """Warnings of the node and its entities (dropped samples, failing callbacks), at a bounded rate."""
        self.callback_errors = 0
        self.parameters: Any = load_parameters(
            parameters, parameter_file or (parsed.params_files[-1] if parsed.params_files else None),
            [*parameter_overrides, *(f"{k}={v}" for k, v in parsed.parameters.items())],
            node_name=self.name, fq_name=self.fq_name,
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
        self._executor = Executor(self.fq_name, self._on_executor_error)
        self.executor_post = self._executor.post
        """:meth:`call_soon` without its own call (the subscriptions' hand-off of every sample)."""
        self.executor_run_here = self._executor.run_here
        """Run a callback on the calling thread if the executor is idle (see :meth:`Executor.run_here`)."""
        self._entities: list[Entity] = []
        self._timers: list[Timer] = []
        self._subscriptions: list[Subscription] = []
        self._statistics_publisher: Publisher | None = None
        self._on_destroy: list[Callable[[], None]] = []
        self._destroyed = False
        self._token = context.session.liveliness().declare_token(self._token_info.key())
        context.own(self)
        if statistics_period_s > 0 and context.statistics_enabled:
            self._timers.append(Timer(self, statistics_period_s, self._publish_statistics))
        self.use_sim_time = use_sim_time
        self._sim_time_ns = 0
        if use_sim_time:
            self._clock = Subscription(self, CLOCK_TYPE, "/clock", self._on_clock, QoSProfile(depth=1))
            self._entities.append(self._clock)

    def _on_executor_error(self, what: str, err: BaseException) -> None:
        self.callback_errors += 1
        self.error_log.warning(f"exec:{what}", "%s: %s raised %s: %s", self.fq_name, what, type(err).__name__, err)

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
                # Forged sequence numbers or stamps can push counts and ages past the message's int32 fields:
                # clamped, so that one hostile sample cannot silence the node's statistics.
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
                    delivered_msgs=_int32(report.delivered),
                    dropped_msgs=_int32(report.dropped),
                    error_msgs=_int32(report.errors),
                    traffic=report.traffic_bytes,
                    period_mean=_duration(report.period_mean_ns),
                    period_stddev=_duration(report.period_stddev_ns),
                    period_max=_duration(report.period_max_ns),
                    stamp_age_mean=_duration(report.age_mean_ns),
                    stamp_age_stddev=_duration(report.age_stddev_ns),
                    stamp_age_max=_duration(report.age_max_ns),
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
        self.context.disown(self)

    def close(self) -> None:
        """Same as :meth:`destroy` (what the context calls on the nodes it owns when it closes)."""
        self.destroy()

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.destroy()


def _gid_array(gid: bytes) -> Any:
    import numpy as np

    return np.frombuffer(gid.ljust(16, b"\x00")[:16], dtype=np.uint8).copy()


_INT32_MAX = 2**31 - 1


def _int32(value: float) -> int:
    """``value`` as the nearest int32 (the message's counters)."""
    return max(-_INT32_MAX - 1, min(_INT32_MAX, int(value)))


def _duration(ns: float) -> Any:
    """builtin_interfaces/Duration of ``ns``, clamped to what its int32 seconds can hold."""
    limit = _INT32_MAX * 1_000_000_000
    return typesys.duration_from_ns(max(-limit, min(limit, int(ns))))
