"""Descriptor matching (pure NumPy/SciPy): guided matching by projection and mutual ratio-test matching.

Guided matching compares each keypoint only with the map points that project within a radius of it, so the
cost grows with the number of nearby pairs (tens of thousands) instead of every keypoint × every map point
(millions): candidate pairs come from a k-d tree over the keypoints, their distances from a vectorised
Hamming popcount (binary descriptors) or L2 norm (float descriptors).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

EMPTY = np.zeros(0, np.intp)


def pair_distances(a: NDArray[Any], b: NDArray[Any], ia: NDArray[np.intp], ib: NDArray[np.intp]) -> NDArray[np.float64]:
    """Distances between descriptors ``a[ia[k]]`` and ``b[ib[k]]``: Hamming bits for uint8 rows, else L2."""
    if a.dtype == np.uint8:
        return np.bitwise_count(a[ia] ^ b[ib]).sum(axis=1, dtype=np.int64).astype(np.float64)
    diff = a[ia].astype(np.float32) - b[ib].astype(np.float32)
    return np.sqrt(np.einsum("ij,ij->i", diff, diff)).astype(np.float64)


def _order_by(group: NDArray[np.intp], distance: NDArray[np.float64]) -> NDArray[np.intp]:
    """Indices sorting by group, then by distance. Hamming distances (small integers) pack with the group into one
    integer key: one argsort instead of lexsort's two passes (the matcher's hot spot)."""
    if len(distance) and np.all(distance == np.rint(distance)) and distance.max() < 2**20 and distance.min() >= 0:
        key = group.astype(np.int64) << 20 | distance.astype(np.int64)
        return np.argsort(key, kind="stable")
    return np.lexsort((distance, group))


def _best_per_query(
    query: NDArray[np.intp],
    train: NDArray[np.intp],
    distance: NDArray[np.float64],
    ratio: float,
    positions: NDArray[np.floating] | None = None,
    same_point_radius: float = 0.0,
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
    """Per query index, its nearest train index if it passes the ratio test against the second nearest (a
    query with one candidate passes). With ``positions`` (per train index) and ``same_point_radius`` > 0, the
    second nearest is sought only among candidates farther than that from the nearest: candidates on the same
    spot are the same point twice, not a rival."""
    order = _order_by(query, distance)
    query, train, distance = query[order], train[order], distance[order]
    first = np.ones(len(query), bool)
    first[1:] = query[1:] != query[:-1]
    starts = np.flatnonzero(first)
    best = distance[starts]
    rival = np.ones(len(query), bool)
    if positions is not None and same_point_radius > 0 and len(query):
        group = np.cumsum(first) - 1
        spot = np.asarray(positions, np.float64)
        offset = spot[train] - spot[train[starts]][group]
        rival = np.einsum("ij,ij->i", offset, offset) > same_point_radius**2
    rival[starts] = False
    second = np.minimum.reduceat(np.where(rival, distance, np.inf), starts) if len(starts) else best
    keep = best < ratio * second
    return query[starts][keep], train[starts][keep], best[keep]


def match_by_projection(
    keypoints: NDArray[np.floating],
    descriptors: NDArray[Any],
    projected: NDArray[np.floating],
    map_descriptors: NDArray[Any],
    radius: float,
    ratio: float,
    max_distance: float = 0.0,
    same_point_radius: float = 0.0,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Match keypoints (N, 2) to map points whose predicted image positions ``projected`` (M, 2) lie within
    ``radius`` pixels: nearest descriptor with a ratio test among those candidates.

    ``max_distance`` > 0 also bounds the descriptor distance. ``same_point_radius`` > 0: map points projected
    within that many pixels of the nearest one do not count as its rival in the ratio test (the same landmark
    twice, made from two keyframes, would otherwise reject both). Returns (keypoint indices, map indices).
    """
    if len(keypoints) == 0 or len(projected) == 0:
        return EMPTY, EMPTY
    pairs = cKDTree(np.asarray(keypoints, np.float64)).sparse_distance_matrix(
        cKDTree(np.asarray(projected, np.float64)), radius, output_type="ndarray"
    )
    if len(pairs) == 0:
        return EMPTY, EMPTY
    query = pairs["i"].astype(np.intp)
    train = pairs["j"].astype(np.intp)
    distance = pair_distances(descriptors, map_descriptors, query, train)
    if max_distance > 0:
        close = distance <= max_distance
        query, train, distance = query[close], train[close], distance[close]
    query, train, distance = _best_per_query(query, train, distance, ratio, projected, same_point_radius)
    # A map point is one physical point: when several keypoints chose it, only the closest descriptor keeps it.
    order = _order_by(train, distance)
    first = np.ones(len(order), bool)
    first[1:] = train[order][1:] != train[order][:-1]
    keep = np.sort(order[first])
    return query[keep], train[keep]


def match_ratio(
    descriptors_a: NDArray[Any], descriptors_b: NDArray[Any], ratio: float, max_distance: float = 0.0
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Brute-force nearest neighbours a → b (OpenCV's k-NN: Hamming for uint8 rows, else L2) that pass the ratio
    test against the second nearest (``ratio`` ≥ 1: no test) and, when ``max_distance`` > 0, that bound."""
    from fleetslam.slam.features import import_cv2

    if len(descriptors_a) == 0 or len(descriptors_b) < 2:
        return EMPTY, EMPTY
    cv2 = import_cv2()
    binary = descriptors_a.dtype == np.uint8
    if not binary:
        descriptors_a, descriptors_b = descriptors_a.astype(np.float32), descriptors_b.astype(np.float32)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING if binary else cv2.NORM_L2)
    pairs = [
        (pair[0].queryIdx, pair[0].trainIdx)
        for pair in matcher.knnMatch(descriptors_a, descriptors_b, k=2)
        if len(pair) == 2
        and (ratio >= 1.0 or pair[0].distance < ratio * pair[1].distance)
        and (max_distance <= 0 or pair[0].distance <= max_distance)
    ]
    if not pairs:
        return EMPTY, EMPTY
    a_index, b_index = zip(*pairs, strict=True)
    return np.asarray(a_index, np.intp), np.asarray(b_index, np.intp)


def match_mutual(
    descriptors_a: NDArray[Any], descriptors_b: NDArray[Any], ratio: float, max_distance: float = 0.0
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Matches a → b that pass the ratio test (:func:`match_ratio`) and are each other's nearest neighbour."""
    if len(descriptors_a) < 2 or len(descriptors_b) < 2:
        return EMPTY, EMPTY
    # The ratio test one way and a plain nearest-neighbour cross-check the other: requiring the ratio both ways
    # lost half of the true correspondences between two views of the plant's start (21 instead of 27).
    forward = match_ratio(descriptors_a, descriptors_b, ratio, max_distance)
    backward = dict(zip(*match_ratio(descriptors_b, descriptors_a, 1.0, max_distance), strict=True))
    keep = np.array([backward.get(int(b)) == int(a) for a, b in zip(*forward, strict=True)], dtype=bool)
    if not keep.any():
        return EMPTY, EMPTY
    return forward[0][keep], forward[1][keep]
