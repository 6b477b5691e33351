"""Multi-agent fusion: inter-agent alignment from shared loop closures and the fleet's global occupancy map,
plus the fleet map node.

Names are loaded on first use; numba (the ``mapping`` extra) only when the fleet map is.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.fusion.alignment import InterAgentClosure, estimate_agent_transform, rigid_fit
    from fleetslam.fusion.fleet_map import FleetMap
    from fleetslam.fusion.node import FleetMapConfig, FleetMapNode

__all__ = ["FleetMap", "FleetMapConfig", "FleetMapNode", "InterAgentClosure", "estimate_agent_transform", "rigid_fit"]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "alignment": ["InterAgentClosure", "estimate_agent_transform", "rigid_fit"],
            "fleet_map": ["FleetMap"],
            "node": ["FleetMapConfig", "FleetMapNode"],
        },
    )
