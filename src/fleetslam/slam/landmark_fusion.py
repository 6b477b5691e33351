"""Fusion of duplicated landmarks in the local map (pure NumPy/SciPy), as ORB-SLAM's local mapping does it
(``SearchInNeighbors``: landmarks projected into a keyframe that fall on one of its keypoints).

A keyframe makes landmarks of the keypoints it did not track; where tracking had missed an existing landmark (the
ratio test rejected it, or the prediction put it a little off), the same physical point is made a second time
beside the first. From then on the two are each other's rival in the ratio test, so tracking matches neither, and
the window's adjustment holds each with half the observations. :func:`fuse_into_view` finds, for one view (a
keyframe's keypoints and the landmarks they observe), the landmarks of the map that project onto one of its
keypoints with a close descriptor and a consistent position (reprojection, and depth where the keypoint has it, within
the χ² gate tracking uses); :func:`merge_plan` turns the pairs found into which landmark each duplicate becomes: the
one with the most observations (ORB-SLAM's ``MapPoint::Replace``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from fleetslam.slam.matching import pair_distances

#: χ² at 95 % for 2 (no depth) and 3 (with depth) residuals, as tracking's inlier gate and ORB-SLAM's ``Fuse``.
CHI2_PIXEL, CHI2_DEPTH = 5.991, 7.815


@dataclass(frozen=True)
class View:
    """One keyframe's keypoints as fusion sees them."""

    T_world_camera: NDArray[np.float64]
    keypoints: NDArray[np.float64]
    """(N, 2) pixels."""
    descriptors: NDArray[Any]
    """(N, D) their descriptors."""
    scales: NDArray[np.float64]
    """(N,) pyramid scale of each keypoint (its pixel noise grows with it)."""
    depths: NDArray[np.float64]
    """(N,) measured depth (metres), 0 where none."""
    landmarks: NDArray[np.int64]
    """(N,) the landmark id each keypoint observes, -1 where none."""


@dataclass(frozen=True)
class Fusion:
    """What one view's search found: landmark pairs that are one point, and new observations."""

    duplicates: NDArray[np.int64]
    """(K, 2) ids (the keypoint's landmark, the projected landmark): the same physical point made twice."""
    observed_index: NDArray[np.intp]
    """Keypoints without a landmark that the projected landmark ``observed_ids`` falls on."""
    observed_ids: NDArray[np.int64]


