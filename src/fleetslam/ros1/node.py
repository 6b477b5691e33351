"""A ROS 1 node in pure Python: the master's XML-RPC API (as a client), the slave API (as a server) and TCPROS.

Enough of ROS 1 for a bridge: advertise and publish raw ROS 1 bytes (latched or not), subscribe and receive raw
bytes, provide and call services (raw request and response bytes), answer ``rosnode info/ping``, ``rostopic`` and
``rosservice`` probes, follow ``publisherUpdate``, and register again when the master restarts (a watchdog
compares the master's pid). Every peer is untrusted: a malformed header or message closes that one connection
with a logged reason; nothing a peer sends stops the node.

Services speak TCPROS on the same port as topics: the caller's header names ``service`` (not ``topic``),
``md5sum`` and ``callerid`` (``probe=1`` asks for the reply header only, ``persistent=1`` keeps the connection
for more calls); each request is a length-prefixed message, each answer an ok byte (1) and the response, or 0
and an error string.

Threads: one XML-RPC server, one TCPROS accept loop, one watchdog, one reader per inbound connection (a service
call runs its handler there) and one writer per outbound connection (a slow subscriber drops its oldest queued
messages, it never blocks others).
"""

from __future__ import annotations

import collections
import contextlib
import http.client
import logging
import os
import socket
import socketserver
import threading
import time
import xmlrpc.client
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar
from urllib.parse import urlparse
from xmlrpc.server import SimpleXMLRPCRequestHandler, SimpleXMLRPCServer

from fleetslam.errors import MiddlewareError, ServiceError
from fleetslam.ros1 import tcpros
from fleetslam.ros1.messages import Ros1ServiceType, Ros1Type

log = logging.getLogger(__name__)

EntityT = TypeVar("EntityT")

#: Seconds a peer gets to send its connection header; a silent peer cannot hold a thread forever.
HEADER_TIMEOUT_S = 5.0
#: Messages queued per subscriber connection before the oldest are dropped.
OUTBOUND_QUEUE = 8


class MasterUnreachableError(MiddlewareError):
    """The ROS master did not answer."""


class _TimeoutTransport(xmlrpc.client.Transport):
    def __init__(self, timeout_s: float) -> None:
        super().__init__()
        self.timeout_s = timeout_s

    def make_connection(self, host: Any) -> http.client.HTTPConnection:
        conn = super().make_connection(host)
        conn.timeout = self.timeout_s
        return conn


def xmlrpc_call(uri: str, method: str, *args: Any, timeout_s: float = 5.0) -> Any:
    """One ROS XML-RPC call; returns the value of a ``[code, status, value]`` answer with code 1."""
    try:
        proxy = xmlrpc.client.ServerProxy(uri, transport=_TimeoutTransport(timeout_s), allow_none=False)
        answer = getattr(proxy, method)(*args)
    except (OSError, http.client.HTTPException, xmlrpc.client.Error) as err:
        raise MasterUnreachableError(f"{method} at {uri} failed: {err}") from err
    if not (isinstance(answer, list | tuple) and len(answer) == 3 and isinstance(answer[0], int)):
        raise MiddlewareError(f"{method} at {uri}: not a ROS answer [code, status, value]: {answer!r:.200}")
    code, status, value = answer
    if code != 1:
        raise MiddlewareError(f"{method} at {uri} refused: {status}")
    return value


@dataclass
class _Outbound:
    """One subscriber's TCPROS connection to us, fed by its own writer thread."""

    sock: socket.socket
    peer: str
    queue: collections.deque[bytes] = field(default_factory=lambda: collections.deque(maxlen=OUTBOUND_QUEUE))
    ready: threading.Condition = field(default_factory=threading.Condition)
    closed: bool = False

    def push(self, data: bytes) -> None:
        with self.ready:
            self.queue.append(data)
            self.ready.notify()

    def close(self) -> None:
        with self.ready:
            self.closed = True
            self.ready.notify()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()

    def run(self) -> None:
        try:
            while True:
                with self.ready:
                    while not self.queue and not self.closed:
                        self.ready.wait()
                    if self.closed:
                        return
                    data = self.queue.popleft()
                self.sock.sendall(data)
        except OSError as err:
            log.info("ROS 1 subscriber %s went away: %s", self.peer, err)
        finally:
            self.closed = True


