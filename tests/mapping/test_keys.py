"""Coordinate ↔ key conversion and Morton (pre-order) codes, checked against OctoMap's coordToKey."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.mapping.keys import (
    TREE_MAX_VAL,
    coords_to_keys,
    keys_to_coords,
    morton,
    node_centers,
    pack,
    unmorton,
    unpack,
)

octomap = pytest.importorskip("octomap")


@pytest.mark.parametrize("res", [0.05, 0.1, 0.2, 0.01])
def test_keys_match_octomap_including_voxel_borders(res: float) -> None:
    rng = np.random.default_rng(1)
    tree = octomap.OcTree(res)
    borders = (np.arange(-40, 40) * res)[:, None].repeat(3, axis=1)
    coords = np.concatenate([rng.uniform(-5, 5, size=(300, 3)), borders, [[-0.05, -0.05, -0.05]]]).astype(np.float32)
    keys, valid = coords_to_keys(coords, res)
    assert valid.all()
    for c, k in zip(coords, keys, strict=True):
        expected = tree.coordToKey(c.astype(np.float64))
        assert (int(expected[0]), int(expected[1]), int(expected[2])) == tuple(int(v) for v in k)


def test_float64_arithmetic_on_float32_coordinate() -> None:
    keys, _ = coords_to_keys(np.array([-0.05, 0.05, 0.0]), 0.05)
    # float32(-0.05) is slightly below -0.05: in float64 it falls into the second voxel below zero
    # (float32 arithmetic would give −1 exactly, one voxel off).
    assert keys[0].tolist() == [TREE_MAX_VAL - 2, TREE_MAX_VAL + 1, TREE_MAX_VAL]


def test_invalid_coordinates_are_flagged() -> None:
    res = 0.1
    limit = TREE_MAX_VAL * res
    _, valid = coords_to_keys(
        np.array([[np.nan, 0, 0], [np.inf, 0, 0], [limit, 0, 0], [-limit + 0.2, 0, 0], [limit - 0.2, 0, 0]]), res
    )
    assert valid.tolist() == [False, False, False, True, True]


def test_centres_and_packing_round_trip() -> None:
    rng = np.random.default_rng(4)
    keys = rng.integers(0, 65536, size=(500, 3)).astype(np.uint16)
    assert (unpack(pack(keys)) == keys).all()
    assert (unmorton(morton(keys)) == keys).all()
    centres = keys_to_coords(keys, 0.05)
    back, valid = coords_to_keys(centres, 0.05)
    assert valid.all() and (back == keys).all()
    assert np.allclose(node_centers(keys, np.full(500, 16), 0.05), centres)


def test_morton_order_is_octomap_child_order() -> None:
    # Child index at each level: x adds 1, y adds 2, z adds 4; the top level is the most significant.
    top_x = np.array([[1 << 15, 0, 0]], np.uint16)
    top_y = np.array([[0, 1 << 15, 0]], np.uint16)
    all_low = np.array([[(1 << 15) - 1] * 3], np.uint16)
    assert morton(top_x)[0] == 1 << 45
    assert morton(top_y)[0] == 2 << 45
    assert morton(all_low)[0] < morton(top_x)[0] < morton(top_y)[0]


def test_morton_kernel_matches_morton() -> None:
    from fleetslam.mapping._prune_kernels import morton_keys, unmorton_keys

    keys = np.random.default_rng(3).integers(0, 1 << 16, (5000, 3)).astype(np.uint16)
    codes = morton_keys(keys)
    np.testing.assert_array_equal(codes, morton(keys))
    np.testing.assert_array_equal(unmorton_keys(codes), keys)
