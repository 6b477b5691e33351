"""The octree's public API: bad input, queries, edits, copies, change sets, files."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from fleetslam.config import load_config
from fleetslam.errors import ConfigError
from fleetslam.mapping.config import MappingConfig, make_octree
from fleetslam.mapping.keys import coords_to_keys, pack
from fleetslam.mapping.leaves import LeafArrays
from fleetslam.mapping.octree import OccupancyOctree, _expand_to_finest

DATA = Path(__file__).parents[2] / ".." / "shared" / "data" / "octomap"


def wall_scan(x: float = 1.0, step: float = 0.02) -> np.ndarray:
    ys, zs = np.meshgrid(np.arange(-0.5, 0.5, step), np.arange(-0.5, 0.5, step))
    return np.stack([np.full(ys.size, x), ys.ravel(), zs.ravel()], axis=1).astype(np.float32)


def test_bad_points_are_skipped_and_counted_once(caplog: pytest.LogCaptureFixture) -> None:
    tree = OccupancyOctree(0.1)
    pts = np.array([[1, 0, 0], [np.nan, 0, 0], [0, np.inf, 0], [1e6, 0, 0], [-1e6, 0, 0], [0, 1, 0]], np.float32)
    with caplog.at_level(logging.INFO, logger="fleetslam.mapping.octree"):
        summary = tree.insert_point_cloud(pts, np.zeros(3))
    assert (summary.points, summary.used) == (6, 2)
    assert (summary.skipped_nonfinite, summary.skipped_out_of_range) == (2, 2)
    assert summary.occupied_voxels == 2
    assert len([r for r in caplog.records if "skipped" in r.getMessage()]) == 1
    assert tree.is_occupied(np.array([1.0, 0.0, 0.0]))


def test_log_odds_queries_single_and_many() -> None:
    tree = OccupancyOctree(0.1)
    tree.insert_point_cloud(wall_scan(), np.zeros(3))
    assert tree.log_odds(np.array([5.0, 5.0, 5.0])) is None
    hit = tree.log_odds(np.array([1.0, 0.0, 0.0]))
    assert hit == pytest.approx(float(np.float32(np.log(0.7 / 0.3))))
    many = tree.log_odds(np.array([[1.0, 0.0, 0.0], [0.5, 0.0, 0.0], [5.0, 5.0, 5.0]]))
    assert isinstance(many, np.ndarray)
    assert many[0] > 0 and many[1] < 0 and np.isnan(many[2])
    occupied = tree.is_occupied(np.array([[1.0, 0.0, 0.0], [0.5, 0.0, 0.0], [5.0, 5.0, 5.0]]))
    assert list(occupied) == [True, False, False]  # type: ignore[arg-type]


def test_centres_split_occupied_and_free() -> None:
    tree = OccupancyOctree(0.1)
    tree.insert_point_cloud(wall_scan(), np.zeros(3))
    occ, occ_sizes = tree.occupied_centers()
    free, free_sizes = tree.free_centers()
    assert len(occ) + len(free) == tree.num_leaf_nodes()
    assert np.allclose(occ[:, 0], 1.05) and np.all(occ_sizes == pytest.approx(0.1))
    assert free[:, 0].max() < 1.1 and len(free_sizes) == len(free)  # oblique rays clip the wall layer
    lo, hi = tree.metric_bounds()
    assert lo[0] == pytest.approx(0.0) and hi[0] == pytest.approx(1.1)


def test_pop_changes_reports_touched_voxels_once() -> None:
    tree = OccupancyOctree(0.1)
    tree.insert_point_cloud(np.array([[0.55, 0.05, 0.05]], np.float32), np.array([0.05, 0.05, 0.05]))
    changed = tree.pop_changes()
    assert len(changed) == 6  # 5 free + 1 occupied
    assert len(tree.pop_changes()) == 0


def test_prune_copy_and_max_likelihood_keep_the_tree() -> None:
    tree = OccupancyOctree(0.1)
    for _ in range(10):
        tree.insert_point_cloud(wall_scan(), np.zeros(3))
    nodes, leaves = tree.num_nodes(), tree.leaves()
    copy = tree.copy()
    tree.prune()
    assert tree.num_nodes() == nodes
    assert np.array_equal(tree.leaves().keys, leaves.keys)
    ml = tree.to_max_likelihood()
    assert set(np.unique(ml.leaves().log_odds)) <= {ml.clamp_min_log, ml.clamp_max_log}
    assert np.array_equal(tree.leaves().log_odds, leaves.log_odds)
    copy.insert_point_cloud(wall_scan(2.0), np.zeros(3))
    assert tree.num_nodes() == nodes and copy.num_nodes() != nodes
    rebuilt = OccupancyOctree.from_leaves(0.1, tree.leaves())
    assert rebuilt.num_nodes() == nodes


def test_clear_bbox_sets_clamp_min() -> None:
    tree = OccupancyOctree(0.1)
    tree.insert_point_cloud(wall_scan(), np.zeros(3))
    cleared = tree.clear_bbox(np.array([0.9, -0.2, -0.2]), np.array([1.2, 0.2, 0.2]))
    assert cleared > 0
    assert tree.log_odds(np.array([1.0, 0.0, 0.0])) == pytest.approx(float(tree.clamp_min_log))
    assert tree.is_occupied(np.array([1.0, 0.4, 0.4]))


def test_merge_adds_log_odds_and_moves_by_transform() -> None:
    a, b = OccupancyOctree(0.1), OccupancyOctree(0.1)
    a.insert_point_cloud(wall_scan(), np.zeros(3))
    b.insert_point_cloud(wall_scan(), np.zeros(3))
    a.merge(b)
    hit = float(np.float32(np.log(0.7 / 0.3)))
    # float32 log-odds: hit + hit is exact (measured equal); 1e-5 ≈ 80 ulp at 1.7, far below one hit (0.85)
    assert a.log_odds(np.array([1.0, 0.0, 0.0])) == pytest.approx(2 * hit, abs=1e-5)
    moved = OccupancyOctree(0.1)
    shift = np.eye(4)
    shift[:3, 3] = [0.0, 0.0, 3.0]
    moved.merge(b, shift)
    assert moved.log_odds(np.array([1.0, 0.0, 3.0])) == pytest.approx(hit, abs=1e-6)  # moved, not summed: exact
    assert moved.log_odds(np.array([1.0, 0.0, 0.0])) is None
    with pytest.raises(ValueError):
        moved.merge(OccupancyOctree(0.2))


def test_config_and_factory(tmp_path: Path) -> None:
    path = tmp_path / "mapping.yaml"
    path.write_text("resolution: 0.1\nclamp_min: 0.12\nclamp_max: 0.97\n")
    config = load_config(MappingConfig, path)
    tree = make_octree(config)
    assert tree.resolution == 0.1 and tree.clamp_min == 0.12
    path.write_text("clamp_min: 0.6\n")
    with pytest.raises(ConfigError):
        load_config(MappingConfig, path)


def test_empty_tree() -> None:
    tree = OccupancyOctree(0.05)
    assert tree.num_nodes() == 0 and tree.num_leaf_nodes() == 0
    assert len(tree.leaves()) == 0 and isinstance(tree.leaves(), LeafArrays)
    summary = tree.insert_point_cloud(np.zeros((0, 3)), np.zeros(3))
    assert summary.used == 0 and tree.num_nodes() == 0


def test_files_round_trip_through_octomap(tmp_path: Path) -> None:
    octomap = pytest.importorskip("octomap")
    tree = OccupancyOctree(0.1)
    for x in (1.0, 1.5):
        tree.insert_point_cloud(wall_scan(x), np.zeros(3))
    full = tmp_path / "map.ot"
    tree.write(full)
    back = OccupancyOctree.read(full)
    assert back.num_nodes() == tree.num_nodes()
    assert np.array_equal(back.leaves().log_odds, tree.leaves().log_odds)
    binary = tmp_path / "map.bt"
    tree.write_binary(binary)
    theirs = octomap.OcTree(0.1)
    assert theirs.readBinary(str(binary).encode())
    assert theirs.size() == OccupancyOctree.read(binary).num_nodes()


@pytest.mark.skipif(not (DATA / "geb079.bt").exists(), reason="shared OctoMap data (../shared/data/octomap) absent")
def test_updates_into_a_coarse_tree_read_from_file() -> None:
    octomap = pytest.importorskip("octomap")
    ours = OccupancyOctree.read(DATA / "geb079.bt")
    theirs = octomap.OcTree(0.1)
    theirs.readBinary(str(DATA / "geb079.bt").encode())
    assert ours.num_nodes() == theirs.size() == 532566
    rng = np.random.default_rng(0)
    points = rng.uniform(-3, 3, size=(200, 3)).astype(np.float32)
    ours.insert_point_cloud(points, np.zeros(3))
    theirs.insertPointCloud(points.astype(np.float64), np.zeros(3))
    assert ours.num_nodes() == theirs.size()
    assert ours.num_leaf_nodes() == theirs.getNumLeafNodes()


def test_max_likelihood_in_place_and_changed_keys() -> None:
    tree = OccupancyOctree(0.1)
    tree.insert_point_cloud(wall_scan(), np.zeros(3))
    keys = tree.pop_changed_keys()
    assert keys.dtype == np.uint16 and len(keys) > 0 and len(tree.pop_changed_keys()) == 0
    before = tree.num_nodes()
    same = tree.to_max_likelihood(in_place=True)
    assert same is tree
    assert set(np.unique(tree.leaves().log_odds)) <= {tree.clamp_min_log, tree.clamp_max_log}
    assert tree.num_nodes() <= before


def _scan(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A scan of a room's walls (x = ±2, y = ±2) from a random origin near its centre."""
    rng = np.random.default_rng(seed)
    origin = np.array([*rng.uniform(-0.5, 0.5, 2), 0.5])
    angles = rng.uniform(0, 2 * np.pi, 600)
    heights = rng.uniform(0.0, 1.2, 600)
    direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    # Distance to the square's boundary along each direction.
    t = np.min(np.where(np.abs(direction) > 1e-9, (2.0 - np.sign(direction) * origin[:2]) / np.abs(direction), 1e9),
               axis=1)  # fmt: skip
    points = np.column_stack([origin[:2] + direction * t[:, None], heights]).astype(np.float32)
    return points, origin