class Ros1Publisher:
    """Publishes raw ROS 1 bytes on a topic; latched publishers hand their last message to late subscribers."""

    def __init__(self, node: Ros1Node, topic: str, msg_type: Ros1Type, latch: bool) -> None:
        self.node = node
        self.topic = topic
        self.type = msg_type
        self.latch = latch
        self.connections: list[_Outbound] = []
        self.last: bytes | None = None
        self.published = 0
        self._lock = threading.Lock()

    def publish(self, ros1_bytes: bytes) -> None:
        data = tcpros.frame(ros1_bytes)
        with self._lock:
            if self.latch:
                self.last = data
            self.connections = [c for c in self.connections if not c.closed]
            targets = list(self.connections)
            self.published += 1
        for conn in targets:
            conn.push(data)

    def add(self, conn: _Outbound) -> None:
        with self._lock:
            if self.last is not None:
                conn.push(self.last)
            self.connections.append(conn)
        threading.Thread(target=conn.run, name=f"tcpros-out {self.topic}", daemon=True).start()

    def close(self) -> None:
        with self._lock:
            conns, self.connections = self.connections, []
        for conn in conns:
            conn.close()


class Ros1Subscription:
    """Receives raw ROS 1 bytes of a topic from every publisher the master names."""

    def __init__(self, node: Ros1Node, topic: str, msg_type: Ros1Type, callback: Callable[[bytes, str], None]) -> None:
        self.node = node
        self.topic = topic
        self.type = msg_type
        self.callback = callback
        """``callback(ros1_bytes, publisher_callerid)``, on the connection's reader thread."""
        self.received = 0
        self.errors = 0
        self._lock = threading.Lock()
        self._connected: dict[str, socket.socket] = {}
        self._closed = False

    def update_publishers(self, uris: list[str]) -> None:
        with self._lock:
            if self._closed:
                return
            new = [u for u in uris if u not in self._connected and u != self.node.uri]
            for uri in new:
                self._connected[uri] = socket.socket()  # placeholder until connected; closed on close()
        for uri in new:
            threading.Thread(target=self._read, args=(uri,), name=f"tcpros-in {self.topic}", daemon=True).start()

    def _read(self, uri: str) -> None:
        try:
            protocol = xmlrpc_call(uri, "requestTopic", self.node.caller_id, self.topic, [["TCPROS"]])
            if not (isinstance(protocol, list) and len(protocol) == 3 and protocol[0] == "TCPROS"):
                raise MiddlewareError(f"publisher {uri} offers no TCPROS for {self.topic}: {protocol!r:.200}")
            _, host, port = protocol
            sock = socket.create_connection((str(host), int(port)), timeout=HEADER_TIMEOUT_S)
            with self._lock:
                placeholder = self._connected.get(uri)
                self._connected[uri] = sock
                if self._closed:
                    sock.close()
                    return
            if placeholder is not None and placeholder is not sock:
                placeholder.close()
            sock.sendall(
                tcpros.encode_header(
                    {
                        "callerid": self.node.caller_id,
                        "topic": self.topic,
                        "md5sum": self.type.md5sum,
                        "type": self.type.ros1_name,
                        "message_definition": self.type.definition,
                        "tcp_nodelay": "1",
                    }
                )
            )
            header = tcpros.recv_header(sock)
            if "error" in header:
                raise MiddlewareError(f"publisher {uri} refused {self.topic}: {header['error']}")
            if header.get("md5sum") not in (self.type.md5sum, "*"):
                raise MiddlewareError(
                    f"publisher {uri} of {self.topic} sends {header.get('type')} (md5 {header.get('md5sum')}),"
                    f" not {self.type.ros1_name} ({self.type.md5sum})"
                )
            sock.settimeout(None)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            publisher = header.get("callerid", uri)
            log.info("ROS 1 %s: connected to %s", self.topic, publisher)
            while True:
                data = tcpros.recv_message(sock)
                self.received += 1
                try:
                    self.callback(data, publisher)
                except Exception as err:  # one bad message must not end the connection
                    self.errors += 1
                    log.warning("ROS 1 %s: message from %s dropped: %s", self.topic, publisher, err)
        except (OSError, MiddlewareError) as err:
            if not self._closed:
                log.info("ROS 1 %s: connection to %s ended: %s", self.topic, uri, err)
        finally:
            with self._lock:
                sock_left = self._connected.pop(uri, None)
            if sock_left is not None:
                sock_left.close()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            socks, self._connected = list(self._connected.values()), {}
        for sock in socks:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()


