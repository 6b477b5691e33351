"""Compile the octree engine's numba kernels (and the fleet map's, and the SLAM vocabulary's) into their on-disk
cache, so that the first scan of a mapping node or keyframe of a SLAM node does not wait for the compiler (about
20 s on two cores). ``scripts/setup`` runs it:

    python -m fleetslam.mapping.warmup
"""

from __future__ import annotations

import time

import numpy as np


def compile_kernels() -> float:
    """Run every kernel a mapping node uses once, on a small scan; returns the seconds it took."""
    from fleetslam.fusion.fleet_map import FleetMap
    from fleetslam.geometry import pose_from_planar
    from fleetslam.mapping.octree import OccupancyOctree
    from fleetslam.mapping.voxel_table import VoxelTable

    start = time.perf_counter()
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(400, 3))
    points = (directions / np.linalg.norm(directions, axis=1, keepdims=True) * 2.0).astype(np.float32)
    tree = OccupancyOctree(0.05, accelerator="cpu")
    tree.insert_point_cloud(points, np.zeros(3, np.float32))  # grows the table: every insertion kernel
    tree.insert_point_cloud(points[:10], np.zeros(3, np.float32), max_range=1.0)
    tree.num_nodes()  # the canonical structure's kernels
    free, occupied = tree.compute_update(points[:50], np.zeros(3, np.float32))
    table = VoxelTable()  # a mapping node's re-integration: voxel sets, replay, assignment
    table.set(free, np.zeros(len(free), np.float32))
    tree.assign(occupied, table.get(occupied))  # absent from the table: NaN, so forgotten
    table.add(free, 1.0)
    table.delete(free[:10])
    tree.prune()
    tree.log_odds(points[0])
    fleet = FleetMap(0.05)  # the fleet map node's kernels
    fleet.set_transform("b", pose_from_planar(1.0, 2.0, 0.3))
    fleet.update_agent("b", tree)
    from fleetslam.slam._hamming_kernels import nearest2_packed  # the SLAM vocabulary's search
    from fleetslam.slam.vocabulary import pack_binary, pack_binary_by_lane

    descriptors = rng.integers(0, 256, size=(4, 32), dtype=np.uint8)
    nearest2_packed(pack_binary(descriptors), pack_binary_by_lane(descriptors))
    return time.perf_counter() - start


def main() -> None:
    print(f"mapping kernels compiled in {compile_kernels():.1f} s", flush=True)


if __name__ == "__main__":
    main()
