"""The voxel table (and the octree table's deletion kernel) against a Python dict."""

from __future__ import annotations

import numpy as np

from fleetslam.mapping.voxel_table import VoxelTable


def test_table_matches_a_dict_through_growth_and_deletions() -> None:
    rng = np.random.default_rng(7)
    table = VoxelTable()
    reference: dict[int, float] = {}
    # Keys from a small range collide in long probe runs: deletions must keep every later key reachable.
    universe = np.unique(rng.integers(1, 1 << 40, 6000, dtype=np.uint64))
    for step in range(40):
        keys = np.unique(rng.choice(universe, 400))
        if step % 3 == 2:
            removed = table.delete(keys)
            assert removed == sum(int(k) in reference for k in keys)
            for k in keys.tolist():
                reference.pop(k, None)
        elif step % 3 == 1:
            table.add(keys, 1.0)
            for k in keys.tolist():
                reference[k] = float(np.float32(reference.get(k, 0.0)) + np.float32(1.0))
        else:
            values = rng.normal(size=len(keys)).astype(np.float32)
            table.set(keys, values)
            reference.update(zip(keys.tolist(), values.tolist(), strict=True))
        assert len(table) == len(reference)
        got = table.get(universe)
        want = np.array([reference.get(int(k), np.nan) for k in universe], np.float32)
        np.testing.assert_array_equal(got, want)
    keys, values = table.items()
    assert dict(zip(keys.tolist(), values.tolist(), strict=True)) == reference
    table.clear()
    assert len(table) == 0 and np.isnan(table.get(universe)).all()
