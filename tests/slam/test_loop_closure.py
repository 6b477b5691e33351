"""Loop-closure detection end to end on a synthetic world, and PnP geometric verification."""

from __future__ import annotations

import numpy as np

from fleetslam.geometry import invert, rotation_angle, translation_distance
from fleetslam.slam.loop_closure import (
    GeometricVerifier,
    LoopClosureDetector,
    make_loop_closure_detector,
    off_plane_count,
)
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.signature import LinkType, Signature

from .loop_scene import CAMERA_MATRIX, Place, make_place, observe, place_pose, revisit_pose


def feed(detector: LoopClosureDetector, rng: np.random.Generator, place: Place, pose: np.ndarray, stamp: float):
    obs = observe(rng, place, pose)
    return detector.process(obs.keyframe(stamp))


def test_planted_revisit_is_detected_and_new_places_are_not() -> None:
    rng = np.random.default_rng(10)
    # 25 places, revisited from the 6th: a short-term memory of 10 (RTAB-Map's) leaves them loop candidates.
    detector = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(stm_size=10), CAMERA_MATRIX)
    places = [make_place(rng, place_pose(k)) for k in range(25)]
    for k, place in enumerate(places):
        hyp = feed(detector, rng, place, place.pose, float(k))
        assert hyp.query_id == k + 1
        assert not hyp.accepted, hyp
    revisited = [5, 6, 7, 8]
    accepted = []
    for step, k in enumerate(revisited):
        hyp = feed(detector, rng, places[k], revisit_pose(places[k]), 100.0 + step)
        if hyp.accepted:
            accepted.append(hyp)
            assert hyp.match_id == k + 1, hyp
            assert hyp.probability >= 0.11
            assert hyp.inliers >= 20
            assert hyp.transform is not None
            truth = invert(places[k].pose) @ revisit_pose(places[k])
            # 0.3 px keypoint noise over >100 inliers at 2-6 m: ~1 mm and 0.02° measured; bounds are what a loop
            # constraint may carry (its σ is 2 cm / 1°), far above the estimate's own spread.
            assert translation_distance(hyp.transform, truth) < 0.05
            assert rotation_angle(invert(hyp.transform) @ truth) < np.radians(1.0)
            link = detector.memory.signatures[k + 1].links[hyp.query_id]
            assert link.type == LinkType.LOOP
    assert len(accepted) >= 2, "the revisit should close loops within a few keyframes"
    # New places after the revisit never fire; the posterior, which carries the revisit over for a few
    # keyframes through the prediction, returns to the virtual place.
    values = []
    for k in range(40, 47):
        fresh = make_place(rng, place_pose(k))
        hyp = feed(detector, rng, fresh, fresh.pose, 200.0 + k)
        assert not hyp.accepted
        values.append(hyp.probability)
    assert values == sorted(values, reverse=True)
    assert values[-1] < 0.11, values


def test_posterior_of_a_new_place_stays_on_the_virtual_place() -> None:
    rng = np.random.default_rng(11)
    detector = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(stm_size=3), CAMERA_MATRIX)
    for k in range(15):
        place = make_place(rng, place_pose(k))
        hyp = feed(detector, rng, place, place.pose, float(k))
        assert not hyp.accepted
    assert detector.last_posterior[-1] > 0.89
    assert all(location not in detector.last_posterior for location in detector.memory.stm)


def make_signature(id_: int, obs, word_ids: np.ndarray) -> Signature:
    return Signature(
        id=id_,
        stamp=0.0,
        pose=obs.pose,
        keypoints=obs.keypoints.astype(np.float32),
        points3d=obs.points3d.astype(np.float32),
        descriptors=obs.descriptors,
        word_ids=word_ids,
    )


def test_geometric_verification_recovers_known_transform_and_rejects_wrong_match() -> None:
    rng = np.random.default_rng(12)
    place = make_place(rng, place_pose(0), n_points=120)
    candidate_obs = observe(rng, place, place.pose)
    query_pose = revisit_pose(place)
    query_obs = observe(rng, place, query_pose)
    # Each landmark is one word: word ids are the indices of the visible landmarks.
    verifier = GeometricVerifier(CAMERA_MATRIX, min_inliers=20, correspondences="words")
    cand_ids = landmark_ids(place, place.pose)
    query_ids = landmark_ids(place, query_pose)
    candidate = make_signature(1, candidate_obs, cand_ids)
    query = make_signature(2, query_obs, query_ids)
    result = verifier.verify(query, candidate)
    assert result.accepted, result
    assert result.inliers >= 0.9 * result.correspondences  # 0.3 px noise vs a 2-3 px RANSAC threshold: all
    truth = invert(place.pose) @ query_pose
    assert result.transform is not None
    # ~100 correspondences with 0.3 px noise at 2-6 m: 1.8 mm, 0.03° measured (same on every SIMD path).
    assert translation_distance(result.transform, truth) < 0.02
    assert rotation_angle(invert(result.transform) @ truth) < np.radians(0.5)

    # Same words, but the candidate's 3D points belong to other landmarks: no consistent pose.
    wrong = make_signature(1, candidate_obs, rng.permutation(cand_ids))
    rejected = verifier.verify(query, wrong)
    assert not rejected.accepted
    assert rejected.inliers < 20
    assert "inliers" in rejected.reason

    # A candidate sharing no word is rejected before RANSAC.
    unrelated = make_signature(1, candidate_obs, cand_ids + 10_000)
    none = verifier.verify(query, unrelated)
    assert not none.accepted and none.correspondences == 0


