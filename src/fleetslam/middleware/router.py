"""The fleet's discovery service: a Zenoh router (rmw_zenohd's role, the ROS master's in ROS 1).

A session opened in ``router`` mode routes data and liveliness tokens between the peers that connect to it.
Like ``rmw_zenohd`` it listens on ``tcp/[::]:7447`` by default, with multicast scouting off and gossip on;
it refuses messages over :data:`~fleetslam.middleware.context.MAX_MESSAGE_BYTES` as they arrive (before
reassembling them). ``ZENOH_ROUTER_CONFIG_URI`` replaces those defaults with a JSON5 file and
``ZENOH_CONFIG_OVERRIDE`` applies on top. Explicit ``listen``/``connect`` endpoints always win. ``ROS_DOMAIN_ID``
does not matter to a router.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import zenoh

from fleetslam.errors import MiddlewareError
from fleetslam.middleware.context import (
    MAX_MESSAGE_BYTES,
    apply_config_overrides,
    endpoints_of,
    load_config_file,
    split_endpoints,
)

log = logging.getLogger(__name__)

DEFAULT_ROUTER_LISTEN = ("tcp/[::]:7447",)


def router_config(
    listen: Sequence[str] | None = DEFAULT_ROUTER_LISTEN,
    connect: Sequence[str] | None = (),
    environ: Mapping[str, str] | None = None,
    security: Path | None = None,
) -> zenoh.Config:
    """rmw_zenohd's config (or ``ZENOH_ROUTER_CONFIG_URI``'s file, or the router's of the keystore ``security``:
    mutual TLS and the fleet's access control) with these endpoints and the overrides."""
    environ = os.environ if environ is None else environ
    uri = environ.get("ZENOH_ROUTER_CONFIG_URI", "").strip()
    if security is not None:
        from fleetslam.security.keystore import ROUTER, host_folder, load_zenoh_config

        config = load_zenoh_config(host_folder(security, ROUTER))
    elif uri:
        config = load_config_file(uri, "ZENOH_ROUTER_CONFIG_URI")
    else:
        config = zenoh.Config()
        config.insert_json5("mode", '"router"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("scouting/gossip/enabled", "true")
        config.insert_json5("scouting/delay", "0")  # nothing to scout for: don't idle 500 ms in open()
        config.insert_json5("timestamping/enabled", "true")
        config.insert_json5("transport/link/rx/max_message_size", str(MAX_MESSAGE_BYTES))
    if listen is not None:
        config.insert_json5("listen/endpoints", json.dumps(split_endpoints(listen)))
    if connect is not None:
        config.insert_json5("connect/endpoints", json.dumps(split_endpoints(connect)))
    overrides = environ.get("ZENOH_CONFIG_OVERRIDE", "")
    if overrides:
        apply_config_overrides(config, overrides)
    return config


class Router:
    """A Zenoh router running in this process until :meth:`close`; a context manager.

    Args:
        listen: endpoints to listen on (``None`` with a config file: the file's).
        connect: other routers to connect to.
        environ: environment to read instead of ``os.environ``.
        security: a keystore of ``fleetslam security init`` (its ``router`` folder, or that folder itself): mutual
            TLS and the fleet's access control; ``listen=None`` keeps its ``tls/`` endpoints.

    Raises:
        MiddlewareError: the router cannot start (e.g. the port is taken).
        ConfigError: the config file is invalid.
    """

    def __init__(
        self,
        listen: Sequence[str] | None = DEFAULT_ROUTER_LISTEN,
        *,
        connect: Sequence[str] = (),
        environ: Mapping[str, str] | None = None,
        security: Path | None = None,
    ) -> None:
        config = router_config(list(listen) if listen is not None else None, list(connect), environ, security)
        try:
            self.session = zenoh.open(config)
        except Exception as err:
            where = ", ".join(listen) if listen else "the configured endpoints"
            raise MiddlewareError(f"cannot start the router listening on {where}: {err}") from err
        self.zid = str(self.session.info.zid())
        self.listen = endpoints_of(config, "listen/endpoints")
        self._closed = False
        log.info("router %s listening on %s", self.zid, ", ".join(self.listen))

    def peers(self) -> list[str]:
        """Zenoh ids of the peers connected to this router."""
        return [str(z) for z in self.session.info.peers_zid()]

    def close(self) -> None:
        """Stop routing; connected peers lose each other unless they are also directly connected."""
        if self._closed:
            return
        self._closed = True
        self.session.close()
        log.info("router %s stopped", self.zid)

    def __enter__(self) -> Router:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
