"""Multi-agent fusion: what agents exchange (keyframe summaries, graph deltas), the consistency of inter-agent
closures, alignment of the agents' map frames, the fleet back-end's joint optimisation and the fleet's global
occupancy map, plus their nodes.

Names are loaded on first use; numba (the ``mapping`` extra) only when the fleet map is.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.fusion.alignment import rigid_fit
    from fleetslam.fusion.collaboration import CollaborationConfig, InterAgentLinker
    from fleetslam.fusion.consistency import ClosureSet, PairClosure
    from fleetslam.fusion.fleet_graph import AgentPlacement, ClosureReport, FleetClosure, FleetGraph, FleetSolution
    from fleetslam.fusion.fleet_graph_node import FleetGraphConfig, FleetGraphNode
    from fleetslam.fusion.fleet_map import FleetMap
    from fleetslam.fusion.graph_exchange import GraphDeltaWriter, GraphMirror, GraphUpdate
    from fleetslam.fusion.keyframe_summary import KeyframeSummary, summarize
    from fleetslam.fusion.node import FleetMapConfig, FleetMapNode

__all__ = [
    "AgentPlacement",
    "ClosureReport",
    "ClosureSet",
    "CollaborationConfig",
    "FleetClosure",
    "FleetGraph",
    "FleetGraphConfig",
    "FleetGraphNode",
    "FleetMap",
    "FleetMapConfig",
    "FleetMapNode",
    "FleetSolution",
    "GraphDeltaWriter",
    "GraphMirror",
    "GraphUpdate",
    "InterAgentLinker",
    "KeyframeSummary",
    "PairClosure",
    "rigid_fit",
    "summarize",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "alignment": ["rigid_fit"],
            "collaboration": ["CollaborationConfig", "InterAgentLinker"],
            "consistency": ["ClosureSet", "PairClosure"],
            "graph_exchange": ["GraphDeltaWriter", "GraphMirror", "GraphUpdate"],
            "keyframe_summary": ["KeyframeSummary", "summarize"],
            "fleet_graph": ["AgentPlacement", "ClosureReport", "FleetClosure", "FleetGraph", "FleetSolution"],
            "fleet_graph_node": ["FleetGraphConfig", "FleetGraphNode"],
            "fleet_map": ["FleetMap"],
            "node": ["FleetMapConfig", "FleetMapNode"],
        },
    )