def test_descriptor_verification_matches_features_and_rejects_a_repeated_pattern() -> None:
    rng = np.random.default_rng(15)
    place = make_place(rng, place_pose(0), n_points=150)
    query_pose = revisit_pose(place)
    # No visual words at all: the default verifier re-matches the two locations' descriptors.
    candidate = make_signature(1, observe(rng, place, place.pose), np.zeros(0, np.int64))
    query = make_signature(2, observe(rng, place, query_pose), np.zeros(0, np.int64))
    verifier = GeometricVerifier(CAMERA_MATRIX, min_inliers=20)
    result = verifier.verify(query, candidate)
    assert result.accepted, result
    truth = invert(place.pose) @ query_pose
    assert result.transform is not None
    # As above: 1.3 mm, 0.03° measured.
    assert translation_distance(result.transform, truth) < 0.02
    assert rotation_angle(invert(result.transform) @ truth) < np.radians(0.5)

    # The candidate's descriptors match, but its 3D points are another arrangement of the same-looking
    # features (a repeated pattern seen elsewhere): PnP must not find a pose that explains them.
    shuffled = Signature(
        id=1,
        stamp=0.0,
        pose=candidate.pose,
        keypoints=candidate.keypoints,
        points3d=candidate.points3d[rng.permutation(len(candidate.points3d))],
        descriptors=candidate.descriptors,
    )
    rejected = verifier.verify(query, shuffled)
    assert not rejected.accepted
    assert "inliers" in rejected.reason or "disagree" in rejected.reason


def test_verification_expresses_the_transform_in_base_frames() -> None:
    rng = np.random.default_rng(13)
    place = make_place(rng, place_pose(0), n_points=100)
    query_pose = revisit_pose(place)
    candidate = make_signature(1, observe(rng, place, place.pose, pixel_noise=0.0), landmark_ids(place, place.pose))
    query = make_signature(2, observe(rng, place, query_pose, pixel_noise=0.0), landmark_ids(place, query_pose))
    base_camera = np.array([[0.0, 0.0, 1.0, 0.1], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.3], [0, 0, 0, 1.0]])
    result = GeometricVerifier(CAMERA_MATRIX, camera_to_base=base_camera).verify(query, candidate)
    assert result.transform is not None
    truth_base = base_camera @ invert(place.pose) @ query_pose @ invert(base_camera)
    # Noise-free pixels: only EPnP + LM convergence (1e-6 relative) and float round-off remain.
    np.testing.assert_allclose(result.transform, truth_base, atol=1e-4)


def landmark_ids(place: Place, pose: np.ndarray) -> np.ndarray:
    """Indices of the landmarks visible from ``pose`` in the order :func:`observe` returns them."""
    from fleetslam.geometry import transform_points

    from .loop_scene import HEIGHT, WIDTH

    local = transform_points(invert(pose), place.points_world)
    uv = (CAMERA_MATRIX @ local.T).T
    uv = uv[:, :2] / uv[:, 2:3]
    visible = (local[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < WIDTH) & (uv[:, 1] >= 0) & (uv[:, 1] < HEIGHT)
    return np.flatnonzero(visible).astype(np.int64)


def test_retrieval_brings_ltm_neighbours_back_for_the_next_loop() -> None:
    rng = np.random.default_rng(14)
    detector = make_loop_closure_detector(
        LoopClosureConfig(), MemoryConfig(stm_size=2, max_wm_size=6, max_retrieved=2), CAMERA_MATRIX
    )
    places = [make_place(rng, place_pose(k)) for k in range(20)]
    for k, place in enumerate(places):
        feed(detector, rng, place, place.pose, float(k))
    memory = detector.memory
    assert len(memory.wm) <= 6 and len(memory.ltm) >= 12
    # Going backwards through the map: a WM location whose predecessor is in LTM.
    target = max(i for i in memory.wm_ids() if i - 1 in memory.ltm)
    hyp = feed(detector, rng, places[target - 1], revisit_pose(places[target - 1]), 100.0)
    assert hyp.match_id == target
    assert target - 1 in hyp.retrieved
    assert memory.where(target - 1) == "wm"
    assert not set(hyp.retrieved) & set(hyp.transferred)
    hyp = feed(detector, rng, places[target - 2], revisit_pose(places[target - 2]), 101.0)
    assert hyp.accepted and hyp.match_id == target - 1, hyp


def test_off_plane_count_finds_the_points_off_the_plane_holding_most() -> None:
    rng = np.random.default_rng(5)
    floor = np.column_stack([rng.uniform(-2, 2, 60), rng.uniform(0.5, 4, 60), np.full(60, 1.2)])
    floor[:, 2] += rng.normal(0.0, 0.005, 60)  # depth noise
    shelf = np.column_stack([rng.uniform(-2, 2, 9), np.full(9, 3.0), rng.uniform(-0.5, 1.0, 9)])
    assert off_plane_count(floor, 0.05) == 0
    assert off_plane_count(np.vstack([floor, shelf]), 0.05) == 9
    tilted = floor @ np.array([[1.0, 0.0, 0.0], [0.0, 0.8, -0.6], [0.0, 0.6, 0.8]]).T  # any plane, not only z = c
    assert off_plane_count(np.vstack([tilted, shelf[:3]]), 0.05) == 3
    assert off_plane_count(shelf[:3], 0.05) == 0  # three points always lie on a plane
