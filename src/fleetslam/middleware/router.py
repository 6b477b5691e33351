"""The fleet's discovery service: a Zenoh router (rmw_zenohd's role, the ROS master's in ROS 1)."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from typing import Any

import zenoh

from fleetslam.errors import MiddlewareError
from fleetslam.middleware.context import apply_config_overrides

log = logging.getLogger(__name__)

DEFAULT_ROUTER_LISTEN = ("tcp/[::]:7447",)


class Router:
    """A Zenoh router in this process: listens on ``listen``, multicast scouting off, gossip on.

    ``ZENOH_ROUTER_CONFIG_URI`` replaces the defaults with a file; ``ZENOH_CONFIG_OVERRIDE`` applies on top.
    """

    def __init__(
        self,
        listen: Sequence[str] = DEFAULT_ROUTER_LISTEN,
        *,
        connect: Sequence[str] = (),
        environ: Mapping[str, str] | None = None,
    ) -> None:
        environ = os.environ if environ is None else environ
        uri = environ.get("ZENOH_ROUTER_CONFIG_URI", "").strip()
        try:
            if uri:
                config = zenoh.Config.from_file(uri)
            else:
                config = zenoh.Config()
                config.insert_json5("mode", '"router"')
                config.insert_json5("scouting/multicast/enabled", "false")
                config.insert_json5("scouting/gossip/enabled", "true")
                config.insert_json5("timestamping/enabled", "true")
            config.insert_json5("listen/endpoints", json.dumps(list(listen)))
            config.insert_json5("connect/endpoints", json.dumps(list(connect)))
        except Exception as err:
            raise MiddlewareError(f"router configuration (listen {list(listen)}): {err}") from err
        overrides = environ.get("ZENOH_CONFIG_OVERRIDE", "")
        if overrides:
            apply_config_overrides(config, overrides)
        try:
            self.session = zenoh.open(config)
        except Exception as err:
            raise MiddlewareError(f"cannot start the router listening on {', '.join(listen)}: {err}") from err
        self.listen = list(listen)
        self.zid = str(self.session.info.zid())
        log.info("router %s listening on %s", self.zid, ", ".join(self.listen))

    def peers(self) -> list[str]:
        """Zenoh ids of the peers connected to this router."""
        return [str(z) for z in self.session.info.peers_zid()]

    def close(self) -> None:
        self.session.close()

    def __enter__(self) -> Router:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
