"""Multi-agent fusion: what agents exchange (keyframe summaries, graph deltas), the consistency of inter-agent
closures, alignment of the agents' map frames, and the fleet's global occupancy map, plus the fleet map node.

Names are loaded on first use; numba (the ``mapping`` extra) only when the fleet map is.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.fusion.alignment import InterAgentClosure, estimate_agent_transform, rigid_fit
    from fleetslam.fusion.collaboration import CollaborationConfig, InterAgentLinker
    from fleetslam.fusion.consistency import ClosureSet, PairClosure
    from fleetslam.fusion.fleet_map import FleetMap
    from fleetslam.fusion.graph_exchange import GraphDeltaWriter, GraphMirror, GraphUpdate
    from fleetslam.fusion.keyframe_summary import KeyframeSummary, summarize
    from fleetslam.fusion.node import FleetMapConfig, FleetMapNode

__all__ = [
    "ClosureSet",
    "CollaborationConfig",
    "FleetMap",
    "FleetMapConfig",
    "FleetMapNode",
    "GraphDeltaWriter",
    "GraphMirror",
    "GraphUpdate",
    "InterAgentClosure",
    "InterAgentLinker",
    "KeyframeSummary",
    "PairClosure",
    "estimate_agent_transform",
    "rigid_fit",
    "summarize",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "alignment": ["InterAgentClosure", "estimate_agent_transform", "rigid_fit"],
            "collaboration": ["CollaborationConfig", "InterAgentLinker"],
            "consistency": ["ClosureSet", "PairClosure"],
            "graph_exchange": ["GraphDeltaWriter", "GraphMirror", "GraphUpdate"],
            "keyframe_summary": ["KeyframeSummary", "summarize"],
            "fleet_map": ["FleetMap"],
            "node": ["FleetMapConfig", "FleetMapNode"],
        },
    )
