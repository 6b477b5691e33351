"""A peer's keyframe, summarised as on the wire, is recognised in this agent's memory and verified: rendered views
of a textured room, real ORB features, a peer with another camera; a view of a tiled floor one tile further on is
not taken for the same place."""

from __future__ import annotations

import numpy as np

from fleetslam.datasets.base import Intrinsics
from fleetslam.fusion.keyframe_summary import summarize
from fleetslam.geometry import invert, make_pose, rotation_angle, so3_exp, so3_log
from fleetslam.slam.features import FeatureExtractor
from fleetslam.slam.frontend import KeyframeFeatures, KeyframeObservation
from fleetslam.slam.loop_closure import GeometricVerifier, make_loop_closure_detector
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.odometry import backproject
from fleetslam.slam.peer_recognition import (
    MIN_OFF_PLANE_INLIERS,
    ClosureQuality,
    PeerMatch,
    PeerPlaceRecognizer,
    closure_information,
    make_peer_recognizer,
    refine_closure,
)

from .textured_room import HALF_SIZE, TEXELS, make_textures, render

OWN = Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
PEER = Intrinsics(fx=300.0, fy=300.0, cx=161.0, cy=118.0, width=320, height=240)
OPTICAL_IN_WORLD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Camera optical axes (x right, y down, z forward) in a z-up world looking along world x."""


def camera_pose(x: float, y: float, yaw_deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return make_pose(yaw @ OPTICAL_IN_WORLD, [x, y, 0.2])


def features_of(pose: np.ndarray, intrinsics: Intrinsics, textures: list[np.ndarray]):
    rgb, depth = render(pose, intrinsics, textures)
    features = FeatureExtractor(max_features=600).detect(rgb[:, :, 0])
    points, valid = backproject(features.keypoints, depth, intrinsics, 0.1, 8.0)
    points[~valid] = np.nan
    return features.keypoints, points, features.descriptors


def own_memory(textures: list[np.ndarray], poses: list[np.ndarray]):
    detector = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(), OWN.K)
    ids = []
    for index, pose in enumerate(poses):
        keypoints, points, descriptors = features_of(pose, OWN, textures)
        hypothesis = detector.process(
            KeyframeObservation(float(index), pose, KeyframeFeatures(keypoints, points, descriptors))
        )
        ids.append(hypothesis.query_id)
    return detector.memory, ids


def test_a_peer_view_of_a_known_place_is_recognised_with_its_transform() -> None:
    textures = make_textures(np.random.default_rng(3))
    # Views into the room's corners: two walls each (a view of one plane only is not believed, see below).
    own_poses = [camera_pose(0.0, 0.0, yaw) for yaw in (45.0, 135.0, 225.0, 315.0)]
    memory, ids = own_memory(textures, own_poses)
    recognizer = make_peer_recognizer(LoopClosureConfig(), memory, OWN.K)

    peer_pose_in_own_world = camera_pose(-0.3, 0.2, 130.0)  # near the view of the (-x, +y) corner, another camera
    keypoints, points, descriptors = features_of(peer_pose_in_own_world, PEER, textures)
    peer_map_pose = make_pose(np.eye(3), [5.0, -2.0, 0.0]) @ peer_pose_in_own_world  # the peer's own frame
    summary = summarize("r2d2", 7, 0, peer_map_pose, PEER, keypoints, points, descriptors)
    result = recognizer.recognize(summary)

    assert result.match is not None, result.reasons
    assert result.match.own_id == ids[1]
    assert (result.match.peer_agent, result.match.peer_id) == ("r2d2", 7)
    truth = invert(own_poses[1]) @ peer_pose_in_own_world
    error = invert(truth) @ result.match.relative
    assert np.linalg.norm(error[:3, 3]) < 0.03
    assert np.degrees(rotation_angle(error)) < 1.0
    assert result.match.off_plane >= MIN_OFF_PLANE_INLIERS
    # Refined with depth, spread over the view, with a covariance that the constraint carries to the fleet.
    assert result.match.covariance is not None and result.match.spread >= ClosureQuality().min_spread
    assert np.sqrt(np.linalg.eigvalsh(result.match.covariance[:3, :3]).max()) < 0.03


def test_a_peer_view_is_verified_with_its_own_inlier_count_not_the_loop_closures() -> None:
    textures = make_textures(np.random.default_rng(3))
    memory, ids = own_memory(textures, [camera_pose(0.0, 0.0, yaw) for yaw in (45.0, 135.0, 225.0, 315.0)])
    peer_pose = camera_pose(-0.3, 0.2, 130.0)
    keypoints, points, descriptors = features_of(peer_pose, PEER, textures)
    summary = summarize("r2d2", 7, 0, peer_pose, PEER, keypoints, points, descriptors)

    strict_peers = LoopClosureConfig(min_inliers=4, peer_min_inliers=10_000)
    refused = make_peer_recognizer(strict_peers, memory, OWN.K).recognize(summary)
    assert refused.match is None
    assert any("(< 10000)" in reason for reason in refused.reasons), refused.reasons
    strict_loops = LoopClosureConfig(min_inliers=10_000)  # the agent's own loops ask nothing of a peer's view
    accepted = make_peer_recognizer(strict_loops, memory, OWN.K).recognize(summary)
    assert accepted.match is not None and accepted.match.own_id == ids[1], accepted.reasons


LOOKING_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
"""Camera optical axes looking straight down at the floor."""


def tiled_floor_room(tile_texels: int) -> tuple[list[np.ndarray], float]:
    """The room with its floor a repeated tile (the plant's floor texture repeats every 2 m): textures, period (m)."""
    textures = make_textures(np.random.default_rng(3))
    floor = textures[4]  # the face at z = -HALF_SIZE
    textures[4] = np.tile(floor[:tile_texels, :tile_texels], (TEXELS // tile_texels, TEXELS // tile_texels))
    return textures, tile_texels * 2 * HALF_SIZE / (TEXELS - 1)


def test_a_view_of_a_tiled_floor_one_period_further_is_not_taken_for_the_same_place() -> None:
    textures, period = tiled_floor_room(128)
    floor_view = make_pose(LOOKING_DOWN, [-0.6, 0.0, 0.2])  # sees the floor only, 2.7 m below
    memory, ids = own_memory(textures, [floor_view] + [camera_pose(0.0, 0.0, yaw) for yaw in (45.0, 135.0, 225.0)])
    peer_pose = make_pose(LOOKING_DOWN, [-0.6 + period, 0.0, 0.2])  # the same image, one tile further on
    keypoints, points, descriptors = features_of(peer_pose, OWN, textures)
    summary = summarize("r2d2", 3, 0, peer_pose, OWN, keypoints, points, descriptors)

    # Without the check the closure passes PnP both ways, with the floor view and exactly one period off.
    unchecked = make_peer_recognizer(LoopClosureConfig(), memory, OWN.K, min_off_plane=0).recognize(summary)
    assert unchecked.match is not None and unchecked.match.own_id == ids[0], unchecked.reasons
    error = invert(invert(floor_view) @ peer_pose) @ unchecked.match.relative
    assert abs(np.linalg.norm(error[:3, 3]) - period) < 0.05

    result = make_peer_recognizer(LoopClosureConfig(), memory, OWN.K).recognize(summary)
    assert result.match is None
    assert any(f"{ids[0]}: 0 inliers off their dominant plane" in reason for reason in result.reasons), result.reasons


def test_a_view_of_another_room_is_not_recognised() -> None:
    memory, _ = own_memory(make_textures(np.random.default_rng(3)), [camera_pose(-1.0, 0.0, 90.0)])
    recognizer = make_peer_recognizer(LoopClosureConfig(), memory, OWN.K)
    elsewhere = make_textures(np.random.default_rng(4))
    keypoints, points, descriptors = features_of(camera_pose(-0.6, 0.3, 100.0), PEER, elsewhere)
    result = recognizer.recognize(summarize("r2d2", 1, 0, np.eye(4), PEER, keypoints, points, descriptors))
    assert result.match is None
    assert len(result.candidates) <= 2


def test_the_recognizer_refuses_a_verifier_in_base_frames() -> None:
    memory, _ = own_memory(make_textures(np.random.default_rng(3)), [camera_pose(-1.0, 0.0, 0.0)])
    mounted = GeometricVerifier(OWN.K, camera_to_base=make_pose(np.eye(3), [0.1, 0.0, 0.3]))
    try:
        PeerPlaceRecognizer(memory, mounted)
    except ValueError as err:
        assert "camera frames" in str(err)
    else:
        raise AssertionError("a verifier with a base mounting was accepted")


# -- refinement and precision of a verified closure ------------------------------------------------------------------
K_QVGA = np.array([[277.0, 0.0, 159.5], [0.0, 277.0, 119.5], [0.0, 0.0, 1.0]])


def _closure_data(
    rng: np.random.Generator, points_candidate: np.ndarray, truth: np.ndarray, *, pixel_noise: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """The query camera's view (``truth`` = ``T_candidate_query``) of the candidate's points: noisy pixels, and
    depths with a Kinect's noise (σ = 1.5e-3·z²)."""
    seen = points_candidate @ invert(truth)[:3, :3].T + invert(truth)[:3, 3]
    pixels = seen[:, :2] / seen[:, 2:3] * 277.0 + [159.5, 119.5] + rng.normal(0.0, pixel_noise, (len(seen), 2))
    depths = seen[:, 2] + rng.normal(0.0, 1.5e-3 * seen[:, 2] ** 2)
    return pixels, depths


def _points_in_view(rng: np.random.Generator, n: int, u: tuple[float, float], v: tuple[float, float],
                    z: tuple[float, float]) -> np.ndarray:  # fmt: skip
    """``n`` points of the candidate's camera seen within the pixel box ``u`` × ``v`` at depths ``z``."""
    pixels = np.column_stack([rng.uniform(*u, n), rng.uniform(*v, n)])
    depth = rng.uniform(*z, n)
    return np.column_stack([(pixels - [159.5, 119.5]) / 277.0 * depth[:, None], depth])


def _error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    difference = invert(truth) @ estimate
    return float(np.linalg.norm(difference[:3, 3])), float(np.degrees(rotation_angle(difference)))


def test_a_closure_spread_over_the_view_is_refined_with_depth_and_gets_its_covariance() -> None:
    rng = np.random.default_rng(5)
    truth = make_pose(so3_exp([0.02, 0.15, -0.01]), [0.25, -0.02, 0.4])  # T_candidate_query
    points = _points_in_view(rng, 60, (10.0, 310.0), (10.0, 230.0), (1.5, 4.5))
    pixels, depths = _closure_data(rng, points, truth)
    pnp = truth @ make_pose(so3_exp([0.0, 0.02, 0.0]), [0.08, 0.0, -0.05])  # 9 cm and 1.1° off, as PnP left some
    refined = refine_closure(pnp, points, pixels, depths, K_QVGA, ClosureQuality(), min_inliers=15)
    assert refined.reason == "accepted", refined.reason
    metres, degrees = _error(refined.relative, truth)
    assert metres < 0.015 and degrees < 0.3, (metres, degrees)
    assert refined.spread > 0.2 and refined.inliers == 60
    # Its covariance is the right perturbation's (relative · exp(ξ), translation first), and covers the error.
    difference = invert(truth) @ refined.relative
    xi = np.concatenate([difference[:3, 3], so3_log(difference[:3, :3])])
    assert float(xi @ np.linalg.solve(refined.covariance, xi)) < 22.5  # χ²₆ at 99.95 %
    assert np.sqrt(np.linalg.eigvalsh(refined.covariance[:3, :3]).max()) < 0.01


def test_a_closure_on_a_small_far_patch_is_not_believed_precise() -> None:
    rng = np.random.default_rng(6)
    truth = make_pose(so3_exp([0.0, 0.1, 0.0]), [0.3, 0.0, 0.2])
    # The benchmark's imprecise closures: most inliers in one patch 4 m away (80 × 25 px), two strays nearer.
    points = np.vstack([_points_in_view(rng, 30, (20.0, 100.0), (90.0, 115.0), (4.1, 4.4)),
                        _points_in_view(rng, 2, (130.0, 190.0), (145.0, 155.0), (2.3, 2.5))])  # fmt: skip
    pixels, depths = _closure_data(rng, points, truth)
    pnp = truth @ make_pose(so3_exp([0.02, 0.0, 0.0]), [0.0, 0.15, 0.1])
    refined = refine_closure(pnp, points, pixels, depths, K_QVGA, ClosureQuality(), min_inliers=15)
    assert refined.reason.startswith("inliers bunched"), refined.reason
    assert refined.spread < ClosureQuality().min_spread
    # Its covariance alone would pass it: with independent noise a patch is precise enough. The benchmark's patches
    # were not (their errors correlated: 10-23 cm off at 2-5 cm of sigma), so a patch is not believed, right or wrong.
    lenient = refine_closure(pnp, points, pixels, depths, K_QVGA, ClosureQuality(min_spread=0.0), min_inliers=15)
    assert lenient.reason == "accepted", lenient.reason


def test_the_covariance_travels_as_the_constraint_information() -> None:
    covariance = np.diag([1e-4, 4e-4, 9e-4, 1e-5, 2e-5, 3e-5])
    match = PeerMatch(1, "r2d2", 2, 0.5, np.eye(4), 40, 12, covariance, 0.15)
    np.testing.assert_allclose(closure_information(match).reshape(6, 6), np.linalg.inv(covariance))
    unrefined = PeerMatch(1, "r2d2", 2, 0.5, np.eye(4), 40, 12)
    assert not closure_information(unrefined).any()  # zeros: the back-end's own closure_sigma stands in


def test_a_closure_its_own_solve_cannot_pin_is_not_believed_precise() -> None:
    rng = np.random.default_rng(7)
    truth = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.2, 0.0, 0.3])
    # Spread over the view, but few points and all far away: their depth is known to ±10 cm.
    points = _points_in_view(rng, 16, (20.0, 300.0), (20.0, 220.0), (7.5, 8.0))
    pixels, depths = _closure_data(rng, points, truth)
    refined = refine_closure(truth, points, pixels, depths, K_QVGA, ClosureQuality(), min_inliers=15)
    assert refined.reason.startswith("imprecise"), refined.reason
    assert refined.spread >= ClosureQuality().min_spread
