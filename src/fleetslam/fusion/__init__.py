"""Multi-agent fusion: what agents exchange (keyframe summaries, graph deltas), inter-agent place recognition and
the consistency of inter-agent closures, alignment of the agents' map frames, and the fleet's global occupancy map,
plus the fleet map node.

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
    from fleetslam.fusion.place_recognition import PeerPlaceRecognizer, make_peer_recognizer

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
    "PeerPlaceRecognizer",
    "estimate_agent_transform",
    "make_peer_recognizer",
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
            "place_recognition": ["PeerPlaceRecognizer", "make_peer_recognizer"],
            "fleet_map": ["FleetMap"],
            "node": ["FleetMapConfig", "FleetMapNode"],
        },
    )