def fuse_into_view(
    view: View,
    ids: NDArray[np.int64],
    points: NDArray[np.float64],
    descriptors: NDArray[Any],
    camera_matrix: NDArray[np.float64],
    *,
    max_distance: float,
    pixel_std: float,
    depth_noise: float,
    min_depth: float,
    distinct: NDArray[np.bool_] | None = None,
    distinct_radius: float = 0.0,
    distinct_ratio: float = 1.0,
) -> Fusion:
    """Project the landmarks ``ids`` (world ``points``, ``descriptors``) into ``view`` and pair each with the keypoint
    it falls on: within the χ² gate of reprojection (σ ``pixel_std`` × the keypoint's scale) and, where the keypoint
    has a depth, of depth (σ ``depth_noise``·z² + 1 mm), with the closest descriptor within ``max_distance`` (each
    landmark goes to one keypoint, its closest descriptor; a keypoint may take several). Landmarks the view already
    observes are skipped. A landmark on a keypoint that observes another one is that one's duplicate; a keypoint
    that observes none observes the closest landmark it took, and the others it took are that one's duplicates."""
    empty = Fusion(np.zeros((0, 2), np.int64), np.zeros(0, np.intp), np.zeros(0, np.int64))
    if len(ids) == 0 or len(view.keypoints) == 0:
        return empty
    candidates = np.flatnonzero(~np.isin(ids, view.landmarks))
    T_cw = np.linalg.inv(view.T_world_camera)
    cam = points[candidates] @ T_cw[:3, :3].T + T_cw[:3, 3]
    in_front = cam[:, 2] > min_depth
    candidates, cam = candidates[in_front], cam[in_front]
    if len(candidates) == 0:
        return empty
    k = camera_matrix
    uv = np.stack([k[0, 0] * cam[:, 0] / cam[:, 2] + k[0, 2], k[1, 1] * cam[:, 1] / cam[:, 2] + k[1, 2]], axis=1)
    radius = float(np.sqrt(CHI2_PIXEL) * pixel_std * max(float(view.scales.max()), 1.0))
    # Only those that land among the keypoints (most of the local map lies outside the view).
    low, high = view.keypoints.min(axis=0) - radius, view.keypoints.max(axis=0) + radius
    inside = np.all((uv >= low) & (uv <= high), axis=1)
    candidates, cam, uv = candidates[inside], cam[inside], uv[inside]
    if len(candidates) == 0:
        return empty
    pairs = cKDTree(np.asarray(view.keypoints, np.float64)).sparse_distance_matrix(
        cKDTree(uv), radius, output_type="ndarray"
    )
    if len(pairs) == 0:
        return empty
    keypoint = pairs["i"].astype(np.intp)
    projected = pairs["j"].astype(np.intp)
    sigma = pixel_std * view.scales[keypoint]
    chi2 = np.sum((uv[projected] - view.keypoints[keypoint]) ** 2, axis=1) / sigma**2
    depth = view.depths[keypoint]
    has_depth = depth > 0
    z = cam[projected, 2]
    chi2 = chi2 + np.where(has_depth, ((z - depth) / (depth_noise * depth**2 + 1e-3)) ** 2, 0.0)
    distance = pair_distances(view.descriptors, descriptors, keypoint, candidates[projected])
    good = (chi2 <= np.where(has_depth, CHI2_DEPTH, CHI2_PIXEL)) & (distance <= max_distance)
    keypoint, projected, distance = keypoint[good], projected[good], distance[good]
    # Each landmark goes to its closest descriptor; a keypoint may take several (all one point, as ORB-SLAM fuses
    # one map point after another into the same keypoint).
    order = np.lexsort((distance, projected))
    first = np.ones(len(order), bool)
    first[1:] = projected[order][1:] != projected[order][:-1]
    best = order[first]
    if distinct is not None and distinct_radius > 0 and len(best):
        best = best[_distinctive(view, descriptors, uv, candidates, projected[best], keypoint[best], distance[best],
                                 distinct, distinct_radius, distinct_ratio)]  # fmt: skip
    index, landmark = keypoint[best], ids[candidates[projected[best]]].astype(np.int64)
    # Per keypoint, its closest landmark first.
    order = np.lexsort((distance[best], index))
    index, landmark = index[order], landmark[order]
    own = view.landmarks[index]
    lead = np.ones(len(index), bool)
    lead[1:] = index[1:] != index[:-1]
    # A keypoint without a landmark observes its closest one; the others it took are that one's duplicates.
    head = np.where(own >= 0, own, landmark[np.flatnonzero(lead)][np.cumsum(lead) - 1])
    pair = (own >= 0) | ~lead
    new = (own < 0) & lead
    return Fusion(np.stack([head[pair], landmark[pair]], axis=1).astype(np.int64), index[new], landmark[new])


def _distinctive(
    view: View,
    descriptors: NDArray[Any],
    uv: NDArray[np.float64],
    candidates: NDArray[np.intp],
    projected: NDArray[np.intp],
    keypoint: NDArray[np.intp],
    distance: NDArray[np.float64],
    distinct: NDArray[np.bool_],
    radius: float,
    ratio: float,
) -> NDArray[np.bool_]:
    """Which pairs pass the ratio test against every other keypoint within ``radius`` of the projection (for the
    landmarks ``distinct`` flags: their position is a guess, so the keypoint in the gate may be a repeat of the
    texture while the true one lies elsewhere)."""
    keep = np.ones(len(projected), bool)
    flagged = np.flatnonzero(distinct[candidates[projected]])
    if len(flagged) == 0:
        return keep
    second = _closest_rival(view.keypoints, view.descriptors, uv[projected[flagged]],
                            descriptors[candidates[projected[flagged]]], keypoint[flagged], radius)  # fmt: skip
    keep[flagged] = distance[flagged] < ratio * second
    return keep


