"""Landmarks for keypoints without depth: epipolar matching between two keyframes and triangulation."""

from __future__ import annotations

import numpy as np

from fleetslam.geometry import invert, pose_from_xyz_rpy
from fleetslam.slam.triangulation import match_and_triangulate

from .loop_scene import flip_bits, random_descriptors

K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])


def _view(
    pose: np.ndarray, points: np.ndarray, rng: np.random.Generator, noise: float
) -> tuple[np.ndarray, np.ndarray]:
    T = invert(pose)
    cam = points @ T[:3, :3].T + T[:3, 3]
    uv = cam[:, :2] / cam[:, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]
    visible = (cam[:, 2] > 0.1) & np.all((uv >= 0) & (uv < [640, 480]), axis=1)
    return uv + rng.normal(0.0, noise, uv.shape), visible


def test_far_keypoints_seen_from_two_keyframes_become_landmarks() -> None:
    rng = np.random.default_rng(0)
    # Texture 5-12 m away, beyond a Kinect's range; the second keyframe 40 cm to the side and 5° turned.
    points = rng.uniform([-4.0, -2.0, 5.0], [4.0, 2.0, 12.0], (400, 3))
    pose_a = np.eye(4)
    pose_b = pose_from_xyz_rpy(0.4, 0.0, 0.1, 0.0, np.radians(5.0), 0.0)
    descriptors = random_descriptors(rng, len(points))
    uv_a, seen_a = _view(pose_a, points, rng, 0.5)
    uv_b, seen_b = _view(pose_b, points, rng, 0.5)
    ia, ib = np.flatnonzero(seen_a), rng.permutation(np.flatnonzero(seen_b))
    result = match_and_triangulate(
        pose_a, uv_a[ia], descriptors[ia], pose_b, uv_b[ib], flip_bits(rng, descriptors[ib], 8),
        np.ones(len(ib)), K, near=2.0, far=60.0, tolerance_px=2.0,
    )  # fmt: skip
    # Every match is the same physical point (descriptor and epipolar constraint together).
    assert len(result.points) > 0.5 * len(np.intersect1d(ia, ib))
    np.testing.assert_array_equal(ia[result.index_a], ib[result.index_b])
    truth = points[ia[result.index_a]]
    depth = truth[:, 2]
    # Depth error of a triangulated point: z²·σ_θ/baseline with σ_θ ≈ √2·0.5 px / 525 (1.3e-3 rad): 8 cm at
    # 12 m over 40 cm; bound 4σ of each point's own expected error.
    expected = depth**2 * (np.sqrt(2) * 0.5 / 525.0) / 0.4
    assert np.all(np.linalg.norm(result.points - truth, axis=1) < 4 * expected + 0.01)


def test_points_without_parallax_or_behind_are_not_triangulated() -> None:
    rng = np.random.default_rng(1)
    points = rng.uniform([-4.0, -2.0, 5.0], [4.0, 2.0, 12.0], (300, 3))
    descriptors = random_descriptors(rng, len(points))
    pose_a = np.eye(4)
    pose_b = pose_from_xyz_rpy(0.005, 0.0, 0.0, 0.0, 0.0, 0.0)  # 5 mm: no angle to triangulate from
    uv_a, _ = _view(pose_a, points, rng, 0.3)
    uv_b, _ = _view(pose_b, points, rng, 0.3)
    result = match_and_triangulate(
        pose_a, uv_a, descriptors, pose_b, uv_b, descriptors, np.ones(len(points)), K,
        near=2.0, far=60.0, tolerance_px=2.0,
    )  # fmt: skip
    assert len(result.points) == 0
