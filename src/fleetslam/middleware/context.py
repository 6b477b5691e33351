"""The process's middleware context: one Zenoh session, configured from the environment like rmw_zenoh.

Environment (explicit constructor arguments win):

- ``FLEETSLAM_ROUTER``: router endpoint(s), comma separated (default ``tcp/localhost:7447``; the ROS master's
  role);
- ``FLEETSLAM_LISTEN``: this host's listen endpoint(s) (default ``tcp/localhost:0``; the ROS_IP role);
- ``FLEETSLAM_AGENT``: default namespace of the process's nodes (``c3po`` → ``/c3po``);
- ``ROS_DOMAIN_ID``: first chunk of every key (default 0);
- ``ZENOH_SESSION_CONFIG_URI``: a JSON5 session config that replaces the defaults; the router and listen
  endpoints are then applied only when given explicitly (argument or variable);
- ``ZENOH_CONFIG_OVERRIDE``: ``a/b=json5;c=json5`` pairs inserted on top (bad pairs are warned about and skipped);
- ``ZENOH_ROUTER_CHECK_ATTEMPTS``: unset → wait up to 2 s for the router, ``<0`` → don't check, ``0`` → wait
  forever, ``n`` → wait up to n seconds (rmw checks n times 1 s apart);
- ``FLEETSLAM_STATISTICS``: ``0`` turns the per-subscription statistics off;
- ``FLEETSLAM_SECURITY``: a keystore made by ``fleetslam security init`` (or one host's folder of it): the session
  is then that host's mutual-TLS client of the router (see :mod:`fleetslam.security`); the host is
  ``FLEETSLAM_IDENTITY``, else the agent of ``FLEETSLAM_AGENT``, else ``station``. ``FLEETSLAM_ROUTER`` still
  overrides the router endpoint; listen endpoints do not apply (a client listens on nothing).

The default session is rmw_zenoh's: peer mode connected to the router, multicast scouting off, gossip on,
timestamping on, queries time out after 600 s (plus ``scouting/delay`` 0: open() does not idle 500 ms, the
context waits for the router itself), and messages larger than :data:`MAX_MESSAGE_BYTES` refused by the
transport while they arrive, before they are reassembled (``transport/link/rx/max_message_size``; with Zenoh's
own default, 1 GiB, one peer made the router and every subscriber hold 300 MB for good; now a refused message
costs at most the limit, which the transport keeps for reuse). Without a reachable router the context raises
:class:`~fleetslam.errors.RouterUnreachableError` at once, saying how to start one.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import os
import re
import signal
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from fleetslam.errors import ConfigError, MiddlewareError, RouterUnreachableError
from fleetslam.middleware.lifetime import Closable, close_at_exit
from fleetslam.middleware.names import domain_id_from_env, namespace_from_env, normalize_namespace

if TYPE_CHECKING:
    from fleetslam.middleware.graph import Graph

log = logging.getLogger(__name__)

DEFAULT_ROUTER = "tcp/localhost:7447"
DEFAULT_LISTEN = "tcp/localhost:0"
DEFAULT_ROUTER_TIMEOUT_S = 2.0
MAX_MESSAGE_BYTES = 16 * 1024 * 1024
"""Largest message a default session or router accepts (a 640×480 RGB image is 0.9 MB, 1920×1080 6.2 MB, a room's
octree a few MB). Raise it with ``ZENOH_CONFIG_OVERRIDE='transport/link/rx/max_message_size=<bytes>'`` on every host."""


_ENDPOINT = re.compile(r"(tcp|udp|tls|quic|ws|unixsock-stream|unixpipe|serial|vsock)/[^\s/?#][^\s]*")


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` if it is ``<protocol>/<address>`` with a Zenoh protocol; else ValueError saying so."""
    if not _ENDPOINT.fullmatch(endpoint.strip()):
        raise ValueError(f"{endpoint!r} is not a Zenoh endpoint (<protocol>/<address>, e.g. tcp/10.0.0.2:7447)")
    return endpoint.strip()


