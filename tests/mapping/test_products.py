"""octomap_server-like products as arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fleetslam.mapping.products import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    cube_list_markers,
    fit_ground_plane,
    height_colormap,
    project_occupancy_grid,
)


def _hsv_reference(h: float) -> tuple[float, float, float]:
    """octomap_server heightMapColor, scalar, s = v = 1."""
    h -= math.floor(h)
    h *= 6
    i = math.floor(h)
    f = h - i
    if not (i & 1):
        f = 1 - f
    n = 1 - f
    return {0: (1, n, 0), 6: (1, n, 0), 1: (n, 1, 0), 2: (0, 1, n), 3: (0, n, 1), 4: (n, 0, 1), 5: (1, 0, n)}[i]


@pytest.mark.parametrize("z", [-1.0, 0.0, 0.1, 0.37, 0.5, 0.8, 1.0, 2.0])
def test_height_colormap_matches_octomap_server(z: float) -> None:
    rgba = height_colormap([z], 0.0, 1.0)[0]
    h = (1.0 - min(max(z, 0.0), 1.0)) * 0.8
    np.testing.assert_allclose(rgba[:3], _hsv_reference(h), atol=1e-6)  # float32 colours: ulp 6e-8 below 1
    assert rgba[3] == 1.0


def test_cube_lists_per_depth() -> None:
    centres = np.array([[0.05, 0.05, 0.05], [0.2, 0.2, 0.2], [0.15, 0.05, 0.05]])
    sizes = np.array([0.1, 0.2, 0.1])
    markers = cube_list_markers(centres, sizes, 0.1, height_range=(0.0, 1.0))
    assert [(m.depth, m.size, len(m.centres)) for m in markers] == [(15, pytest.approx(0.2), 1), (16, 0.1, 2)]
    assert markers[1].colors is not None and markers[1].colors.shape == (2, 4)
    assert cube_list_markers(centres, sizes, 0.1)[0].colors is None


def test_projection_occupied_wins_and_coarse_leaves_cover_their_footprint() -> None:
    occupied = np.array([[0.05, 0.05, 0.5]])
    free = np.array([[0.1, 0.1, 0.5], [0.35, 0.05, 0.5], [0.35, 0.05, 5.0]])
    grid, origin = project_occupancy_grid(occupied, [0.1], free, [0.2, 0.1, 0.1], 0.1, 0.0, 1.0)
    np.testing.assert_allclose(origin, [0.0, 0.0])
    assert grid.shape == (2, 4)  # rows = y, columns = x
    expected = np.array([[OCCUPIED, FREE, UNKNOWN, FREE], [FREE, FREE, UNKNOWN, UNKNOWN]], np.int8)
    np.testing.assert_array_equal(grid, expected)


def test_projection_ignores_leaves_outside_the_z_band() -> None:
    grid, _ = project_occupancy_grid([[0.05, 0.05, 3.0]], [0.1], [[0.15, 0.05, 0.5]], [0.1], 0.1, 0.0, 1.0)
    np.testing.assert_array_equal(grid, [[UNKNOWN, FREE]])


def test_ground_filter_by_height_and_by_fitted_plane() -> None:
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 2, (400, 2))
    tilt = 0.05
    floor = np.column_stack([xy, 0.1 + tilt * xy[:, 0] + rng.normal(0, 0.005, 400)])
    wall = np.column_stack([np.full(100, 1.95), rng.uniform(0, 2, 100), rng.uniform(0.2, 1.0, 100)])
    plane = fit_ground_plane(np.concatenate([floor, wall]))
    assert plane is not None
    # Slope s.e. σ/(√n·std x) ≈ 4e-4; wall points within the 4 cm inlier band bias it to 1.6e-3; 0.02 < tilt.
    np.testing.assert_allclose(plane[:3] / plane[2], [-tilt, 0, 1], atol=0.02)
    # A floor voxel and an obstacle voxel: only the obstacle projects as occupied.
    occupied = np.array([[0.05, 0.05, 0.1], [0.15, 0.05, 0.6]])
    grid, _ = project_occupancy_grid(occupied, [0.1, 0.1], np.zeros((0, 3)), [], 0.1, ground_plane=plane)
    np.testing.assert_array_equal(grid, [[FREE, OCCUPIED]])
    grid, _ = project_occupancy_grid(occupied, [0.1, 0.1], np.zeros((0, 3)), [], 0.1, ground_z=0.1)
    np.testing.assert_array_equal(grid, [[FREE, OCCUPIED]])
    grid, _ = project_occupancy_grid(occupied, [0.1, 0.1], np.zeros((0, 3)), [], 0.1)
    np.testing.assert_array_equal(grid, [[OCCUPIED, OCCUPIED]])
    assert fit_ground_plane(floor[:10]) is None


def test_empty_projection() -> None:
    grid, origin = project_occupancy_grid(np.zeros((0, 3)), [], np.zeros((0, 3)), [], 0.1)
    assert grid.shape == (0, 0) and origin.shape == (2,)


def test_state_confusion_is_exact_across_pruning() -> None:
    from fleetslam.mapping.leaves import LeafArrays
    from fleetslam.mapping.products import state_confusion

    coarse = LeafArrays(np.zeros((1, 3), np.uint16), np.array([15], np.uint8), np.array([2.0], np.float32))
    offsets = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.uint16)
    values = np.array([2.0] * 7 + [-1.0], np.float32)
    fine = LeafArrays(offsets, np.full(8, 16, np.uint8), values)
    extra = LeafArrays(np.array([[4, 0, 0]], np.uint16), np.array([16], np.uint8), np.array([-1.0], np.float32))
    both = LeafArrays(
        np.concatenate([fine.keys, extra.keys]),
        np.concatenate([fine.depths, extra.depths]),
        np.concatenate([fine.log_odds, extra.log_odds]),
    )
    confusion = state_confusion(coarse, both)
    expected = np.zeros((3, 3), np.int64)
    expected[2, 2], expected[2, 1], expected[0, 1] = 7, 1, 1
    np.testing.assert_array_equal(confusion, expected)
