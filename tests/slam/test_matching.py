"""Guided matching by projection and mutual brute-force matching on synthetic ORB-like descriptors."""

from __future__ import annotations

import numpy as np

from fleetslam.slam.matching import match_by_projection, match_mutual, pair_distances

from .loop_scene import flip_bits, random_descriptors


def test_pair_distances_are_hamming_bits_and_l2() -> None:
    a = np.array([[0b1011, 0xFF]], np.uint8)
    b = np.array([[0b0001, 0x0F]], np.uint8)
    index = np.array([0])
    assert pair_distances(a, b, index, index).tolist() == [6.0]
    fa, fb = np.array([[0.0, 3.0]], np.float32), np.array([[4.0, 0.0]], np.float32)
    assert pair_distances(fa, fb, index, index).tolist() == [5.0]


def test_match_by_projection_finds_each_point_near_its_prediction_and_nowhere_else() -> None:
    rng = np.random.default_rng(3)
    n = 400
    map_descriptors = random_descriptors(rng, n)
    predicted = rng.uniform([0, 0], [640, 480], (n, 2))
    # The frame sees each map point 2 px from its prediction with a few flipped bits, in shuffled order,
    # plus a copy of every descriptor far from its prediction (a repeated pattern elsewhere in the image).
    order = rng.permutation(n)
    keypoints = np.vstack([predicted[order] + [1.2, -1.6], (predicted[order] + [200.0, 150.0]) % [640, 480]])
    descriptors = np.vstack([flip_bits(rng, map_descriptors[order], 10), map_descriptors[order]])
    frame_index, map_index = match_by_projection(
        keypoints, descriptors, predicted, map_descriptors, 15.0, 0.8, max_distance=64
    )
    assert len(frame_index) >= 0.95 * n
    assert np.all(frame_index < n), "a far copy was matched despite the search radius"
    np.testing.assert_array_equal(map_index, order[frame_index])
    # Without the distance bound a far copy is the lone candidate of some unrelated map point near it; but a map
    # point is one physical point, matched once, to its closest descriptor: the true keypoint still wins.
    loose_frame, loose_map = match_by_projection(keypoints, descriptors, predicted, map_descriptors, 15.0, 0.8)
    assert len(np.unique(loose_map)) == len(loose_map)
    true = loose_frame < n
    np.testing.assert_array_equal(loose_map[true], order[loose_frame[true]])
    assert true.sum() >= 0.95 * n


def test_a_landmark_made_twice_is_not_its_own_rival_but_a_repeated_pattern_is() -> None:
    """Each keypoint has two candidates with nearly the same descriptor: in the first half on the same spot (one
    landmark made twice, from two keyframes), in the second 12 px apart (a repeated pattern, a floor tile on)."""
    rng = np.random.default_rng(5)
    n = 200
    descriptors = random_descriptors(rng, n)
    keypoints = rng.uniform([20, 20], [620, 460], (n, 2))
    apart = np.where(np.arange(n)[:, None] < n // 2, [0.8, -0.6], [12.0, 0.0])
    shift = np.array([0.5, 0.5])
    predicted = np.vstack([keypoints + shift, keypoints + shift + apart])
    map_descriptors = np.vstack([flip_bits(rng, descriptors, 8), flip_bits(rng, descriptors, 8)])

    def matched(same_point_radius: float) -> np.ndarray:
        frame_index, map_index = match_by_projection(
            keypoints, descriptors, predicted, map_descriptors, 15.0, 0.8, same_point_radius=same_point_radius
        )
        assert np.all(map_index % n == frame_index)  # one of the keypoint's own two candidates
        return frame_index

    # Every candidate a rival: nearly equal distances, the ratio test rejects most of both kinds.
    assert len(matched(0.0)) < 0.2 * n
    # The same spot is the same point: those keypoints match; a pattern 12 px on is still a rival.
    kept = matched(2.0)
    assert np.sum(kept < n // 2) > 0.95 * (n // 2) and np.sum(kept >= n // 2) < 0.2 * (n // 2)


def test_match_mutual_pairs_true_correspondences_only() -> None:
    rng = np.random.default_rng(4)
    base = random_descriptors(rng, 300)
    other = flip_bits(rng, base, 20)
    permutation = rng.permutation(300)
    a_index, b_index = match_mutual(base, other[permutation], 0.8)
    assert len(a_index) >= 280
    np.testing.assert_array_equal(permutation[b_index], a_index)