def split_endpoints(text: str | Sequence[str]) -> list[str]:
    """``"tcp/a:1, tcp/b:2"`` (or a list) → ``["tcp/a:1", "tcp/b:2"]``; ConfigError for one that is not an endpoint."""
    items = text.split(",") if isinstance(text, str) else list(text)
    try:
        return [check_endpoint(item) for item in items if item.strip()]
    except ValueError as err:
        raise ConfigError(f"endpoint {err}") from err


def apply_config_overrides(config: zenoh.Config, overrides: str) -> list[str]:
    """Apply ``ZENOH_CONFIG_OVERRIDE``-style pairs; returns the pairs that were skipped (each is warned about)."""
    skipped = []
    for pair in overrides.split(";"):
        pair = pair.strip()
        if not pair:
            continue
        key, sep, value = pair.partition("=")
        if not sep or not key.strip() or not value.strip():
            log.warning("ZENOH_CONFIG_OVERRIDE: skipping %r (expected key=json5)", pair)
            skipped.append(pair)
            continue
        try:
            config.insert_json5(key.strip(), value.strip())
        except Exception as err:  # zenoh raises ZError for unknown keys or bad values
            log.warning("ZENOH_CONFIG_OVERRIDE: skipping %r: %s", pair, err)
            skipped.append(pair)
    return skipped


def load_config_file(uri: str, variable: str) -> zenoh.Config:
    """A Zenoh JSON5 config file; an invalid or missing file is a ConfigError naming the variable."""
    try:
        return zenoh.Config.from_file(uri)
    except Exception as err:
        raise ConfigError(f"{variable}={uri}: invalid Zenoh config file: {err}") from err


def session_config(
    *,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    environ: Mapping[str, str] | None = None,
) -> zenoh.Config:
    """rmw_zenoh's default peer session config (or the file in ``ZENOH_SESSION_CONFIG_URI``), plus overrides.

    With the defaults, ``None`` endpoints mean none; with a file, ``None`` keeps the file's endpoints.
    """
    environ = os.environ if environ is None else environ
    uri = environ.get("ZENOH_SESSION_CONFIG_URI", "").strip()
    security = environ.get("FLEETSLAM_SECURITY", "").strip()
    if uri:
        config = load_config_file(uri, "ZENOH_SESSION_CONFIG_URI")
    elif security:
        from fleetslam.security.keystore import host_folder, load_zenoh_config

        identity = environ.get("FLEETSLAM_IDENTITY", "").strip() or namespace_from_env(environ).strip("/") or "station"
        config = load_zenoh_config(host_folder(Path(security), identity))
        if listen:
            log.warning("FLEETSLAM_SECURITY: a secured host is a client of the router; listen %s ignored", listen)
        listen = None
    else:
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("scouting/gossip/enabled", "true")
        # Zenoh's default waits 500 ms in open() for scouting; we wait for the router explicitly instead.
        config.insert_json5("scouting/delay", "0")
        config.insert_json5("timestamping/enabled", '{"router": true, "peer": true, "client": true}')
        config.insert_json5("queries_default_timeout", "600000")
        config.insert_json5("transport/link/rx/max_message_size", str(MAX_MESSAGE_BYTES))
        connect = connect or []
        listen = listen or []
    if connect is not None:
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if listen is not None:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    overrides = environ.get("ZENOH_CONFIG_OVERRIDE", "")
    if overrides:
        apply_config_overrides(config, overrides)
    return config


def router_timeout_from_env(environ: Mapping[str, str]) -> float:
    """Seconds to wait for the router per ``ZENOH_ROUTER_CHECK_ATTEMPTS`` (inf = forever, negative = no check)."""
    text = environ.get("ZENOH_ROUTER_CHECK_ATTEMPTS", "").strip()
    if not text:
        return DEFAULT_ROUTER_TIMEOUT_S
    try:
        attempts = int(text)
    except ValueError as err:
        raise ConfigError(f"environment variable ZENOH_ROUTER_CHECK_ATTEMPTS={text!r}: expected an integer") from err
    return math.inf if attempts == 0 else float(attempts)


