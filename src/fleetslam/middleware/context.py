"""The process's middleware context: one Zenoh session, configured from the environment like rmw_zenoh.

Environment (explicit constructor arguments win):

- ``FLEETSLAM_ROUTER``: router endpoint(s), comma separated (default ``tcp/localhost:7447``; the master's role);
- ``FLEETSLAM_LISTEN``: this host's listen endpoint (default ``tcp/localhost:0``; the ROS_IP role);
- ``FLEETSLAM_AGENT``: default namespace of the process's nodes;
- ``ROS_DOMAIN_ID``: first chunk of every key (default 0);
- ``ZENOH_SESSION_CONFIG_URI``: a JSON5 session config replacing the defaults (then the router/listen
  variables are not applied unless given explicitly);
- ``ZENOH_CONFIG_OVERRIDE``: ``a/b=json5;c=json5`` pairs inserted on top (bad pairs are warned about and skipped);
- ``FLEETSLAM_STATISTICS``: ``0`` turns the per-subscription statistics off.

The default session is rmw_zenoh's: peer mode connected to the router, multicast scouting off, gossip on,
timestamping on, queries time out after 600 s.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from fleetslam.errors import ConfigError, RouterUnreachableError
from fleetslam.middleware.names import domain_id_from_env, namespace_from_env, normalize_namespace

if TYPE_CHECKING:
    from fleetslam.middleware.graph import Graph
    from fleetslam.middleware.node import Node

log = logging.getLogger(__name__)

DEFAULT_ROUTER = "tcp/localhost:7447"
DEFAULT_LISTEN = "tcp/localhost:0"


def _split_endpoints(text: str | Sequence[str]) -> list[str]:
    items = text.split(",") if isinstance(text, str) else list(text)
    return [item.strip() for item in items if item.strip()]


def apply_config_overrides(config: zenoh.Config, overrides: str) -> list[str]:
    """Apply ``ZENOH_CONFIG_OVERRIDE``-style pairs; returns the pairs that were skipped (and warns)."""
    skipped = []
    for pair in overrides.split(";"):
        pair = pair.strip()
        if not pair:
            continue
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            log.warning("ZENOH_CONFIG_OVERRIDE: skipping %r (expected key=json5)", pair)
            skipped.append(pair)
            continue
        try:
            config.insert_json5(key.strip(), value.strip())
        except Exception as err:  # zenoh raises ZError for unknown keys or bad values
            log.warning("ZENOH_CONFIG_OVERRIDE: skipping %r: %s", pair, err)
            skipped.append(pair)
    return skipped


def session_config(
    *,
    mode: str = "peer",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    environ: Mapping[str, str] | None = None,
    use_config_file: bool = True,
) -> zenoh.Config:
    """rmw_zenoh's default session config (or the file in ZENOH_SESSION_CONFIG_URI), plus overrides."""
    environ = os.environ if environ is None else environ
    uri = environ.get("ZENOH_SESSION_CONFIG_URI", "").strip() if use_config_file else ""
    if uri:
        path = Path(uri)
        try:
            config = zenoh.Config.from_file(str(path))
        except Exception as err:
            raise ConfigError(f"ZENOH_SESSION_CONFIG_URI={uri}: invalid Zenoh config: {err}") from err
        if connect:
            config.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if listen:
            config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    else:
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("scouting/gossip/enabled", "true")
        config.insert_json5("timestamping/enabled", "true" if mode == "router" else '{"router": true, "peer": true}')
        config.insert_json5("queries_default_timeout", "600000")
    overrides = environ.get("ZENOH_CONFIG_OVERRIDE", "")
    if overrides:
        apply_config_overrides(config, overrides)
    return config


