"""Authenticated fleets: a keystore of certificates and the Zenoh configs (mutual TLS, access control) that use it.

Names are loaded on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.security.keystore import host_folder, init_keystore, load_zenoh_config
    from fleetslam.security.policy import Identity, access_control, host_config, router_config

__all__ = [
    "Identity",
    "access_control",
    "host_config",
    "host_folder",
    "init_keystore",
    "load_zenoh_config",
    "router_config",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "keystore": ["host_folder", "init_keystore", "load_zenoh_config"],
            "policy": ["Identity", "access_control", "host_config", "router_config"],
        },
    )
