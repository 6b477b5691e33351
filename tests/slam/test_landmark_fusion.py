"""Fusion of duplicated landmarks: the pure search and merge plan, and the odometry merging a real duplicate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.slam.config import OdometryConfig
from fleetslam.slam.landmark_fusion import View, _closest_rival, fuse_into_view, merge_plan
from fleetslam.slam.matching import pair_distances
from fleetslam.slam.odometry import VisualOdometry

from .loop_scene import flip_bits, random_descriptors
from .test_odometry import BASE, INTRINSICS
from .textured_room import make_textures, render

K = INTRINSICS.K
OPTIONS = {"max_distance": 50.0, "pixel_std": 1.0, "depth_noise": 1.5e-3, "min_depth": 0.3}


@pytest.fixture(scope="module")
def textures() -> list[np.ndarray]:
    return make_textures(np.random.default_rng(0))


def _project(T_world_camera: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T_cw = np.linalg.inv(T_world_camera)
    cam = points @ T_cw[:3, :3].T + T_cw[:3, 3]
    return cam[:, :2] / cam[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]], cam[:, 2]


def _view(rng: np.random.Generator) -> tuple[View, np.ndarray, np.ndarray]:
    """A keyframe seeing 50 points, each keypoint observing landmark 100 + k; returns the view, the points (world)
    and their descriptors."""
    pose = pose_from_xyz_rpy(0.2, -0.1, 0.3, 0.05, 0.3, 0.0)
    cam = np.column_stack([rng.uniform(-1.0, 1.0, (50, 2)), rng.uniform(1.0, 4.0, 50)])
    cam[:, :2] *= cam[:, 2:] / 2.0
    points = cam @ pose[:3, :3].T + pose[:3, 3]
    pixels, depths = _project(pose, points)
    descriptors = random_descriptors(rng, 50)
    view = View(pose, pixels + rng.normal(0.0, 0.3, pixels.shape), descriptors, np.ones(50), depths,
                np.arange(100, 150, dtype=np.int64))  # fmt: skip
    return view, points, descriptors


def test_a_landmark_made_twice_is_paired_with_the_keypoint_that_observes_its_twin() -> None:
    rng = np.random.default_rng(1)
    view, points, descriptors = _view(rng)
    # Landmarks 3..7 are points 0..4 made a second time (a few millimetres off, the descriptor a few bits off).
    twins = points[:5] + rng.normal(0.0, 0.003, (5, 3))
    fusion = fuse_into_view(view, np.arange(3, 8, dtype=np.int64), twins, flip_bits(rng, descriptors[:5], 6), K,
                            **OPTIONS)  # fmt: skip
    assert sorted(map(tuple, fusion.duplicates.tolist())) == [(100 + k, 3 + k) for k in range(5)]
    assert len(fusion.observed_index) == 0
    # Landmarks the view already observes are not candidates.
    again = fuse_into_view(view, view.landmarks[:5], points[:5], descriptors[:5], K, **OPTIONS)
    assert len(again.duplicates) == 0


def test_a_distinct_landmark_with_a_similar_descriptor_is_not_merged() -> None:
    rng = np.random.default_rng(2)
    view, points, descriptors = _view(rng)
    similar = flip_bits(rng, descriptors[:3], 6)
    ray = points[:3] - view.T_world_camera[:3, 3]
    # Behind the keypoint along the same ray (projects onto it: only the depth tells them apart), 10 cm off to
    # the side (another spot of the image), and the true twin with a descriptor beyond the bound.
    behind = view.T_world_camera[:3, 3] + ray * 1.15
    beside = points[:3] + np.array([0.1, 0.0, 0.0])
    far_descriptor = flip_bits(rng, descriptors[:3], 90)
    for candidate, candidate_descriptors in ((behind, similar), (beside, similar), (points[:3], far_descriptor)):
        fusion = fuse_into_view(view, np.arange(3, dtype=np.int64), candidate, candidate_descriptors, K, **OPTIONS)
        assert len(fusion.duplicates) == 0 and len(fusion.observed_index) == 0
    # Without depth at the keypoint a point on its ray cannot be told apart: the keypoint gains the observation.
    no_landmark = View(view.T_world_camera, view.keypoints, view.descriptors, view.scales, np.zeros(50),
                       np.full(50, -1, np.int64))  # fmt: skip
    fusion = fuse_into_view(no_landmark, np.arange(3, dtype=np.int64), behind, similar, K, **OPTIONS)
    assert fusion.observed_index.tolist() == [0, 1, 2] and fusion.observed_ids.tolist() == [0, 1, 2]


def test_each_group_keeps_the_landmark_with_the_most_observations() -> None:
    # 5-9 and 9-2 are one point (a chain); 11-12 another, tied: the older (smaller id) stays.
    dropped, kept = merge_plan(np.array([[5, 9], [9, 2], [12, 11]]), {5: 4, 9: 1, 2: 2, 11: 1, 12: 1})
    assert dropped.tolist() == [2, 9, 12] and kept.tolist() == [5, 5, 11]
    empty = merge_plan(np.zeros((0, 2), np.int64), {})
    assert len(empty[0]) == 0 and len(empty[1]) == 0


def test_the_odometry_merges_a_landmark_made_twice_everywhere_it_is_referenced(textures: list[np.ndarray]) -> None:
    """A landmark copied into the local map (as a keyframe makes one beside a landmark tracking missed) rivals its
    twin in the ratio test; after the next keyframe's fusion only one of the two is left, in the map and in every
    keyframe of the window, and tracking matches it again."""
    config = OdometryConfig(fuse_landmarks=True, keyframe_translation=0.02, motion_prior_acceleration=0.0)
    vo = VisualOdometry(config, INTRINSICS)
    vo.track(*render(BASE, INTRINSICS, textures), 0.0)
    local_map = vo.local_map
    originals = local_map.ids[:60].copy()
    twins = local_map.add(local_map.points[:60] + 0.002, local_map.descriptors[:60].copy(), vo.frames)
    motion = pose_from_xyz_rpy(0.03, 0.0, 0.0, 0.0, 0.0, 0.0)
    result = vo.track(*render(BASE @ motion, INTRINSICS, textures), 0.1)
    assert result.is_keyframe and not result.lost
    before = set(local_map.ids.tolist())  # the keyframe's own new landmarks come with local mapping, below
    assert vo.local_mapping() is not None
    assert vo.fused_landmarks >= 50
    # Of each original and its twin, one is left (or neither: both merged into a third landmark of the same spot,
    # such as the same corner detected on two pyramid levels); the first keyframe observes the originals, the
    # twins go (5 of the 60 pairs are left whole: the second keyframe has no keypoint where they project).
    _, twin_left = local_map.rows(twins)
    _, original_left = local_map.rows(originals)
    assert (twin_left & original_left).sum() <= 6
    assert twin_left.sum() <= 6 and original_left.sum() >= 50
    assert len(before - set(local_map.ids.tolist())) >= 50
    for kf in vo.window:
        _, found = local_map.rows(kf.landmarks)
        assert found.all(), "a keyframe still refers to a dropped landmark"
        assert len(np.unique(kf.landmarks)) == len(kf.landmarks)
    # The next frame matches the originals the twins had hidden.
    later = vo.track(*render(BASE @ pose_from_xyz_rpy(0.035, 0.0, 0.0, 0.0, 0.0, 0.0), INTRINSICS, textures), 0.2)
    assert later.inliers > result.inliers


def test_landmarks_are_fused_only_where_no_wheel_prior_ties_the_window(textures: list[np.ndarray]) -> None:
    """A camera without wheels fuses; with the wheels tying each keyframe to the one before, the track is the one
    without fusion, to the bit (as ``window_fixed_keyframes``)."""
    motions = [pose_from_xyz_rpy(0.03 * k, 0.0, 0.01 * k, 0.0, np.radians(1.0 * k), 0.0) for k in range(6)]
    frames = [render(BASE @ motion, INTRINSICS, textures) for motion in motions]

    def track(fuse: bool, wheels: bool) -> tuple[VisualOdometry, list[np.ndarray]]:
        vo = VisualOdometry(OdometryConfig(fuse_landmarks=fuse, window_keyframes=3, keyframe_translation=0.05),
                            INTRINSICS)  # fmt: skip
        poses = []
        for k, ((rgb, depth), motion) in enumerate(zip(frames, motions, strict=True)):
            poses.append(vo.track(rgb, depth, 0.1 * k, prior=motion if wheels else None).pose)
            poses.append(adjusted if (adjusted := vo.local_mapping()) is not None else poses[-1])
        return vo, poses

    with_wheels, with_wheels_poses = track(True, wheels=True)
    assert with_wheels.fused_landmarks == 0
    for a, b in zip(with_wheels_poses, track(False, wheels=True)[1], strict=True):
        np.testing.assert_array_equal(a, b)
    hand_held, hand_held_poses = track(True, wheels=False)
    assert hand_held.fused_landmarks > 0
    # Fused, the track is as accurate as the pair test's.
    error = np.linalg.inv(motions[-1]) @ hand_held_poses[-1]
    assert np.linalg.norm(error[:3, 3]) < 0.010


def test_a_bearing_is_fused_only_where_its_keypoint_is_the_clearly_closest_descriptor_around() -> None:
    """A bearing's distance is a guess: the keypoint at its projection may repeat the texture of the one it is. With
    ``distinct`` it is fused only where no other keypoint within the radius has a descriptor nearly as close."""
    rng = np.random.default_rng(3)
    view, points, descriptors = _view(rng)
    keypoints = view.keypoints.copy()
    # Keypoint 1 moved 15 px beside keypoint 0 with keypoint 0's descriptor: a repeat of its texture.
    keypoints[1] = keypoints[0] + [15.0, 0.0]
    view_descriptors = view.descriptors.copy()
    view_descriptors[1] = view_descriptors[0]
    no_landmark = View(view.T_world_camera, keypoints, view_descriptors, view.scales, np.zeros(50),
                       np.full(50, -1, np.int64))  # fmt: skip
    ids = np.arange(3, dtype=np.int64)
    observed = flip_bits(rng, descriptors[:3], 2)

    def fuse(distinct: np.ndarray | None, radius: float) -> list[int]:
        fusion = fuse_into_view(no_landmark, ids, points[:3], observed, K, **OPTIONS, distinct=distinct,
                                distinct_radius=radius, distinct_ratio=0.7)  # fmt: skip
        return sorted(fusion.observed_ids.tolist())

    # Landmark 1's keypoint moved away: it is fused with none.
    assert fuse(None, 0.0) == [0, 2]
    bearing = np.array([True, True, False])
    # Landmark 0 has a rival 15 px away: not fused within 20 px, fused within 10; landmark 2 is not a bearing.
    assert fuse(bearing, 20.0) == [2]
    assert fuse(bearing, 10.0) == [0, 2]


@pytest.mark.parametrize("kind", ["orb", "odd_width", "float"])
def test_the_bearing_rival_search_takes_the_same_keypoints_as_a_brute_force_search(kind: str) -> None:
    """The rivals of a bearing's keypoint are found on a grid; each query must see exactly the keypoints a check of
    every keypoint takes (squared distance ≤ radius², as ``cKDTree.query_ball_point``), its own keypoint left out,
    so the fused pairs stay the same to the digit. Keypoints at exactly the radius, on the grid's lines, repeated
    spots and queries outside the image included."""
    rng = np.random.default_rng(4)
    radius = 50.0
    keypoints = np.vstack([
        rng.uniform(0.0, 320.0, (300, 2)),
        rng.integers(0, 7, (40, 2)) * radius,  # on the grid's lines (repeats among them)
        np.round(rng.uniform(0.0, 320.0, (40, 2))),
    ])  # fmt: skip
    queries = np.vstack([
        rng.uniform(-60.0, 380.0, (150, 2)),
        keypoints[300:380:2] + rng.choice([-1.0, 1.0], (40, 1)) * [[30.0, 40.0]],  # 3-4-5: exactly 50 px away
        keypoints[301:380:2],  # on a keypoint
    ])  # fmt: skip
    own = rng.integers(-1, len(keypoints), len(queries))
    if kind == "float":
        keypoint_descriptors = rng.normal(0.0, 1.0, (len(keypoints), 16)).astype(np.float32)
        query_descriptors = rng.normal(0.0, 1.0, (len(queries), 16)).astype(np.float32)
    else:
        width = 32 if kind == "orb" else 31
        keypoint_descriptors = random_descriptors(rng, len(keypoints), width)
        query_descriptors = random_descriptors(rng, len(queries), width)
    # Half the queries carry their own keypoint's descriptor: were it not left out, it would be the closest.
    copied = np.flatnonzero((own >= 0) & (np.arange(len(queries)) % 2 == 0))
    query_descriptors[copied] = keypoint_descriptors[own[copied]]

    fast = _closest_rival(keypoints, keypoint_descriptors, queries, query_descriptors, own, radius)

    tree = cKDTree(keypoints)
    reference = np.full(len(queries), np.inf)
    sizes = []
    for q, (x, y) in enumerate(queries.tolist()):
        near = [
            k for k, (u, v) in enumerate(keypoints.tolist()) if (x - u) * (x - u) + (y - v) * (y - v) <= radius * radius
        ]
        assert sorted(tree.query_ball_point(queries[q], radius)) == near
        rivals = np.array([k for k in near if k != own[q]], np.intp)
        sizes.append(len(rivals))
        if len(rivals):
            reference[q] = pair_distances(keypoint_descriptors, query_descriptors, rivals,
                                          np.full(len(rivals), q, np.intp)).min()  # fmt: skip
    # The data reach the cases that matter: queries without rivals, and ties at exactly the radius.
    assert min(sizes) == 0 and max(sizes) > 10
    assert np.array_equal(fast, reference)