class Context:
    """One Zenoh session shared by the process's nodes.

    Args:
        router: router endpoint(s); default from ``FLEETSLAM_ROUTER``.
        listen: listen endpoint(s) of this process; default from ``FLEETSLAM_LISTEN``.
        domain_id: ROS domain; default from ``ROS_DOMAIN_ID``.
        namespace: default namespace of nodes; default from ``FLEETSLAM_AGENT``.
        statistics: publish per-subscription statistics on /statistics (default: on unless
            ``FLEETSLAM_STATISTICS=0``).
        router_timeout_s: how long to wait for the router before raising RouterUnreachableError; a negative
            value skips the check (like ``ZENOH_ROUTER_CHECK_ATTEMPTS<0``).
        environ: environment to read (default ``os.environ``).
    """

    def __init__(
        self,
        *,
        router: str | Sequence[str] | None = None,
        listen: str | Sequence[str] | None = None,
        domain_id: int | None = None,
        namespace: str | None = None,
        statistics: bool | None = None,
        router_timeout_s: float = 3.0,
        environ: Mapping[str, str] | None = None,
    ) -> None:
        environ = dict(os.environ if environ is None else environ)
        router_text = router if router is not None else environ.get("FLEETSLAM_ROUTER", DEFAULT_ROUTER)
        listen_text = listen if listen is not None else environ.get("FLEETSLAM_LISTEN", DEFAULT_LISTEN)
        self.router_endpoints = _split_endpoints(router_text)
        self.listen_endpoints = _split_endpoints(listen_text)
        self.domain_id = domain_id if domain_id is not None else domain_id_from_env(environ)
        self.namespace = normalize_namespace(namespace) if namespace is not None else namespace_from_env(environ)
        if statistics is None:
            statistics = environ.get("FLEETSLAM_STATISTICS", "1").strip().lower() not in ("0", "false", "off", "no")
        self.statistics_enabled = statistics
        config = session_config(connect=self.router_endpoints, listen=self.listen_endpoints, environ=environ)
        try:
            self.session = zenoh.open(config)
        except Exception as err:
            raise RouterUnreachableError(self._unreachable_message(str(err))) from err
        self.zid = str(self.session.info.zid())
        self._ids = itertools.count()
        self._ids_lock = threading.Lock()
        self._nodes: list[Node] = []
        self._closed = threading.Event()
        self._graph: Graph | None = None
        if router_timeout_s >= 0 and self.router_endpoints:
            self._wait_for_router(router_timeout_s)

    def _unreachable_message(self, detail: str = "") -> str:
        where = ", ".join(self.router_endpoints) or "(no endpoint)"
        suffix = f" ({detail})" if detail else ""
        return (
            f"no Zenoh router at {where}{suffix}: start one with `fleetslam router` on that host, "
            "or point FLEETSLAM_ROUTER at a running one"
        )

    def _wait_for_router(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            if list(self.session.info.routers_zid()):
                return
            if time.monotonic() >= deadline:
                self.session.close()
                raise RouterUnreachableError(self._unreachable_message())
            time.sleep(0.05)

    # -- ids and registry ----------------------------------------------------------------------------------
    def next_entity_id(self) -> int:
        """Next id from the context's one counter (nodes and entities share it, as in rmw_zenoh)."""
        with self._ids_lock:
            return next(self._ids)

    def _register(self, node: Node) -> None:
        self._nodes.append(node)

    def _unregister(self, node: Node) -> None:
        if node in self._nodes:
            self._nodes.remove(node)

    @property
    def graph(self) -> Graph:
        """The graph of the running system, discovered from liveliness tokens (started on first use)."""
        if self._graph is None:
            from fleetslam.middleware.graph import Graph

            self._graph = Graph(self.session, self.domain_id)
        return self._graph

    @property
    def closed(self) -> bool:
        return self._closed.is_set()

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def spin(self, timeout_s: float | None = None) -> None:
        """Block until the context is closed, ``timeout_s`` passes, or Ctrl-C."""
        self._closed.wait(timeout_s)

    def close(self) -> None:
        """Destroy every node (their tokens disappear from the graph) and close the session."""
        if self._closed.is_set():
            return
        for node in list(self._nodes):
            node.destroy()
        if self._graph is not None:
            self._graph.close()
        self._closed.set()
        try:
            self.session.close()
        except Exception as err:  # closing twice or after a transport error is harmless
            log.debug("closing the Zenoh session: %s", err)

    def __enter__(self) -> Context:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