def _same_voxels(a: OccupancyOctree, b: OccupancyOctree) -> None:
    """The same finest voxels known, with the same values up to float32 rounding (sums taken in another order:
    then the canonical pruning, which needs equal values, may differ)."""
    keys_a, values_a = _expand_to_finest(a.leaves())
    keys_b, values_b = _expand_to_finest(b.leaves())
    order_a, order_b = np.lexsort(keys_a.T), np.lexsort(keys_b.T)
    np.testing.assert_array_equal(keys_a[order_a], keys_b[order_b])
    np.testing.assert_allclose(values_a[order_a], values_b[order_b], atol=1e-5)


def test_computed_updates_applied_are_an_insertion_and_forgetting_makes_voxels_unknown() -> None:
    scans = [_scan(seed) for seed in range(3)]
    tree, reference = OccupancyOctree(0.1, track_changes=False), OccupancyOctree(0.1)
    seen = []
    for points, origin in scans:
        free, occupied = tree.compute_update(points, origin)
        assert len(np.intersect1d(free, occupied)) == 0  # occupied wins
        seen.append(np.concatenate([free, occupied]))
        tree.apply_update(free, occupied)
        reference.insert_point_cloud(points, origin)
    _same_voxels(tree, reference)
    np.testing.assert_array_equal(tree.voxel_log_odds(seen[0]), reference.voxel_log_odds(seen[0]))
    only_last = np.setdiff1d(seen[2], np.concatenate(seen[:2]))
    assert tree.forget(only_last) == len(only_last) > 0
    assert np.isnan(tree.voxel_log_odds(only_last)).all()
    assert not np.isnan(tree.voxel_log_odds(seen[0])).any()
    assert tree.pop_changed_keys().shape == (0, 3)  # not tracked


