"""Map files as a whole: what `fleetslam map info | convert | compare` report about OctoMap ``.bt`` / ``.ot`` files."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.errors import ConfigError, MapFileError

log = logging.getLogger(__name__)


def output_kind(path: Path) -> str:
    """``"bt"`` or ``"ot"`` from a map file's suffix; ConfigError naming the file for any other suffix."""
    suffix = path.suffix.lower()
    if suffix not in (".bt", ".ot"):
        raise ConfigError(f"{path}: the output must end in .bt or .ot, not '{suffix}'")
    return suffix[1:]


def map_info(path: Path) -> dict[str, Any]:
    """Kind, tree type, resolution, node and leaf counts, bounds, volumes and memory of a map file."""
    from fleetslam.mapping.keys import TREE_DEPTH, TREE_MAX_VAL
    from fleetslam.mapping.octomap_io import read_octree_file

    tree = read_octree_file(path)
    leaves = tree.leaves
    occupied = int(np.count_nonzero(leaves.log_odds >= 0.0))
    info: dict[str, Any] = {
        "file": str(path),
        "kind": tree.kind,
        "tree_type": tree.tree_id,
        "resolution": tree.resolution,
        "nodes": tree.num_nodes,
        "leaves": len(leaves),
        "occupied_leaves": occupied,
        "free_leaves": len(leaves) - occupied,
    }
    if len(leaves):
        size = np.power(2.0, TREE_DEPTH - leaves.depths.astype(np.float64))[:, None]
        lo = (leaves.keys.astype(np.float64) - TREE_MAX_VAL) * tree.resolution
        volume = size[:, 0] ** 3 * tree.resolution**3
        info["bbox_min"] = [round(float(v), 6) for v in lo.min(axis=0)]
        info["bbox_max"] = [round(float(v), 6) for v in (lo + size * tree.resolution).max(axis=0)]
        info["occupied_volume_m3"] = float(volume[leaves.log_odds >= 0.0].sum())
        info["free_volume_m3"] = float(volume[leaves.log_odds < 0.0].sum())
    inner = tree.num_nodes - len(leaves)
    # OctoMap's OcTree::memoryUsage(): the tree object, 16 bytes per node, 8 child pointers per inner node.
    info["octomap_memory_bytes"] = 320 + 16 * tree.num_nodes + 64 * inner
    info["file_bytes"] = path.stat().st_size
    return info


@dataclass(frozen=True)
class Conversion:
    """What :func:`convert_map` did."""

    input_kind: str
    output_kind: str
    nodes: int
    """Nodes written."""


def convert_map(source: Path, output: Path) -> Conversion:
    """Convert a map file between ``.bt`` and ``.ot`` (by the output's suffix)."""
    from fleetslam.mapping.octomap_io import read_octree_file, write_bt, write_ot

    kind = output_kind(output)
    tree = read_octree_file(source)
    if kind == "bt":
        written = write_bt(output, tree.resolution, tree.leaves)
    else:
        if tree.kind == "bt":
            log.info("%s holds only max-likelihood states; the .ot file gets clamped log-odds", source)
        written = write_ot(output, tree.resolution, tree.leaves)
    return Conversion(tree.kind, kind, written)


def map_compare(path_a: Path, path_b: Path) -> dict[str, Any]:
    """Volumes per state pair of two maps of the same resolution, and their agreement."""
    from fleetslam.mapping.octomap_io import read_octree_file
    from fleetslam.mapping.products import STATE_NAMES, state_confusion

    a, b = read_octree_file(path_a), read_octree_file(path_b)
    if abs(a.resolution - b.resolution) > 1e-12:
        raise MapFileError(f"{path_b}: resolution {b.resolution} differs from {path_a}'s {a.resolution}")
    confusion = state_confusion(a.leaves, b.leaves)
    voxel = a.resolution**3
    known = confusion.sum() - confusion[0, 0]
    agree = confusion[1, 1] + confusion[2, 2]
    return {
        "a": str(path_a),
        "b": str(path_b),
        "resolution": a.resolution,
        "volume_m3": {
            f"{STATE_NAMES[i]}/{STATE_NAMES[j]}": float(confusion[i, j] * voxel)
            for i in range(3)
            for j in range(3)
            if (i, j) != (0, 0)
        },
        "agreement": float(agree / known) if known else 1.0,
        "occupied_iou": float(
            confusion[2, 2] / max(confusion[2, :].sum() + confusion[:, 2].sum() - confusion[2, 2], 1)
        ),
    }
