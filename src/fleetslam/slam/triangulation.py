"""New landmarks from two keyframes for keypoints the depth camera did not measure (pure NumPy/SciPy).

An RGB-D camera measures depth out to a few metres; in a hall the textured walls and racks are often farther, and
a visual odometry that only uses measured points has little left to hold its heading (far points fix rotation
best). ORB-SLAM's answer, used here: a keypoint without depth in one keyframe is searched for in the next along
its epipolar segment (the projections of its ray between ``near`` and ``far``), matched by descriptor, and
triangulated when the two rays meet at a useful angle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fleetslam.slam.matching import pair_distances


@dataclass
class Triangulated:
    """Landmarks found in both keyframes: their keypoint indices in each and world positions."""

    index_a: NDArray[np.intp]
    index_b: NDArray[np.intp]
    points: NDArray[np.float64]


EMPTY = Triangulated(np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros((0, 3)))


def _project(T_wc: NDArray[np.float64], points: NDArray[np.float64], k: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3): pixel u, v and depth z of world points in a camera at ``T_wc``."""
    rotation = T_wc[:3, :3]
    cam = (points - T_wc[:3, 3]) @ rotation
    z = cam[:, 2]
    safe = np.where(z > 1e-9, z, 1e-9)
    return np.stack([k[0, 0] * cam[:, 0] / safe + k[0, 2], k[1, 1] * cam[:, 1] / safe + k[1, 2], z], axis=1)