def test_assign_sets_clamped_values_and_nan_forgets() -> None:
    tree = OccupancyOctree(0.1)
    tree.insert_point_cloud(wall_scan(), np.zeros(3))
    tree.pop_changed_keys()
    centres = np.array([[3.05, 0.05, 0.05], [3.15, 0.05, 0.05], [3.25, 0.05, 0.05]])  # nobody saw them
    keys, _ = coords_to_keys(centres, 0.1)
    packed = pack(keys)
    tree.assign(packed, np.array([10.0, -0.5, np.nan]))
    assert tree.log_odds(centres[0]) == pytest.approx(float(tree.clamp_max_log))  # clamped
    assert tree.log_odds(centres[1]) == pytest.approx(-0.5)
    assert tree.log_odds(centres[2]) is None
    assert len(tree.pop_changed_keys()) == 2  # the unknown one stayed unknown
    tree.assign(packed[1:2], np.array([np.nan]))
    assert tree.log_odds(centres[1]) is None
    np.testing.assert_array_equal(tree.pop_changed_keys(), keys[1:2])


def test_forget_splits_a_pruned_leaf() -> None:
    tree = OccupancyOctree(0.1)
    for _ in range(6):  # saturate a block of free voxels so that it prunes
        tree.insert_point_cloud(wall_scan(x=1.6, step=0.01), np.zeros(3))
    tree.prune()
    leaves = tree.leaves()
    coarse = np.flatnonzero(leaves.depths < 16)
    assert len(coarse) > 0
    i = int(coarse[0])
    key = leaves.keys[i].astype(np.uint64)
    packed = np.array([(int(key[0]) << 32) | (int(key[1]) << 16) | int(key[2])], np.uint64)
    value = float(leaves.log_odds[i])
    assert tree.forget(packed) == 1
    centre = (leaves.keys[i].astype(np.float64) - 32768 + 0.5) * 0.1
    assert tree.log_odds(centre) is None  # the voxel is unknown again
    assert tree.log_odds(centre + np.array([0.1, 0.0, 0.0])) == pytest.approx(
        value
    )  # its siblings keep the leaf's value
