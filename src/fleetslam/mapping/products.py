"""What octomap_server publishes, as plain arrays: point cloud bytes, cube-list markers and a 2D projection.

Pure functions over leaf centres and sizes (from :meth:`OccupancyOctree.occupied_centers` / ``free_centers``);
a node turns the results into ROS messages (visualization_msgs/MarkerArray, nav_msgs/OccupancyGrid; the point
cloud through :func:`fleetslam.msg.conversions.pointcloud2_msg`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.mapping.keys import TREE_DEPTH
from fleetslam.mapping.leaves import LeafArrays

#: octomap_server's m_colorFactor: hues span 0 … 0.8 of the circle.
DEFAULT_COLOR_FACTOR = 0.8
OCCUPIED, FREE, UNKNOWN = 100, 0, -1


# -- markers -----------------------------------------------------------------------------------------------------
def height_colormap(
    z: ArrayLike, z_min: float, z_max: float, *, color_factor: float = DEFAULT_COLOR_FACTOR
) -> NDArray[np.float32]:
    """RGBA ``(N, 4)`` colours by height, as octomap_server's heightMapColor (HSV hue, full saturation/value).

    The hue is ``(1 − clamp((z − z_min)/(z_max − z_min), 0, 1))·color_factor``: the lowest cells are magenta-ish,
    the highest red.
    """
    zs = np.asarray(z, dtype=np.float64).reshape(-1)
    span = z_max - z_min
    fraction = np.clip((zs - z_min) / span, 0.0, 1.0) if span > 0 else np.zeros_like(zs)
    h = (1.0 - fraction) * color_factor
    h = (h - np.floor(h)) * 6.0
    sector = np.floor(h).astype(np.int64)
    f = h - sector
    f = np.where(sector % 2 == 0, 1.0 - f, f)
    n = 1.0 - f  # value 1, saturation 1: m = 0
    one, zero = np.ones_like(h), np.zeros_like(h)
    # Sector 6 only arises for h == 1 exactly and wraps to sector 0.
    sector = np.where(sector == 6, 0, sector)
    r = np.choose(sector, [one, n, zero, zero, n, one])
    g = np.choose(sector, [n, one, one, n, zero, zero])
    b = np.choose(sector, [zero, zero, n, one, one, n])
    return np.stack([r, g, b, one], axis=1).astype(np.float32)


@dataclass(frozen=True)
class CubeList:
    """One CUBE_LIST marker: all leaves of one depth."""

    depth: int
    """Tree depth of the leaves (16 = finest); octomap_server uses it as the marker id."""
    size: float
    """Cube edge length (marker scale)."""
    centres: NDArray[np.float64]
    """(N, 3) cube centres."""
    colors: NDArray[np.float32] | None
    """(N, 4) RGBA per cube, or None for one colour for the marker."""


def cube_list_markers(
    centres: ArrayLike,
    sizes: ArrayLike,
    resolution: float,
    *,
    height_range: tuple[float, float] | None = None,
    color_factor: float = DEFAULT_COLOR_FACTOR,
) -> list[CubeList]:
    """Cube lists per leaf depth (deepest last), coloured by height over ``height_range`` if given.

    octomap_server colours over the tree's metric z range; pass ``(z_min, z_max)`` of the map for the same look.
    """
    xyz = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    size = np.asarray(sizes, dtype=np.float64).reshape(-1)
    depth = np.rint(TREE_DEPTH - np.log2(np.maximum(size, 1e-300) / resolution)).astype(np.int64)
    markers = []
    for d in np.unique(depth):
        at = depth == d
        colors = None
        if height_range is not None:
            colors = height_colormap(xyz[at, 2], height_range[0], height_range[1], color_factor=color_factor)
        markers.append(CubeList(int(d), float(resolution * 2.0 ** (TREE_DEPTH - d)), xyz[at], colors))
    return markers


# -- 2D projection -----------------------------------------------------------------------------------------------
def fit_ground_plane(
    points: ArrayLike,
    *,
    distance: float = 0.04,
    max_angle: float = 0.15,
    iterations: int = 200,
    seed: int = 0,
) -> NDArray[np.float64] | None:
    """RANSAC plane ``(a, b, c, d)`` (unit normal, c > 0, ax+by+cz+d=0) within ``max_angle`` rad of horizontal.

    Returns None if fewer than 50 points (octomap_server's minimum) or no plane has support. The inliers are then
    refined by least squares.
    """
    xyz = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(xyz) < 50:
        return None
    rng = np.random.default_rng(seed)
    best: tuple[int, NDArray[np.float64]] | None = None
    cos_limit = math.cos(max_angle)
    for _ in range(iterations):
        a, b, c = xyz[rng.choice(len(xyz), 3, replace=False)]
        normal = np.cross(b - a, c - a)
        norm = float(np.linalg.norm(normal))
        if norm < 1e-12:
            continue
        normal /= norm
        if normal[2] < 0:
            normal = -normal
        if normal[2] < cos_limit:
            continue
        d = -float(normal @ a)
        support = int(np.count_nonzero(np.abs(xyz @ normal + d) <= distance))
        if best is None or support > best[0]:
            best = (support, np.append(normal, d))
    if best is None:
        return None
    plane = best[1]
    inliers = xyz[np.abs(xyz @ plane[:3] + plane[3]) <= distance]
    if len(inliers) >= 3:
        centre = inliers.mean(axis=0)
        normal = np.linalg.svd(inliers - centre)[2][-1]
        normal = normal if normal[2] >= 0 else -normal
        if normal[2] >= cos_limit:
            plane = np.append(normal, -float(normal @ centre))
    return plane


def _footprints(
    centres: NDArray[np.float64], sizes: NDArray[np.float64], origin: NDArray[np.float64], resolution: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(column, row) of every grid cell under each leaf's square footprint."""
    cols: list[NDArray[np.int64]] = []
    rows: list[NDArray[np.int64]] = []
    cells = np.maximum(np.rint(sizes / resolution).astype(np.int64), 1)
    corner = np.rint((centres[:, :2] - sizes[:, None] / 2.0 - origin) / resolution).astype(np.int64)
    for width in np.unique(cells):
        at = cells == width
        offsets = np.arange(width)
        dx, dy = np.meshgrid(offsets, offsets, indexing="ij")
        cols.append((corner[at, 0][:, None] + dx.reshape(1, -1)).reshape(-1))
        rows.append((corner[at, 1][:, None] + dy.reshape(1, -1)).reshape(-1))
    if not cols:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(cols), np.concatenate(rows)


def project_occupancy_grid(
    occupied_centres: ArrayLike,
    occupied_sizes: ArrayLike,
    free_centres: ArrayLike,
    free_sizes: ArrayLike,
    resolution: float,
    z_min: float = -math.inf,
    z_max: float = math.inf,
    *,
    ground_z: float | None = None,
    ground_plane: ArrayLike | None = None,
    ground_tolerance: float | None = None,
) -> tuple[NDArray[np.int8], NDArray[np.float64]]:
    """2D occupancy grid (rows = y, columns = x; 100 occupied, 0 free, −1 unknown) and its origin (x, y).

    Leaves whose centre z lies in ``[z_min, z_max]`` are projected with their full footprint; occupied wins over
    free, as octomap_server's projected_map. The grid spans all given leaves. Occupied leaves within
    ``ground_tolerance`` (default one voxel) of the floor — ``ground_z`` or the plane ``ground_plane`` (a, b, c,
    d) — count as free, so the floor does not show up as an obstacle.
    """
    occ = np.asarray(occupied_centres, dtype=np.float64).reshape(-1, 3)
    occ_size = np.asarray(occupied_sizes, dtype=np.float64).reshape(-1)
    free = np.asarray(free_centres, dtype=np.float64).reshape(-1, 3)
    free_size = np.asarray(free_sizes, dtype=np.float64).reshape(-1)
    if len(occ) + len(free) == 0:
        return np.full((0, 0), UNKNOWN, np.int8), np.zeros(2)
    all_centres = np.concatenate([occ, free])
    all_sizes = np.concatenate([occ_size, free_size])
    lo = (all_centres[:, :2] - all_sizes[:, None] / 2.0).min(axis=0)
    hi = (all_centres[:, :2] + all_sizes[:, None] / 2.0).max(axis=0)
    origin = np.floor(lo / resolution + 1e-9) * resolution
    width, height = (np.ceil((hi - origin) / resolution - 1e-9).astype(np.int64)).tolist()
    tolerance = resolution if ground_tolerance is None else ground_tolerance
    on_ground = np.zeros(len(occ), np.bool_)
    if ground_z is not None:
        on_ground |= np.abs(occ[:, 2] - ground_z) <= tolerance
    if ground_plane is not None:
        plane = np.asarray(ground_plane, dtype=np.float64).reshape(4)
        on_ground |= np.abs(occ @ plane[:3] + plane[3]) / np.linalg.norm(plane[:3]) <= tolerance
    in_band_occ = (occ[:, 2] >= z_min) & (occ[:, 2] <= z_max)
    in_band_free = (free[:, 2] >= z_min) & (free[:, 2] <= z_max)
    grid = np.full((height, width), UNKNOWN, np.int8)
    for centres, sizes, value in (
        (np.concatenate([free[in_band_free], occ[in_band_occ & on_ground]]),
         np.concatenate([free_size[in_band_free], occ_size[in_band_occ & on_ground]]), FREE),
        (occ[in_band_occ & ~on_ground], occ_size[in_band_occ & ~on_ground], OCCUPIED),
    ):  # fmt: skip
        cols, rows = _footprints(centres, sizes, origin, resolution)
        inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
        grid[rows[inside], cols[inside]] = value
    return grid, origin


# -- comparing two trees -----------------------------------------------------------------------------------------
STATE_NAMES = ("unknown", "free", "occupied")


def state_confusion(
    a: LeafArrays, b: LeafArrays, *, threshold_a: float = 0.0, threshold_b: float = 0.0
) -> NDArray[np.int64]:
    """Volume (in finest voxels) of space per state pair: ``[i, j]`` is state i in ``a`` and j in ``b`` with states
    0 unknown, 1 free, 2 occupied; ``[0, 0]`` (unknown in both) is left 0.

    Exact for any pruning: leaves are Morton intervals, compared piece by piece.
    """
    from fleetslam.mapping.keys import morton

    def intervals(
        leaves: LeafArrays, threshold: float
    ) -> tuple[NDArray[np.uint64], NDArray[np.uint64], NDArray[np.int64]]:
        starts = morton(leaves.keys)
        lengths = np.left_shift(np.uint64(1), (3 * (TREE_DEPTH - leaves.depths.astype(np.int64))).astype(np.uint64))
        states = np.where(leaves.log_odds >= np.float32(threshold), 2, 1).astype(np.int64)
        return starts, starts + lengths, states

    confusion = np.zeros((3, 3), np.int64)
    parts = [intervals(a, threshold_a), intervals(b, threshold_b)]
    bounds = np.unique(np.concatenate([p[0] for p in parts] + [p[1] for p in parts]))
    if len(bounds) < 2:
        return confusion
    lo, widths = bounds[:-1], (bounds[1:] - bounds[:-1]).astype(np.int64)
    labels = []
    for starts, ends, states in parts:
        idx = np.searchsorted(starts, lo, side="right") - 1
        safe = np.maximum(idx, 0)
        inside = (idx >= 0) & (lo < ends[safe])
        labels.append(np.where(inside, states[safe], 0))
    np.add.at(confusion, (labels[0], labels[1]), widths)
    confusion[0, 0] = 0
    return confusion
