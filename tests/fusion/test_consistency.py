"""Inter-agent closures believed only when they agree: repeated structure along an aisle is not accepted."""

from __future__ import annotations

import itertools

import numpy as np

from fleetslam.fusion.consistency import (
    ClosureSet,
    ConsistencyTolerance,
    PairClosure,
    consistent,
    fit_alignment,
    maximum_clique,
)
from fleetslam.geometry import invert, pose_from_xyz_rpy, rotation_angle

#: Where the peer's map frame truly lies in this agent's map frame.
TRUE_ALIGNMENT = pose_from_xyz_rpy(4.0, -3.0, 0.0, 0.0, 0.0, np.radians(70.0))
IDS = itertools.count(1)
SHELF_PERIOD = pose_from_xyz_rpy(2.4, 0.0, 0.0, 0.0, 0.0, 0.0)
"""The aisle repeats every 2.4 m along this agent's x axis."""


def closure(own_x: float, own_y: float, rng: np.random.Generator, *, shifted: bool = False) -> PairClosure:
    """This agent's keyframe at (own_x, own_y), the peer's keyframe 0.5 m ahead of it, both with drift-like noise;
    ``shifted``: the peer keyframe really faces the next shelf module (a wrong, repeated-structure match)."""
    own_pose = pose_from_xyz_rpy(own_x, own_y, 0.3, 0.0, 0.0, rng.uniform(-np.pi, np.pi))
    relative = pose_from_xyz_rpy(0.0, 0.0, 0.5, 0.0, 0.0, 0.2)
    peer_in_own = own_pose @ relative
    if shifted:
        peer_in_own = SHELF_PERIOD @ peer_in_own
    peer_pose = invert(TRUE_ALIGNMENT) @ peer_in_own
    noise = pose_from_xyz_rpy(*rng.normal(0.0, 0.02, 3), *rng.normal(0.0, np.radians(0.5), 3))
    own_id, peer_id = next(IDS), next(IDS)
    return PairClosure(own_id, peer_id, own_pose, peer_pose @ noise, relative)


def test_closures_on_the_same_map_frame_are_consistent_and_a_shifted_one_is_not() -> None:
    rng = np.random.default_rng(0)
    a, b = closure(0.0, 0.0, rng), closure(3.0, 1.0, rng)
    wrong = closure(1.5, 0.5, rng, shifted=True)
    tolerance = ConsistencyTolerance()
    assert consistent(a, b, tolerance)
    assert not consistent(a, wrong, tolerance)
    assert not consistent(b, wrong, tolerance)


def test_maximum_clique_finds_the_largest_mutually_consistent_set() -> None:
    adjacency = [{1, 2}, {0, 2}, {0, 1}, {4}, {3}]
    assert maximum_clique(adjacency) == [0, 1, 2]
    assert maximum_clique(adjacency, among={3, 4}) == [3, 4]
    assert maximum_clique([]) == []


def test_three_closures_at_two_places_align_the_maps() -> None:
    rng = np.random.default_rng(1)
    closures = ClosureSet()
    for x, y in [(0.0, 0.0), (0.2, 0.1), (3.0, 2.0)]:
        closures.add(closure(x, y, rng))
    decision = closures.decide()
    assert decision.alignment is not None, decision.reason
    error = invert(TRUE_ALIGNMENT) @ decision.alignment
    assert np.linalg.norm(error[:3, 3]) < 0.1
    assert np.degrees(rotation_angle(error)) < 2.0


def test_one_place_seen_many_times_is_not_enough() -> None:
    rng = np.random.default_rng(2)
    closures = ClosureSet()
    for _ in range(6):
        closures.add(closure(1.0, 1.0, rng))
    decision = closures.decide()
    assert decision.alignment is None
    assert "place" in decision.reason