class Ros1ServiceServer:
    """Provides a ROS 1 service: ``handler(request_bytes, caller_id) -> response_bytes`` answers each call on the
    caller's connection thread; an exception it raises is the caller's error answer (ok byte 0 and the reason)."""

    def __init__(
        self, node: Ros1Node, name: str, srv_type: Ros1ServiceType, handler: Callable[[bytes, str], bytes]
    ) -> None:
        self.node = node
        self.name = name
        self.type = srv_type
        self.handler = handler
        self.calls = 0
        self.errors = 0

    def serve(self, sock: socket.socket, caller: str, *, persistent: bool) -> None:
        """Answer one call (or, persistent, calls until the caller closes); closes ``sock``."""
        answered = 0
        try:
            while True:
                # A caller sends its request right after the headers; a persistent one may wait between calls.
                sock.settimeout(None if answered else HEADER_TIMEOUT_S)
                request = tcpros.recv_message(sock)
                try:
                    answer = b"\x01" + tcpros.frame(self.handler(request, caller))
                    self.calls += 1
                except Exception as err:  # any failure of the handler is the caller's answer, not ours to raise
                    self.errors += 1
                    log.info("ROS 1 service %s: call from %s failed: %s", self.name, caller, err)
                    answer = b"\x00" + tcpros.frame(f"{self.name}: {err}".encode())
                sock.sendall(answer)
                answered += 1
                if not persistent:
                    return
        except (OSError, MiddlewareError) as err:
            # After a first call, a persistent caller ends the connection by closing it: that is no error.
            (log.debug if answered else log.info)("ROS 1 service %s: %s ended: %s", self.name, caller, err)
        finally:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()


