"""The pose arithmetic of following the fleet back-end's corrections: corrected, chained, not corrected."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.fusion.fleet_correction import FleetCorrection, corrected_poses, stamp_key
from fleetslam.geometry import invert, pose_from_xyz_rpy, random_pose


def _scene() -> tuple[dict[int, np.ndarray], dict[int, float], dict[int, np.ndarray], np.ndarray]:
    """Five keyframes of one agent: own poses, stamps, their true poses in the fleet frame, and the placement."""
    rng = np.random.default_rng(4)
    T_fleet_map = pose_from_xyz_rpy(3.0, -1.0, 0.2, 0.05, -0.02, 0.8)
    true_fleet = {i: random_pose(rng, 3.0) for i in range(5)}
    # The agent's own graph: the truth in its map frame, bent by an error growing along the run.
    own = {i: invert(T_fleet_map) @ pose_from_xyz_rpy(0.1 * i, 0.05 * i, 0.0, 0.0, 0.0, 0.03 * i) @ true_fleet[i]
           for i in true_fleet}  # fmt: skip
    stamps = {i: 1_700_000_000.1 + 0.7 * i for i in own}
    return own, stamps, true_fleet, T_fleet_map


def test_corrected_keyframes_land_where_the_backend_put_them_through_the_placement() -> None:
    own, stamps, true_fleet, T_fleet_map = _scene()
    corrected = {stamp_key(stamps[i]): true_fleet[i] for i in own}
    poses, chain = corrected_poses(own, stamps, corrected, T_fleet_map)
    for i in own:  # landed by the placement, each keyframe is where the back-end put it
        np.testing.assert_allclose(T_fleet_map @ poses[i], true_fleet[i], atol=1e-9)
    # The chain moves a keyframe newer than the graph as the newest corrected one was moved.
    np.testing.assert_allclose(chain, poses[4] @ invert(own[4]), atol=1e-12)


def test_keyframes_the_backend_does_not_know_follow_their_own_graph_from_the_nearest_corrected_one() -> None:
    own, stamps, true_fleet, T_fleet_map = _scene()
    corrected = {stamp_key(stamps[i]): true_fleet[i] for i in (1, 2)}  # 0 before them, 3 and 4 after
    poses, chain = corrected_poses(own, stamps, corrected, T_fleet_map)
    to_map = invert(T_fleet_map)
    np.testing.assert_allclose(poses[1], to_map @ true_fleet[1], atol=1e-9)
    np.testing.assert_allclose(poses[2], to_map @ true_fleet[2], atol=1e-9)
    for i in (3, 4):  # newer: their own motion since keyframe 2, continued from keyframe 2's correction
        np.testing.assert_allclose(invert(poses[2]) @ poses[i], invert(own[2]) @ own[i], atol=1e-9)
    # Older than every corrected keyframe: from the first corrected one.
    np.testing.assert_allclose(invert(poses[1]) @ poses[0], invert(own[1]) @ own[0], atol=1e-9)
    np.testing.assert_allclose(chain, poses[2] @ invert(own[2]), atol=1e-12)
    # Their own relative poses are bent, so they are not where the truth is: nothing corrected them.
    assert np.linalg.norm((T_fleet_map @ poses[4])[:3, 3] - true_fleet[4][:3, 3]) > 0.05


def test_without_corrections_every_keyframe_keeps_its_own_pose() -> None:
    own, stamps, true_fleet, T_fleet_map = _scene()
    other_run = {stamp_key(stamps[i] + 1000.0): true_fleet[i] for i in own}  # stamps of no keyframe of this graph
    for corrected in ({}, other_run):
        poses, chain = corrected_poses(own, stamps, corrected, T_fleet_map)
        np.testing.assert_array_equal(chain, np.eye(4))
        for i in own:
            np.testing.assert_array_equal(poses[i], own[i])
    follower = FleetCorrection()
    assert not follower.active
    poses, chain = follower.poses(own, stamps)  # nothing heard from the back-end
    assert all(np.array_equal(poses[i], own[i]) for i in own) and np.array_equal(chain, np.eye(4))
    follower.set_path(np.array([stamp_key(stamps[0])]), true_fleet[0][None], "fleet")
    assert not follower.active  # a path without a placement cannot be expressed in the map frame
    follower.set_placement(T_fleet_map, "fleet")
    assert follower.active
    poses, _ = follower.poses(own, stamps)
    np.testing.assert_allclose(T_fleet_map @ poses[0], true_fleet[0], atol=1e-9)
    with pytest.raises(ValueError, match="frame 'world'"):
        follower.set_path(np.array([stamp_key(stamps[0])]), true_fleet[0][None], "world")
    follower.set_placement(T_fleet_map, "world")  # another fleet frame: the path in the old one is dropped
    assert not follower.active


def test_a_placement_that_moved_less_than_the_tolerance_is_not_taken() -> None:
    """As the fleet map keeps landing the map by the placement it took, the keyframes keep theirs."""
    follower = FleetCorrection(placement_tolerance=0.05)
    T_fleet_map = pose_from_xyz_rpy(3.0, -1.0, 0.0, 0.0, 0.0, 0.8)
    assert follower.set_placement(T_fleet_map, "fleet")
    wobble = T_fleet_map @ pose_from_xyz_rpy(0.01, -0.02, 0.0, 0.0, 0.0, 0.002)  # 2.2 cm, 0.11°
    assert not follower.set_placement(wobble, "fleet")
    np.testing.assert_array_equal(follower.T_fleet_map, T_fleet_map)
    turned = T_fleet_map @ pose_from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, 0.006)  # 0.34°: beyond a tenth of 0.05 rad
    assert follower.set_placement(turned, "fleet")
    moved = turned @ pose_from_xyz_rpy(0.06, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert follower.set_placement(moved, "fleet")
    np.testing.assert_array_equal(follower.T_fleet_map, moved)
