"""Single-ray keys and castRay against OctoMap."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.mapping.keys import TREE_MAX_VAL, unpack
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.mapping.raycast import ray_keys, scan_keys

octomap = pytest.importorskip("octomap")


def octomap_free_keys(origin: np.ndarray, end: np.ndarray, res: float) -> set[tuple[int, int, int]]:
    """computeRayKeys as seen through one insert into an empty tree (the binding does not expose it)."""
    tree = octomap.OcTree(res)
    tree.insertPointCloud(end[None].astype(np.float64), origin.astype(np.float64))
    end_key = tree.coordToKey(end.astype(np.float64))
    out = set()
    for leaf in tree.begin_leafs():
        key = leaf.getKey()
        k = (int(key[0]), int(key[1]), int(key[2]))
        if k != (int(end_key[0]), int(end_key[1]), int(end_key[2])):
            out.add(k)
    return out


def test_single_rays_match_octomap() -> None:
    rng = np.random.default_rng(9)
    res = 0.05
    cases = [
        (np.zeros(3), np.array([1.0, 0.0, 0.0])),
        (np.zeros(3), np.array([-1.0, -1.0, -1.0])),
        (np.zeros(3), np.array([0.0, 0.0, 0.02])),  # same voxel: empty ray
        (np.array([0.025, 0.025, 0.025]), np.array([0.525, -0.475, 0.025])),
        (np.array([-0.05, -0.05, -0.05]), np.array([0.3, 0.2, -0.1])),
    ]
    for _ in range(40):
        cases.append((rng.uniform(-0.5, 0.5, 3), rng.uniform(-3, 3, 3)))
    for origin, end in cases:
        o, e = origin.astype(np.float32), end.astype(np.float32)
        ours = {tuple(int(v) for v in k) for k in ray_keys(o, e, res)}
        assert ours == octomap_free_keys(o, e, res)
        assert len(ours) == len(ray_keys(o, e, res))  # each key once along one ray


def test_batch_walk_matches_octomap_on_ties() -> None:
    """Diagonal and axis-aligned rays, from voxel corners and borders: ties between the axes' tMax decide which
    cells a ray crosses, and long rays take the batch walk's branch-free slabs, whose tie rules must be
    OctoMap's. Each ray alone, so that no other ray covers a wrongly chosen cell."""
    res = 0.05
    steps = (-1.0, -0.5, 0.0, 0.5, 1.0)
    directions = np.array([(x, y, z) for x in steps for y in steps for z in steps if (x, y, z) != (0, 0, 0)])
    origins = [np.zeros(3), np.full(3, 0.025), np.array([0.05, -0.1, 0.15]), np.array([-0.3, 0.2, 0.011])]
    mismatches = []
    for origin in origins:
        for end in (origin + directions * 1.3).astype(np.float32):
            free, _, _ = scan_keys(end[None], origin.astype(np.float32), res, -1.0)
            ours = {tuple(int(v) for v in k) for k in unpack(free)}
            if ours != octomap_free_keys(origin.astype(np.float32), end, res):
                mismatches.append((origin.tolist(), end.tolist()))
    assert not mismatches, f"{len(mismatches)} rays differ, e.g. {mismatches[:3]}"


def test_ray_with_out_of_range_end_is_empty() -> None:
    assert len(ray_keys(np.zeros(3), np.array([TREE_MAX_VAL * 0.05 + 1, 0, 0]), 0.05)) == 0


def test_cast_ray_matches_octomap() -> None:
    rng = np.random.default_rng(12)
    res = 0.1
    ours, theirs = OccupancyOctree(res), octomap.OcTree(res)
    ys, zs = np.meshgrid(np.arange(-1.5, 1.5, 0.03), np.arange(-1.0, 1.0, 0.03))
    wall = np.stack([np.full(ys.size, 2.0), ys.ravel(), zs.ravel()], axis=1).astype(np.float32)
    ours.insert_point_cloud(wall, np.zeros(3))
    theirs.insertPointCloud(wall.astype(np.float64), np.zeros(3))
    hits = 0
    for _ in range(60):
        origin = rng.uniform(-0.3, 0.3, 3).astype(np.float32)
        direction = np.array([1.0, *rng.uniform(-0.6, 0.6, 2)], np.float32)
        for ignore_unknown, max_range in ((False, -1.0), (True, 3.0), (False, 1.0)):
            end = np.zeros(3)
            hit = theirs.castRay(
                origin.astype(np.float64), direction.astype(np.float64), end,
                ignoreUnknownCells=ignore_unknown, maxRange=max_range,
            )  # fmt: skip
            got = ours.cast_ray(origin, direction, max_range=max_range, ignore_unknown=ignore_unknown)
            if hit:
                hits += 1
                assert got is not None and np.allclose(got, end, atol=1e-6)  # both: float64 voxel centres
            else:
                assert got is None
    assert hits > 20