class _QuietHandler(SimpleXMLRPCRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        log.debug("xmlrpc: " + format, *args)


class _ThreadingXMLRPCServer(socketserver.ThreadingMixIn, SimpleXMLRPCServer):
    daemon_threads = True


class Ros1Node:
    """A ROS 1 node named ``name`` registered at ``master_uri``; its servers listen on ``host``."""

    def __init__(self, name: str, *, master_uri: str, host: str = "127.0.0.1", watchdog_period_s: float = 1.0) -> None:
        self.caller_id = name if name.startswith("/") else f"/{name}"
        self.master_uri = master_uri
        self.host = host
        self.watchdog_period_s = watchdog_period_s
        self.publishers: dict[str, Ros1Publisher] = {}
        self.subscriptions: dict[str, Ros1Subscription] = {}
        self.services: dict[str, Ros1ServiceServer] = {}
        self.registrations = 0
        """How many times this node registered with a master (1 + restarts survived)."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._master_pid: int | None = None
        self._master_up = False
        self._xmlrpc = _ThreadingXMLRPCServer(
            (host, 0), requestHandler=_QuietHandler, logRequests=False, allow_none=False
        )
        self._xmlrpc.register_instance(_SlaveApi(self))
        self.uri = f"http://{host}:{self._xmlrpc.server_address[1]}/"
        self._tcpros = socket.create_server((host, 0))
        self.tcpros_port = self._tcpros.getsockname()[1]
        self.service_uri = f"rosrpc://{host}:{self.tcpros_port}"
        self._threads = [
            threading.Thread(target=self._xmlrpc.serve_forever, name="ros1-xmlrpc", daemon=True),
            threading.Thread(target=self._accept, name="ros1-tcpros", daemon=True),
        ]

    # -- lifecycle ------------------------------------------------------------------------------------------
    def start(self) -> Ros1Node:
        """Start serving; raises :class:`MasterUnreachableError` naming the URI when no master answers."""
        try:
            self._master_pid = int(xmlrpc_call(self.master_uri, "getPid", self.caller_id))
        except MiddlewareError as err:
            self._shutdown_servers()
            raise MasterUnreachableError(
                f"ROS master at {self.master_uri} is unreachable ({err}); start roscore or set ROS_MASTER_URI"
            ) from err
        self._master_up = True
        self.registrations = 1
        for thread in self._threads:
            thread.start()
        watchdog = threading.Thread(target=self._watch_master, name="ros1-watchdog", daemon=True)
        watchdog.start()
        self._threads.append(watchdog)
        return self

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        for topic, pub in list(self.publishers.items()):
            with contextlib.suppress(MiddlewareError):
                xmlrpc_call(self.master_uri, "unregisterPublisher", self.caller_id, topic, self.uri, timeout_s=1.0)
            pub.close()
        for topic, sub in list(self.subscriptions.items()):
            with contextlib.suppress(MiddlewareError):
                xmlrpc_call(self.master_uri, "unregisterSubscriber", self.caller_id, topic, self.uri, timeout_s=1.0)
            sub.close()
        for name in list(self.services):
            with contextlib.suppress(MiddlewareError):
                xmlrpc_call(self.master_uri, "unregisterService", self.caller_id, name, self.service_uri, timeout_s=1.0)
        self._shutdown_servers()

    def _shutdown_servers(self) -> None:
        if self._threads[0].is_alive():
            self._xmlrpc.shutdown()
        self._xmlrpc.server_close()
        with contextlib.suppress(OSError):
            self._tcpros.shutdown(socket.SHUT_RDWR)
        self._tcpros.close()

    def __enter__(self) -> Ros1Node:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- topics ---------------------------------------------------------------------------------------------
    def _add_registered(
        self, table: dict[str, EntityT], name: str, taken: str, make: Callable[[], EntityT],
        register: Callable[[EntityT], None],
    ) -> EntityT:  # fmt: skip
        """Add an entity to ``table`` under ``name`` and register it with the master; a failed registration (the
        master down) leaves nothing half-added, so the caller may try again once the master is back. ``taken``
        says what the name already is, for the error (e.g. "topic /a is already advertised")."""
        with self._lock:
            if name in table:
                raise MiddlewareError(f"ROS 1 {taken} by {self.caller_id}")
            entity = table[name] = make()
        try:
            register(entity)
        except MiddlewareError:
            del table[name]
            raise
        return entity

    def advertise(self, topic: str, msg_type: Ros1Type, *, latch: bool = False) -> Ros1Publisher:
        return self._add_registered(
            self.publishers, topic, f"topic {topic} is already advertised",
            lambda: Ros1Publisher(self, topic, msg_type, latch), self._register_publisher,
        )  # fmt: skip

    def subscribe(self, topic: str, msg_type: Ros1Type, callback: Callable[[bytes, str], None]) -> Ros1Subscription:
        return self._add_registered(
            self.subscriptions, topic, f"topic {topic} is already subscribed",
            lambda: Ros1Subscription(self, topic, msg_type, callback), self._register_subscriber,
        )  # fmt: skip

    def _register_publisher(self, pub: Ros1Publisher) -> None:
        xmlrpc_call(self.master_uri, "registerPublisher", self.caller_id, pub.topic, pub.type.ros1_name, self.uri)

    def _register_subscriber(self, sub: Ros1Subscription) -> None:
        uris = xmlrpc_call(
            self.master_uri, "registerSubscriber", self.caller_id, sub.topic, sub.type.ros1_name, self.uri
        )
        sub.update_publishers([str(u) for u in uris])

    # -- services -------------------------------------------------------------------------------------------
    def advertise_service(
        self, name: str, srv_type: Ros1ServiceType, handler: Callable[[bytes, str], bytes]
    ) -> Ros1ServiceServer:
        """Provide service ``name``: ``handler(request_bytes, caller_id) -> response_bytes``."""
        return self._add_registered(
            self.services, name, f"service {name} is already provided",
            lambda: Ros1ServiceServer(self, name, srv_type, handler), self._register_service,
        )  # fmt: skip

    def _register_service(self, server: Ros1ServiceServer) -> None:
        xmlrpc_call(self.master_uri, "registerService", self.caller_id, server.name, self.service_uri, self.uri)

    def lookup_service(self, name: str) -> tuple[str, int]:
        """(host, port) of the TCPROS server that provides ``name``; :class:`ServiceError` when none does."""
        try:
            uri = str(xmlrpc_call(self.master_uri, "lookupService", self.caller_id, name))
        except MiddlewareError as err:
            raise ServiceError(f"ROS 1 service {name}: no provider ({err})") from err
        parsed = urlparse(uri)
        if parsed.scheme != "rosrpc" or not parsed.hostname or parsed.port is None:
            raise ServiceError(f"ROS 1 service {name}: the master gave {uri!r}, not rosrpc://host:port")
        return parsed.hostname, parsed.port

    def _service_connection(self, name: str, header: dict[str, str], timeout_s: float) -> socket.socket:
        """A connection to ``name``'s provider after the header exchange; returns it with the reply header read
        into ``header`` (which is replaced by the provider's)."""
        host, port = self.lookup_service(name)
        sock = socket.create_connection((host, port), timeout=timeout_s)
        try:
            sock.sendall(tcpros.encode_header({"callerid": self.caller_id, "service": name, **header}))
            reply = tcpros.recv_header(sock)
        except (OSError, MiddlewareError):
            sock.close()
            raise
        header.clear()
        header.update(reply)
        return sock

    def probe_service(self, name: str, *, timeout_s: float = HEADER_TIMEOUT_S) -> dict[str, str]:
        """The header a service's provider answers a probe with (``type``, ``md5sum``, ...), as rosservice asks."""
        header = {"md5sum": "*", "probe": "1"}
        try:
            self._service_connection(name, header, timeout_s).close()
        except (OSError, MiddlewareError) as err:
            raise ServiceError(f"ROS 1 service {name}: probe failed: {err}") from err
        if "error" in header:
            raise ServiceError(f"ROS 1 service {name}: probe refused: {header['error']}")
        return header

    def call_service(self, name: str, srv_type: Ros1ServiceType, request: bytes, *, timeout_s: float = 10.0) -> bytes:
        """Call ``name`` with serialised ``request``; the serialised response, or :class:`ServiceError` naming why
        not (no provider, refused, the provider's error string, no answer within ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s

        def remaining() -> float:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no response within {timeout_s} s")
            return left

        header = {"md5sum": srv_type.md5sum, "type": srv_type.ros1_name}
        try:
            sock = self._service_connection(name, header, timeout_s)
        except (OSError, MiddlewareError) as err:
            raise ServiceError(f"ROS 1 service {name} ({srv_type.ros1_name}): {err}") from err
        with sock:
            try:
                if "error" in header:
                    raise ServiceError(f"refused: {header['error']}")
                if header.get("md5sum") != srv_type.md5sum:
                    raise ServiceError(
                        f"the provider serves {header.get('type')} (md5 {header.get('md5sum')}), not"
                        f" {srv_type.ros1_name} ({srv_type.md5sum})"
                    )
                sock.settimeout(remaining())
                sock.sendall(tcpros.frame(request))
                sock.settimeout(remaining())
                ok = tcpros.recv_exact(sock, 1)
                sock.settimeout(remaining())
                body = tcpros.recv_message(sock)
            except (OSError, MiddlewareError) as err:
                if isinstance(err, socket.timeout):
                    err = TimeoutError(f"no response within {timeout_s} s")
                raise ServiceError(f"ROS 1 service {name} ({srv_type.ros1_name}): {err}") from err
        if ok != b"\x01":
            reason = body.decode(errors="replace")
            raise ServiceError(f"ROS 1 service {name} ({srv_type.ros1_name}) failed: {reason}")
        return body

    def services_of(self) -> dict[str, list[str]]:
        """ROS 1 service -> caller ids of its providers (``getSystemState``)."""
        state = xmlrpc_call(self.master_uri, "getSystemState", self.caller_id)
        return {str(name): [str(n) for n in nodes] for name, nodes in state[2]}

    def published_topics(self) -> dict[str, str]:
        """ROS 1 topic -> type of every topic some node publishes (``getPublishedTopics``)."""
        return {str(t): str(ty) for t, ty in xmlrpc_call(self.master_uri, "getPublishedTopics", self.caller_id, "")}

    def publishers_of(self) -> dict[str, list[str]]:
        """ROS 1 topic -> caller ids of its publishers (``getSystemState``)."""
        state = xmlrpc_call(self.master_uri, "getSystemState", self.caller_id)
        return {str(topic): [str(n) for n in nodes] for topic, nodes in state[0]}

    # -- master watchdog ------------------------------------------------------------------------------------
    def _watch_master(self) -> None:
        while not self._stop.wait(self.watchdog_period_s):
            try:
                pid = int(xmlrpc_call(self.master_uri, "getPid", self.caller_id, timeout_s=2.0))
            except MiddlewareError as err:
                if self._master_up:
                    log.warning("ROS master at %s lost (%s); waiting for it to come back", self.master_uri, err)
                self._master_up = False
                continue
            if pid == self._master_pid:
                # The same master process (a busy master times out, and answers again): it still holds our
                # registrations, and registering again would only count a restart that did not happen.
                if not self._master_up:
                    log.info("ROS master at %s answers again (same pid %d)", self.master_uri, pid)
                self._master_up = True
                continue
            log.info("ROS master at %s is back (pid %d); registering again", self.master_uri, pid)
            try:
                for pub in list(self.publishers.values()):
                    self._register_publisher(pub)
                for sub in list(self.subscriptions.values()):
                    self._register_subscriber(sub)
                for server in list(self.services.values()):
                    self._register_service(server)
            except MiddlewareError as err:
                log.warning("registering again with %s failed: %s", self.master_uri, err)
                continue
            self._master_pid = pid
            self._master_up = True
            self.registrations += 1

    # -- inbound TCPROS (subscribers of our publishers) -------------------------------------------------------
    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                sock, addr = self._tcpros.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(sock, f"{addr[0]}:{addr[1]}"), daemon=True).start()

    def _serve(self, sock: socket.socket, peer: str) -> None:
        sock.settimeout(HEADER_TIMEOUT_S)
        try:
            header = tcpros.recv_header(sock)
            if "service" in header:
                service_reply, server = self._answer_service(header)
                sock.sendall(tcpros.encode_header(service_reply))
            else:
                reply, pub = self._answer(header)
                sock.sendall(tcpros.encode_header(reply))
        except (OSError, MiddlewareError) as err:
            log.warning("TCPROS connection from %s refused: %s", peer, err)
            sock.close()
            return
        if "service" in header:
            if server is None or header.get("probe") == "1":
                sock.close()
                return
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            persistent = header.get("persistent", "").lower() in ("1", "true")
            server.serve(sock, f"{header['callerid']} at {peer}", persistent=persistent)
            return
        if pub is None or header.get("probe") == "1":
            sock.close()
            return
        sock.settimeout(None)
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        pub.add(_Outbound(sock, f"{header.get('callerid', '?')} at {peer}"))

    def _answer(self, header: dict[str, str]) -> tuple[dict[str, str], Ros1Publisher | None]:
        """The reply to a subscriber's header, and the publisher it connects to (None: an error reply)."""
        topic = header.get("topic")
        if topic is None:
            return {"error": "header names no 'topic' and no 'service'"}, None
        pub = self.publishers.get(topic)
        if pub is None:
            return {"error": f"{self.caller_id} does not publish {topic}"}, None
        if header.get("md5sum", "*") not in ("*", pub.type.md5sum):
            return {
                "error": f"{topic} is {pub.type.ros1_name} (md5 {pub.type.md5sum}), the subscriber asked for"
                f" {header.get('type')} (md5 {header.get('md5sum')})"
            }, None
        reply = {
            "callerid": self.caller_id,
            "topic": topic,
            "type": pub.type.ros1_name,
            "md5sum": pub.type.md5sum,
            "message_definition": pub.type.definition,
            "latching": "1" if pub.latch else "0",
        }
        return reply, pub

    def _answer_service(self, header: dict[str, str]) -> tuple[dict[str, str], Ros1ServiceServer | None]:
        """The reply to a service caller's header, and the service it calls (None: an error reply)."""
        name = header["service"]
        missing = [key for key in ("md5sum", "callerid") if key not in header]
        if missing:
            return {"error": f"service header lacks {', '.join(missing)}"}, None
        server = self.services.get(name)
        if server is None:
            return {"error": f"{self.caller_id} does not provide service {name}"}, None
        srv = server.type
        if header["md5sum"] not in ("*", srv.md5sum):
            return {
                "error": f"{name} is {srv.ros1_name} (md5 {srv.md5sum}), the caller asked for"
                f" {header.get('type', '?')} (md5 {header['md5sum']})"
            }, None
        reply = {
            "callerid": self.caller_id,
            "service": name,
            "type": srv.ros1_name,
            "md5sum": srv.md5sum,
            "request_type": srv.request.ros1_name,
            "response_type": srv.response.ros1_name,
        }
        return reply, server


class _SlaveApi:
    """The ROS 1 slave API (http://wiki.ros.org/ROS/Slave_API), as far as tools use it; method names are the
    protocol's."""

    def __init__(self, node: Ros1Node) -> None:
        self._node = node

    def getBusStats(self, caller_id: str) -> list[Any]:
        pubs = [[t, p.published, []] for t, p in self._node.publishers.items()]
        subs = [[t, [], []] for t in self._node.subscriptions]
        return [1, "", [pubs, subs, []]]

    def getBusInfo(self, caller_id: str) -> list[Any]:
        info: list[list[Any]] = []
        for topic, pub in self._node.publishers.items():
            info += [[i, c.peer, "o", "TCPROS", topic, True, c.peer] for i, c in enumerate(pub.connections)]
        return [1, "", info]

    def getMasterUri(self, caller_id: str) -> list[Any]:
        return [1, "", self._node.master_uri]

    def shutdown(self, caller_id: str, msg: str = "") -> list[Any]:
        log.warning("%s asked this ROS 1 node to shut down (%s); ignored, stop the bridge instead", caller_id, msg)
        return [1, "ignored", 0]

    def getPid(self, caller_id: str) -> list[Any]:
        return [1, "", os.getpid()]

    def getSubscriptions(self, caller_id: str) -> list[Any]:
        return [1, "", [[t, s.type.ros1_name] for t, s in self._node.subscriptions.items()]]

    def getPublications(self, caller_id: str) -> list[Any]:
        return [1, "", [[t, p.type.ros1_name] for t, p in self._node.publishers.items()]]

    def paramUpdate(self, caller_id: str, key: str, value: Any) -> list[Any]:
        return [1, "", 0]

    def publisherUpdate(self, caller_id: str, topic: str, publishers: list[str]) -> list[Any]:
        sub = self._node.subscriptions.get(topic)
        if sub is not None and isinstance(publishers, list):
            sub.update_publishers([str(u) for u in publishers])
        return [1, "", 0]

    def requestTopic(self, caller_id: str, topic: str, protocols: list[Any]) -> list[Any]:
        if topic not in self._node.publishers:
            return [-1, f"{self._node.caller_id} does not publish {topic}", []]
        offered = [p[0] for p in protocols if isinstance(p, list) and p] if isinstance(protocols, list) else []
        if "TCPROS" not in offered:
            return [0, f"only TCPROS is supported, asked for {offered}", []]
        return [1, "", ["TCPROS", self._node.host, self._node.tcpros_port]]


def master_from_env(environ: dict[str, str] | os._Environ[str]) -> tuple[str, str]:
    """(master URI, host to listen on and advertise) from ROS_MASTER_URI, ROS_IP and ROS_HOSTNAME."""
    master = environ.get("ROS_MASTER_URI", "http://127.0.0.1:11311")
    parsed = urlparse(master)
    if parsed.scheme != "http" or not parsed.hostname:
        raise MiddlewareError(f"ROS_MASTER_URI {master!r} is not an http://host:port URI")
    host = environ.get("ROS_IP") or environ.get("ROS_HOSTNAME") or "127.0.0.1"
    return master, host
