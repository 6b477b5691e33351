"""The operator's web console: a bridge from the fleet's topics to the browser, the HTTP/WebSocket server
(aiohttp, the ``station`` extra) and its access token, and the message protocol between them.

Names are loaded on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.station.access import ConsoleAccess
    from fleetslam.station.bridge import AgentView, StationBridge
    from fleetslam.station.protocol import TeleopGate, TeleopLimits, VoxelDiff
    from fleetslam.station.server import StationServer

__all__ = ["AgentView", "ConsoleAccess", "StationBridge", "StationServer", "TeleopGate", "TeleopLimits", "VoxelDiff"]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "access": ["ConsoleAccess"],
            "bridge": ["AgentView", "StationBridge"],
            "protocol": ["TeleopGate", "TeleopLimits", "VoxelDiff"],
            "server": ["StationServer"],
        },
    )
