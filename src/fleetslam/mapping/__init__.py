"""Occupancy mapping: an octree engine with OctoMap 1.10's semantics, OctoMap file IO, scan readers, map
products (point clouds, markers, 2D grids) and the mapping node.

Names are loaded on first use: ``import fleetslam.mapping`` imports no submodule, and numba (the ``mapping``
extra) is imported only when a name that needs it is used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.mapping.config import MappingConfig, make_octree
    from fleetslam.mapping.keyframe_mapper import KeyframeMapper, depth_to_points
    from fleetslam.mapping.leaves import LeafArrays
    from fleetslam.mapping.node import MappingNode, MappingNodeConfig
    from fleetslam.mapping.octomap_io import OctreeFile, bt_bytes, read_octree_file, write_bt, write_ot
    from fleetslam.mapping.octree import InsertSummary, OccupancyOctree, logodds, probability
    from fleetslam.mapping.products import cube_list_markers, fit_ground_plane, project_occupancy_grid
    from fleetslam.mapping.rgbd_scans import open_rgbd_scans
    from fleetslam.mapping.scan_io import (
        ScanEdge,
        ScanGraph,
        ScanNode,
        load_scan_graph,
        load_scans,
        read_scan_graph,
        write_scan_graph,
    )

__all__ = [
    "InsertSummary",
    "KeyframeMapper",
    "LeafArrays",
    "MappingConfig",
    "MappingNode",
    "MappingNodeConfig",
    "OccupancyOctree",
    "OctreeFile",
    "ScanEdge",
    "ScanGraph",
    "ScanNode",
    "bt_bytes",
    "cube_list_markers",
    "depth_to_points",
    "fit_ground_plane",
    "load_scan_graph",
    "load_scans",
    "logodds",
    "make_octree",
    "open_rgbd_scans",
    "probability",
    "project_occupancy_grid",
    "read_octree_file",
    "read_scan_graph",
    "write_bt",
    "write_ot",
    "write_scan_graph",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "config": ["MappingConfig", "make_octree"],
            "octree": ["InsertSummary", "OccupancyOctree", "logodds", "probability"],
            "leaves": ["LeafArrays"],
            "keyframe_mapper": ["KeyframeMapper", "depth_to_points"],
            "octomap_io": ["OctreeFile", "bt_bytes", "read_octree_file", "write_bt", "write_ot"],
            "scan_io": [
                "ScanEdge",
                "ScanGraph",
                "ScanNode",
                "load_scan_graph",
                "load_scans",
                "read_scan_graph",
                "write_scan_graph",
            ],
            "rgbd_scans": ["open_rgbd_scans"],
            "products": ["cube_list_markers", "fit_ground_plane", "project_occupancy_grid"],
            "node": ["MappingNode", "MappingNodeConfig"],
        },
    )