def _closest_rival(
    keypoints: NDArray[np.float64],
    keypoint_descriptors: NDArray[Any],
    queries: NDArray[np.float64],
    query_descriptors: NDArray[Any],
    own: NDArray[np.intp],
    radius: float,
) -> NDArray[np.float64]:
    """Per query (a pixel and a descriptor), the smallest descriptor distance to a keypoint within ``radius``
    (squared pixel distance ≤ radius², as ``cKDTree.query_ball_point``) other than its ``own``; inf where none.

    The queries are bucketed on a grid of cells ``radius`` wide, and each cell's queries are compared at once, as
    a block of pixel and descriptor distances, with the keypoints around it (those of the 3 × 3 cells): on the
    hand-held figure eight at 320 × 240 (~1000 bearings, half the keypoints within 80 px of each), a ball query
    per bearing and a descriptor distance per neighbour cost a median 31 ms a keyframe (up to 170), this 4.5 ms
    (up to 17), with the same result."""
    keypoints = np.asarray(keypoints, np.float64)
    second = np.full(len(queries), np.inf)
    if len(queries) == 0 or len(keypoints) == 0:
        return second
    packed = _packed(keypoint_descriptors), _packed(query_descriptors)
    bound = radius * radius
    # Only to pick the keypoints worth testing: the test itself is the exact one, so rounding at a cell's edge
    # cannot drop a neighbour (the margin keeps any keypoint the exact test would take).
    margin = radius + 1e-6 * (radius + float(np.abs(keypoints).max()) + float(np.abs(queries).max()))
    cells = np.floor(queries / max(radius, 1e-9)).astype(np.int64)
    _, group = np.unique(cells, axis=0, return_inverse=True)
    group = group.reshape(-1)
    order = np.argsort(group, kind="stable")
    bounds = np.flatnonzero(np.diff(group[order])) + 1
    for rows in np.split(order, bounds):
        low, high = queries[rows].min(axis=0) - margin, queries[rows].max(axis=0) + margin
        cols = np.flatnonzero(np.all((keypoints >= low) & (keypoints <= high), axis=1))
        if len(cols) == 0:
            continue
        dx = queries[rows, 0][:, None] - keypoints[cols, 0][None, :]
        dy = queries[rows, 1][:, None] - keypoints[cols, 1][None, :]
        near = dx * dx + dy * dy <= bound
        near &= cols[None, :] != own[rows][:, None]
        if packed[0] is not None and packed[1] is not None:
            # One popcount per 64-bit word over the whole block (a word at a time: broadcasting the words' axis
            # too is several times slower).
            table = np.zeros(near.shape, np.uint32)
            for word in range(packed[0].shape[1]):
                table += np.bitwise_count(packed[1][rows, word][:, None] ^ packed[0][cols, word][None, :])
            second[rows] = np.where(near, table.astype(np.float64), np.inf).min(axis=1)
        else:
            i, j = np.nonzero(near)
            d = pair_distances(keypoint_descriptors, query_descriptors, cols[j], rows[i])
            np.minimum.at(second, rows[i], d)
    return second


def _packed(descriptors: NDArray[Any]) -> NDArray[np.uint64] | None:
    """Binary descriptors as 64-bit words (the Hamming distance over 8 bytes in one popcount), None for others."""
    if descriptors.dtype != np.uint8 or descriptors.ndim != 2 or descriptors.shape[1] % 8:
        return None
    return np.ascontiguousarray(descriptors).view(np.uint64)


def merge_plan(
    duplicates: NDArray[np.int64], observations: dict[int, int]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Which landmark each duplicate becomes: the pairs are joined into groups of one physical point (a pair chain
    A–B, B–C is one group), and each group keeps its landmark with the most ``observations`` (the oldest, i.e. the
    smallest id, on a tie). Returns (dropped ids, the id each becomes), dropped ids sorted."""
    parent: dict[int, int] = {}

    def root(a: int) -> int:
        while parent.setdefault(a, a) != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in np.asarray(duplicates, np.int64).reshape(-1, 2).tolist():
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[int]] = {}
    for member in list(parent):
        groups.setdefault(root(member), []).append(member)
    dropped: list[int] = []
    kept: list[int] = []
    for members in groups.values():
        keep = min(members, key=lambda m: (-observations.get(m, 0), m))
        for m in members:
            if m != keep:
                dropped.append(m)
                kept.append(keep)
    order = np.argsort(np.asarray(dropped, np.int64), kind="stable")
    return np.asarray(dropped, np.int64)[order], np.asarray(kept, np.int64)[order]