def _rays(T_wc: NDArray[np.float64], pixels: NDArray[np.float64], k: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit world directions of the pixels' rays."""
    local = np.stack([(pixels[:, 0] - k[0, 2]) / k[0, 0], (pixels[:, 1] - k[1, 2]) / k[1, 1], np.ones(len(pixels))], 1)
    world = local @ T_wc[:3, :3].T
    return world / np.linalg.norm(world, axis=1, keepdims=True)


def match_and_triangulate(
    pose_a: NDArray[np.float64],
    pixels_a: NDArray[np.floating],
    descriptors_a: NDArray[Any],
    pose_b: NDArray[np.float64],
    pixels_b: NDArray[np.floating],
    descriptors_b: NDArray[Any],
    scales_b: NDArray[np.floating],
    camera_matrix: NDArray[np.float64],
    *,
    near: float,
    far: float,
    tolerance_px: float,
    max_distance: float = 50.0,
    ratio: float = 0.8,
    min_parallax_deg: float = 1.0,
) -> Triangulated:
    """Match keypoints of keyframe a (``T_world_camera`` ``pose_a``) to keyframe b's along epipolar segments and
    triangulate them.

    A pair is kept when b's keypoint lies within ``tolerance_px``·(its pyramid scale) of a's segment between depths
    ``near`` and ``far``, its descriptor is within ``max_distance`` (Hamming bits for binary descriptors) and passes
    the ``ratio`` test against a's other candidates, no other keypoint of a claims the same keypoint of b with a
    closer descriptor, the rays meet in front of both cameras at more than ``min_parallax_deg``, and the point
    reprojects within the tolerance in both."""
    if len(pixels_a) == 0 or len(pixels_b) == 0:
        return EMPTY
    k = camera_matrix
    a_px = np.asarray(pixels_a, np.float64)
    b_px = np.asarray(pixels_b, np.float64)
    rays = _rays(pose_a, a_px, k)
    centre_a, centre_b = pose_a[:3, 3], pose_b[:3, 3]
    start = _project(pose_b, centre_a + near * rays, k)
    end = _project(pose_b, centre_a + far * rays, k)
    usable = np.flatnonzero((start[:, 2] > 0.1) & (end[:, 2] > 0.1))
    if len(usable) == 0:
        return EMPTY
    p0, p1 = start[usable, :2], end[usable, :2]
    mid, half = (p0 + p1) / 2.0, np.linalg.norm(p1 - p0, axis=1) / 2.0
    reach = tolerance_px * float(np.max(scales_b))
    # Candidate pairs: keypoints of b within the longest half-segment of any midpoint (one sparse query, no Python
    # loop), then the exact distance to each segment below.
    pairs = cKDTree(mid).sparse_distance_matrix(cKDTree(b_px), float(half.max()) + reach, output_type="ndarray")
    if len(pairs) == 0:
        return EMPTY
    seg, cand_b = pairs["i"].astype(np.intp), pairs["j"].astype(np.intp)
    near_enough = pairs["v"] <= half[seg] + reach
    seg, cand_b = seg[near_enough], cand_b[near_enough]
    # Distance of b's keypoint to a's segment.
    direction = p1[seg] - p0[seg]
    length2 = np.maximum(np.einsum("ij,ij->i", direction, direction), 1e-12)
    t = np.clip(np.einsum("ij,ij->i", b_px[cand_b] - p0[seg], direction) / length2, 0.0, 1.0)
    off = np.linalg.norm(p0[seg] + t[:, None] * direction - b_px[cand_b], axis=1)
    close = off <= tolerance_px * scales_b[cand_b]
    seg, cand_b = seg[close], cand_b[close]
    if len(seg) == 0:
        return EMPTY
    cand_a = usable[seg]
    distance = pair_distances(descriptors_a, descriptors_b, cand_a, cand_b)
    good = distance <= max_distance
    cand_a, cand_b, distance = cand_a[good], cand_b[good], distance[good]
    cand_a, cand_b = _best_unique(cand_a, cand_b, distance, ratio)
    if len(cand_a) == 0:
        return EMPTY
    # Midpoint of the two rays' closest points.
    da, db = rays[cand_a], _rays(pose_b, b_px[cand_b], k)
    w0 = centre_a - centre_b
    a_, b_, c_ = 1.0, np.einsum("ij,ij->i", da, db), 1.0
    d_, e_ = np.einsum("ij,j->i", da, w0), np.einsum("ij,j->i", db, w0)
    denominator = a_ * c_ - b_**2
    parallel = denominator < 1e-12
    denominator = np.where(parallel, 1.0, denominator)
    s = (b_ * e_ - c_ * d_) / denominator
    u = (a_ * e_ - b_ * d_) / denominator
    points = ((centre_a + s[:, None] * da) + (centre_b + u[:, None] * db)) / 2.0
    parallax = np.degrees(np.arccos(np.clip(b_, -1.0, 1.0)))
    in_a, in_b = _project(pose_a, points, k), _project(pose_b, points, k)
    error_a = np.linalg.norm(in_a[:, :2] - a_px[cand_a], axis=1)
    error_b = np.linalg.norm(in_b[:, :2] - b_px[cand_b], axis=1)
    limit = tolerance_px * scales_b[cand_b]
    ok = (
        ~parallel
        & (s > 0)
        & (u > 0)
        & (parallax >= min_parallax_deg)
        & (in_a[:, 2] < far)
        & (error_a <= limit)
        & (error_b <= limit)
    )
    return Triangulated(cand_a[ok], cand_b[ok], points[ok])


def _best_unique(
    a: NDArray[np.intp], b: NDArray[np.intp], distance: NDArray[np.float64], ratio: float
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Per a, the closest b if clearly better than a's second candidate; then per b, only the closest a."""
    if len(a) == 0:
        return a, b
    order = np.lexsort((distance, a))
    a, b, distance = a[order], b[order], distance[order]
    first = np.ones(len(a), bool)
    first[1:] = a[1:] != a[:-1]
    starts = np.flatnonzero(first)
    second = np.full(len(starts), np.inf)
    following = starts + 1
    inside = following < len(a)
    inside[inside] = ~first[following[inside]]
    second[inside] = distance[following[inside]]
    keep = distance[starts] < ratio * second
    a, b, distance = a[starts][keep], b[starts][keep], distance[starts][keep]
    order = np.lexsort((distance, b))
    first = np.ones(len(order), bool)
    first[1:] = b[order][1:] != b[order][:-1]
    chosen = order[first]
    return a[chosen], b[chosen]