def endpoints_of(config: zenoh.Config, key: str) -> list[str]:
    """The endpoint list at ``key`` of a config ([] when absent or mode-dependent)."""
    try:
        value = json.loads(config.get_json(key))
    except Exception:  # a key the config file does not have
        return []
    return [str(v) for v in value] if isinstance(value, list) else []


class Context:
    """One Zenoh session shared by the process's nodes; a context manager.

    Args:
        router: router endpoint(s), a comma-separated string or a list; default ``FLEETSLAM_ROUTER``.
        listen: listen endpoint(s) of this process; default ``FLEETSLAM_LISTEN``.
        domain_id: ROS domain; default ``ROS_DOMAIN_ID``.
        namespace: default namespace of nodes; default ``FLEETSLAM_AGENT``.
        statistics: publish per-subscription statistics on /statistics (default: on unless
            ``FLEETSLAM_STATISTICS=0``).
        router_timeout_s: how long to wait for the router before raising RouterUnreachableError (``math.inf``:
            forever, negative: no check); default from ``ZENOH_ROUTER_CHECK_ATTEMPTS``, else 2 s.
        environ: environment to read instead of ``os.environ`` (tests pass ``{}``).

    Raises:
        RouterUnreachableError: no router answered in time.
        ConfigError: an environment variable or the session config file is invalid.
        MiddlewareError: the session cannot be opened (e.g. the listen endpoint is taken).
    """

    def __init__(
        self,
        *,
        router: str | Sequence[str] | None = None,
        listen: str | Sequence[str] | None = None,
        domain_id: int | None = None,
        namespace: str | None = None,
        statistics: bool | None = None,
        router_timeout_s: float | None = None,
        environ: Mapping[str, str] | None = None,
    ) -> None:
        environ = dict(os.environ if environ is None else environ)
        from_file = bool(environ.get("ZENOH_SESSION_CONFIG_URI", "").strip() or environ.get("FLEETSLAM_SECURITY"))
        if router is None and "FLEETSLAM_ROUTER" in environ:
            router = environ["FLEETSLAM_ROUTER"]
        if listen is None and "FLEETSLAM_LISTEN" in environ:
            listen = environ["FLEETSLAM_LISTEN"]
        if not from_file:  # a config file keeps its own endpoints unless they are given explicitly
            router = DEFAULT_ROUTER if router is None else router
            listen = DEFAULT_LISTEN if listen is None else listen
        self.domain_id = domain_id if domain_id is not None else domain_id_from_env(environ)
        self.namespace = normalize_namespace(namespace) if namespace is not None else namespace_from_env(environ)
        if statistics is None:
            statistics = environ.get("FLEETSLAM_STATISTICS", "1").strip().lower() not in ("0", "false", "off", "no")
        self.statistics_enabled = statistics
        config = session_config(
            connect=None if router is None else split_endpoints(router),
            listen=None if listen is None else split_endpoints(listen),
            environ=environ,
        )
        self.router_endpoints = endpoints_of(config, "connect/endpoints")
        self.listen_endpoints = endpoints_of(config, "listen/endpoints")
        mode = json.loads(config.get_json("mode") or '"peer"') or "peer"
        try:
            self.session = zenoh.open(config)
        except Exception as err:  # e.g. a listen endpoint that is taken or not an address of this host
            if mode == "client":  # a client's open() fails when it cannot reach a router
                raise RouterUnreachableError(self._unreachable_message(str(err))) from err
            raise MiddlewareError(
                f"cannot open a Zenoh session (connect {self.router_endpoints}, listen {self.listen_endpoints}): {err}"
            ) from err
        self.zid = str(self.session.info.zid())
        self._ids = itertools.count()
        self._ids_lock = threading.Lock()
        self._owned: dict[Closable, None] = {}  # an ordered set: closed in the order they came
        self._owned_lock = threading.Lock()
        self._closed = threading.Event()
        self._graph: Graph | None = None
        self._graph_lock = threading.Lock()
        close_at_exit(self)
        if router_timeout_s is None:
            router_timeout_s = router_timeout_from_env(environ)
        if router_timeout_s >= 0 and mode != "router":
            self._wait_for_router(router_timeout_s)
        log.debug("context %s: connect %s, listen %s", self.zid, self.router_endpoints, self.listen_endpoints)

    def _unreachable_message(self, detail: str = "") -> str:
        where = ", ".join(self.router_endpoints) or "(no connect endpoint configured)"
        suffix = f" ({detail})" if detail else ""
        return (
            f"no router at {where}{suffix}: start one with `fleetslam router` (on that host), "
            "or set FLEETSLAM_ROUTER to a running one's endpoint"
        )

    def _wait_for_router(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not list(self.session.info.routers_zid()):
            if time.monotonic() >= deadline:
                self.session.close()
                raise RouterUnreachableError(self._unreachable_message())
            time.sleep(0.02)

    # -- ids, owned objects, graph ---------------------------------------------------------------------------
    def next_entity_id(self) -> int:
        """Next id from the context's one counter (nodes and entities share it, from 0, as in rmw_zenoh)."""
        with self._ids_lock:
            return next(self._ids)

    def own(self, closable: Closable) -> None:
        """Close ``closable`` when the context closes (a node owns itself to its context when it is made)."""
        with self._owned_lock:
            self._owned[closable] = None

    def disown(self, closable: Closable) -> None:
        """Forget ``closable`` (it was closed on its own); nothing happens if the context does not own it."""
        with self._owned_lock:
            self._owned.pop(closable, None)

    @property
    def closables(self) -> list[Closable]:
        """What the context closes when it closes (its live nodes), in the order they came."""
        with self._owned_lock:
            return list(self._owned)

    @property
    def graph(self) -> Graph:
        """The graph of the running system, discovered from liveliness tokens (started on first use)."""
        with self._graph_lock:
            if self._graph is None:
                from fleetslam.middleware.graph import Graph

                self._graph = Graph(self.session, self.domain_id)
            return self._graph

    @property
    def closed(self) -> bool:
        return self._closed.is_set()

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def spin(self, timeout_s: float | None = None) -> None:
        """Block until the context is closed, ``timeout_s`` passes, or Ctrl-C (which returns cleanly).

        Callbacks do not need it (they run on the nodes' executor threads); it only keeps the main thread alive.
        In the main thread, Ctrl-C (SIGINT) only sets a flag while it spins: a KeyboardInterrupt raised inside the
        wait's lock handling could leave the lock released twice, and a second signal (a supervisor that signals
        the process and its group) would interrupt the handling of the first.
        """
        interrupted = threading.Event()
        previous = None
        if threading.current_thread() is threading.main_thread():
            previous = signal.signal(signal.SIGINT, lambda *_: interrupted.set())
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            while not self._closed.is_set() and not interrupted.is_set():
                left = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
                if left <= 0:
                    break
                self._closed.wait(left)
        except KeyboardInterrupt:  # a SIGINT handler installed by the program itself may still raise
            interrupted.set()
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
        if interrupted.is_set():
            log.info("interrupted")

    def close(self) -> None:
        """Close what the context owns (nodes: their tokens disappear from the graph), then the session;
        idempotent."""
        if self._closed.is_set():
            return
        for closable in self.closables:
            closable.close()
        with self._owned_lock:
            self._owned.clear()
        if self._graph is not None:
            self._graph.close()
        self._closed.set()
        try:
            self.session.close()
        except Exception as err:  # closing after a transport error is harmless
            log.debug("closing the Zenoh session: %s", err)

    def __enter__(self) -> Context:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