def test_places_on_either_side_count_for_a_judge_of_both_agents() -> None:
    """This agent turns on one spot while the peer passes it: one place of this agent's, three of the peer's. Its own
    test waits; the peer's (the same closures seen from the other side) accepts; the fleet back-end, judging both
    agents' closures, accepts as the peer does."""
    rng = np.random.default_rng(4)
    closures = []
    for yaw, ahead in [(0.0, 1.0), (0.6, 2.0), (1.2, 3.0)]:
        own_pose = pose_from_xyz_rpy(1.0, 1.0, 0.3, 0.0, 0.0, yaw)
        peer_in_own = own_pose @ pose_from_xyz_rpy(0.0, 0.0, ahead, 0.0, 0.0, 0.1)
        noise = pose_from_xyz_rpy(*rng.normal(0.0, 0.01, 3), *rng.normal(0.0, np.radians(0.3), 3))
        peer_pose = invert(TRUE_ALIGNMENT) @ peer_in_own @ noise
        closures.append(PairClosure(next(IDS), next(IDS), own_pose, peer_pose, invert(own_pose) @ peer_in_own))
    own_side, peer_side, both_sides = ClosureSet(), ClosureSet(), ClosureSet(places_either_side=True)
    for c in closures:
        own_side.add(c)
        peer_side.add(PairClosure(c.peer_id, c.own_id, c.peer_pose, c.own_pose, invert(c.relative)))
        both_sides.add(c)
    assert own_side.decide().alignment is None and "place" in own_side.decide().reason
    assert peer_side.decide().alignment is not None, peer_side.decide().reason
    decision = both_sides.decide()
    assert decision.alignment is not None, decision.reason
    error = invert(TRUE_ALIGNMENT) @ decision.alignment
    assert np.linalg.norm(error[:3, 3]) < 0.1


def test_repeated_shelves_along_an_aisle_are_never_accepted() -> None:
    """Walking an aisle, the peer's keyframes match the next module as well as the right one: two consistent
    sets of the same size. Nothing is accepted until places outside the aisle tell them apart, and then the
    right alignment is."""
    rng = np.random.default_rng(3)
    closures = ClosureSet()
    for step in range(5):
        x = 0.6 * step
        closures.add(closure(x, 0.0, rng, shifted=True))
        closures.add(closure(x + 0.3, 0.0, rng))
        decision = closures.decide()
        assert decision.alignment is None, f"accepted inside the aisle at step {step}: {decision.reason}"
    assert "ambiguous" in decision.reason
    for x, y in [(6.0, 4.0), (-3.0, 5.0), (8.0, -2.0), (-4.0, -4.0), (2.0, 7.0), (9.0, 6.0)]:
        closures.add(closure(x, y, rng))
    decision = closures.decide()
    assert decision.alignment is not None, decision.reason
    error = invert(TRUE_ALIGNMENT) @ decision.alignment
    assert np.linalg.norm(error[:3, 3]) < 0.1
    assert decision.rival == 5


def test_the_oldest_closures_leave_a_full_set() -> None:
    rng = np.random.default_rng(4)
    closures = ClosureSet(max_closures=4)
    for x in range(6):
        closures.add(closure(float(x), 0.0, rng))
    assert len(closures.closures) == 4
    assert closures.decide().inliers == [0, 1, 2, 3]


def test_fit_alignment_of_exact_closures_is_exact() -> None:
    rng = np.random.default_rng(5)
    exact = []
    for x, y in [(0.0, 0.0), (2.0, 1.0)]:
        c = closure(x, y, rng)
        exact.append(PairClosure(0, 0, c.own_pose, invert(TRUE_ALIGNMENT) @ c.own_pose @ c.relative, c.relative))
    np.testing.assert_allclose(fit_alignment(exact), TRUE_ALIGNMENT, atol=1e-9)


def test_the_same_pair_of_keyframes_counts_once() -> None:
    rng = np.random.default_rng(6)
    closures = ClosureSet()
    first = closure(0.0, 0.0, rng)
    assert closures.add(first)
    assert not closures.add(PairClosure(first.own_id, first.peer_id, first.own_pose, first.peer_pose, first.relative))
    assert len(closures.closures) == 1
