"""Keyframe graphs as deltas: a mirror built from them equals the writer's graph, gaps are noticed and healed by
a full graph on request, and a steady run sends only what changed."""

from __future__ import annotations

import numpy as np

from fleetslam.fusion.graph_exchange import GraphDeltaWriter, GraphMirror, GraphUpdate
from fleetslam.geometry import pose_from_xyz_rpy


def grow(poses: dict, stamps: dict, constraints: list, count: int) -> None:
    for _ in range(count):
        i = len(poses)
        poses[i] = pose_from_xyz_rpy(0.3 * i, 0.0, 0.0, 0.0, 0.0, 0.05 * i)
        stamps[i] = float(i)
        if i:
            constraints.append(("odometry", i - 1, i))


def assert_same(mirror: GraphMirror, poses: dict, constraints: list) -> None:
    assert mirror.synced
    assert sorted(mirror.poses) == sorted(poses)
    for i, pose in poses.items():
        np.testing.assert_allclose(mirror.poses[i], pose, atol=0.01)
    assert mirror.constraints == constraints


def test_a_mirror_of_deltas_equals_the_graph_and_deltas_carry_only_changes() -> None:
    writer: GraphDeltaWriter = GraphDeltaWriter()
    mirror: GraphMirror = GraphMirror()
    poses, stamps, constraints = {}, {}, []
    sizes = []
    for _ in range(10):
        grow(poses, stamps, constraints, 3)
        update = writer.update(poses, stamps, constraints)
        assert update is not None and not update.full
        sizes.append(len(update.poses))
        assert mirror.apply(update)
    assert sizes == [3] * 10
    assert_same(mirror, poses, constraints)
    assert writer.update(poses, stamps, constraints) is None  # nothing changed, nothing sent
    # A loop closure moves every pose: one update carries them all and the new constraint, once.
    correction = pose_from_xyz_rpy(0.0, 0.05, 0.0, 0.0, 0.0, 0.01)
    for i in poses:
        poses[i] = correction @ poses[i]
    constraints.append(("loop", 0, 29))
    update = writer.update(poses, stamps, constraints)
    assert update is not None and len(update.poses) == 30 and update.constraints == [("loop", 0, 29)]
    assert mirror.apply(update)
    assert_same(mirror, poses, constraints)
    # A pose that moved less than the threshold is not re-sent.
    poses[5] = pose_from_xyz_rpy(0.0005, 0.0, 0.0, 0.0, 0.0, 0.0) @ poses[5]
    assert writer.update(poses, stamps, constraints) is None


def test_a_gap_is_noticed_and_the_full_graph_with_the_deltas_after_it_heals_it() -> None:
    writer: GraphDeltaWriter = GraphDeltaWriter()
    mirror: GraphMirror = GraphMirror()
    poses, stamps, constraints = {}, {}, []
    grow(poses, stamps, constraints, 2)
    assert mirror.apply(writer.update(poses, stamps, constraints))
    grow(poses, stamps, constraints, 2)
    writer.update(poses, stamps, constraints)  # lost on the way
    grow(poses, stamps, constraints, 2)
    assert not mirror.apply(writer.update(poses, stamps, constraints))
    assert not mirror.synced
    # The reader asks; before the answer arrives, another delta comes in.
    answer = writer.full(poses, stamps, constraints)
    grow(poses, stamps, constraints, 2)
    assert not mirror.apply(writer.update(poses, stamps, constraints))
    assert mirror.apply(answer)
    assert_same(mirror, poses, constraints)


def test_a_late_reader_starts_from_a_full_graph() -> None:
    writer: GraphDeltaWriter = GraphDeltaWriter()
    poses, stamps, constraints = {}, {}, []
    for _ in range(5):
        grow(poses, stamps, constraints, 2)
        writer.update(poses, stamps, constraints)
    late: GraphMirror = GraphMirror()
    grow(poses, stamps, constraints, 1)
    assert not late.apply(writer.update(poses, stamps, constraints))
    assert late.apply(writer.full(poses, stamps, constraints))
    assert_same(late, poses, constraints)
    # An old full graph after newer deltas is ignored.
    stale = GraphUpdate(1, True, {}, {}, [], writer.epoch)
    assert late.apply(stale) and len(late.poses) == len(poses)


def test_a_restarted_writer_graph_is_sent_whole() -> None:
    writer: GraphDeltaWriter = GraphDeltaWriter()
    poses, stamps, constraints = {}, {}, []
    grow(poses, stamps, constraints, 4)
    writer.update(poses, stamps, constraints)
    poses, stamps, constraints = {}, {}, []
    grow(poses, stamps, constraints, 1)
    update = writer.update(poses, stamps, constraints)
    assert update is not None and update.full and sorted(update.poses) == [0]


def test_a_restarted_writer_is_a_new_epoch_and_the_mirror_starts_over() -> None:
    writer: GraphDeltaWriter = GraphDeltaWriter()
    mirror: GraphMirror = GraphMirror()
    poses, stamps, constraints = {}, {}, []
    for _ in range(5):
        grow(poses, stamps, constraints, 2)
        assert mirror.apply(writer.update(poses, stamps, constraints))
    restarted: GraphDeltaWriter = GraphDeltaWriter()  # the agent's SLAM started again: a new map frame
    assert restarted.epoch != writer.epoch
    poses, stamps, constraints = {}, {}, []
    grow(poses, stamps, constraints, 3)
    update = restarted.update(poses, stamps, constraints)
    assert update is not None and update.sequence == 1  # would read as an old duplicate without the epoch
    assert mirror.apply(update)
    assert mirror.epoch == restarted.epoch
    assert_same(mirror, poses, constraints)
