"""The engine against OctoMap 1.10 itself (octomap-python): same nodes, same leaves, same log-odds."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from fleetslam.mapping.octree import OccupancyOctree

octomap = pytest.importorskip("octomap")


def octomap_leaves(tree: object) -> dict[tuple[int, int, int, int], float]:
    leaves = {}
    for leaf in tree.begin_leafs():  # type: ignore[attr-defined]
        key = leaf.getIndexKey()
        leaves[(int(key[0]), int(key[1]), int(key[2]), int(leaf.getDepth()))] = float(leaf.getValue())
    return leaves


def our_leaves(tree: OccupancyOctree) -> dict[tuple[int, int, int, int], float]:
    leaves = tree.leaves()
    return {
        (int(k[0]), int(k[1]), int(k[2]), int(d)): float(v)
        for k, d, v in zip(leaves.keys, leaves.depths, leaves.log_odds, strict=True)
    }


def assert_same(ours: OccupancyOctree, theirs: object) -> None:
    expected = octomap_leaves(theirs)
    got = our_leaves(ours)
    missing = set(expected) - set(got)
    extra = set(got) - set(expected)
    assert not missing and not extra, (
        f"{len(missing)} leaves missing, {len(extra)} extra: {sorted(missing)[:3]} {sorted(extra)[:3]}"
    )
    worst = max((abs(expected[k] - got[k]) for k in expected), default=0.0)
    # Both add float32 log-odds in the same order (0.0 measured); 1e-6 is 4 ulp at the clamp 3.5.
    assert worst <= 1e-6
    assert ours.num_leaf_nodes() == theirs.getNumLeafNodes()  # type: ignore[attr-defined]
    assert ours.num_nodes() == theirs.size()  # type: ignore[attr-defined]


def insert_both(
    ours: OccupancyOctree, theirs: object, points: NDArray[np.floating], origin: NDArray[np.floating], **kwargs: object
) -> None:
    pts32 = np.asarray(points, dtype=np.float32)
    origin32 = np.asarray(origin, dtype=np.float32)
    ours.insert_point_cloud(pts32, origin32, **kwargs)  # type: ignore[arg-type]
    oct_kwargs = {"maxrange": kwargs.get("max_range", -1.0), "discretize": kwargs.get("discretize", False)}
    theirs.insertPointCloud(pts32.astype(np.float64), origin32.astype(np.float64), **oct_kwargs)  # type: ignore[attr-defined]


def random_scan(rng: np.random.Generator, n: int, res: float) -> NDArray[np.float32]:
    """Points on a noisy sphere shell plus points exactly on voxel boundaries and negative coordinates."""
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ranges = rng.uniform(0.3, 2.0, size=(n, 1))
    pts = directions * ranges
    boundary = np.round(pts[: n // 4] / res) * res  # exactly on voxel borders
    return np.concatenate([pts, boundary, [[-0.05, -0.05, -0.05], [0.05, -0.05, 0.0]]]).astype(np.float32)


@pytest.mark.parametrize("res", [0.05, 0.1])
def test_several_scans_match_octomap(res: float) -> None:
    rng = np.random.default_rng(7)
    ours, theirs = OccupancyOctree(res), octomap.OcTree(res)
    for scan in range(6):
        origin = rng.uniform(-0.2, 0.2, 3) if scan % 2 else np.zeros(3)
        insert_both(ours, theirs, random_scan(rng, 400, res), origin)
    assert_same(ours, theirs)


def test_repeated_scan_clamps_and_prunes_like_octomap() -> None:
    res = 0.1
    # A dense wall seen many times: free space clamps and collapses into coarse leaves.
    ys, zs = np.meshgrid(np.arange(-0.8, 0.8, 0.02), np.arange(-0.8, 0.8, 0.02))
    wall = np.stack([np.full(ys.size, 1.6), ys.ravel(), zs.ravel()], axis=1)
    ours, theirs = OccupancyOctree(res), octomap.OcTree(res)
    for _ in range(12):
        insert_both(ours, theirs, wall, np.zeros(3))
    assert_same(ours, theirs)
    assert (ours.leaves().depths < 16).any(), "expected pruned leaves"
    # Updates into pruned leaves expand them as OctoMap does.
    rng = np.random.default_rng(3)
    insert_both(ours, theirs, random_scan(rng, 300, res), np.array([0.05, -0.1, 0.2]))
    assert_same(ours, theirs)


def test_axis_and_diagonal_rays_match_octomap() -> None:
    res = 0.05
    ours, theirs = OccupancyOctree(res), octomap.OcTree(res)
    pts = []
    for sign in (1, -1):
        for axis in np.eye(3):
            pts.append(sign * axis * 1.0)
        pts.append(sign * np.array([1.0, 1.0, 1.0]))
        pts.append(sign * np.array([1.0, -1.0, 0.0]))
        pts.append(sign * np.array([0.5, 0.5, 0.0]))
    # Single rays from an origin on a voxel corner.
    for point in pts:
        one_ours, one_theirs = OccupancyOctree(res), octomap.OcTree(res)
        insert_both(one_ours, one_theirs, np.array([point]), np.zeros(3))
        assert_same(one_ours, one_theirs)
    insert_both(ours, theirs, np.array(pts), np.array([0.025, 0.025, 0.025]))
    assert_same(ours, theirs)


def test_max_range_and_discretize_match_octomap() -> None:
    rng = np.random.default_rng(11)
    for discretize in (False, True):
        ours, theirs = OccupancyOctree(0.05), octomap.OcTree(0.05)
        for _ in range(3):
            insert_both(ours, theirs, random_scan(rng, 300, 0.05), np.zeros(3), max_range=1.2, discretize=discretize)
        assert_same(ours, theirs)


def test_custom_sensor_model_matches_octomap() -> None:
    rng = np.random.default_rng(5)
    ours = OccupancyOctree(0.1, prob_hit=0.8, prob_miss=0.3, clamp_min=0.12, clamp_max=0.97)
    theirs = octomap.OcTree(0.1)
    theirs.setProbHit(0.8)
    theirs.setProbMiss(0.3)
    theirs.setClampingThresMin(0.12)
    theirs.setClampingThresMax(0.97)
    for _ in range(5):
        insert_both(ours, theirs, random_scan(rng, 300, 0.1), np.zeros(3))
    assert_same(ours, theirs)


def test_queries_match_octomap() -> None:
    rng = np.random.default_rng(2)
    ours, theirs = OccupancyOctree(0.1), octomap.OcTree(0.1)
    for _ in range(4):
        insert_both(ours, theirs, random_scan(rng, 300, 0.1), np.zeros(3))
    probes = rng.uniform(-2.2, 2.2, size=(300, 3))
    values = ours.log_odds(probes)
    assert isinstance(values, np.ndarray)
    for probe, value in zip(probes, values, strict=True):
        node = theirs.search(probe)
        try:
            expected = node.getLogOdds()
        except octomap.NullPointerException:
            expected = None
        if expected is None:
            assert np.isnan(value)
        else:
            assert value == pytest.approx(expected, abs=1e-6)  # the same float32 sums, as above
            assert ours.is_occupied(probe) == theirs.isNodeOccupied(node)


def test_sorting_fallback_for_huge_scans_matches_octomap(monkeypatch: pytest.MonkeyPatch) -> None:
    from fleetslam.mapping import raycast

    monkeypatch.setattr(raycast, "MAX_GRID_CELLS", 1000)
    rng = np.random.default_rng(21)
    ours, theirs = OccupancyOctree(0.05), octomap.OcTree(0.05)
    for _ in range(3):
        insert_both(ours, theirs, random_scan(rng, 300, 0.05), np.zeros(3), max_range=1.5)
    assert_same(ours, theirs)
