"""An agent recognises a peer's keyframes in its own memory (rendered views of one room, the peer mapping in a
frame of its own) and, once the closures agree at several places, places the peer's map frame in its own."""

from __future__ import annotations

import numpy as np

from fleetslam.datasets.base import Intrinsics
from fleetslam.fusion.collaboration import CollaborationConfig, InterAgentLinker
from fleetslam.fusion.consistency import PairClosure
from fleetslam.fusion.keyframe_summary import summarize
from fleetslam.geometry import invert, pose_from_xyz_rpy, rotation_angle
from fleetslam.slam.frontend import KeyframeFeatures, KeyframeObservation
from fleetslam.slam.loop_closure import make_loop_closure_detector
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.peer_recognition import make_peer_recognizer

from ..slam.test_peer_recognition import camera_pose, features_of
from ..slam.textured_room import make_textures

CAMERA = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
#: The peer's map frame in this agent's (what the agents must find).
PEER_MAP = pose_from_xyz_rpy(3.0, -1.0, 0.0, 0.0, 0.0, np.radians(-120.0))
PLACES = [(-1.0, -1.0, 225.0), (1.0, -1.0, 315.0), (1.0, 1.0, 45.0), (-1.0, 1.0, 135.0)]
"""Views into the nearest corner of the room (two walls: a view of one plane is not believed)."""


def test_a_peer_map_frame_is_found_from_closures_at_several_places() -> None:
    textures = make_textures(np.random.default_rng(11))
    detector = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(), CAMERA.K)
    own_poses = {}
    for index, (x, y, yaw) in enumerate(PLACES):
        pose = camera_pose(x, y, yaw)
        keypoints, points, descriptors = features_of(pose, CAMERA, textures)
        observation = KeyframeObservation(float(index), pose, KeyframeFeatures(keypoints, points, descriptors))
        own_poses[detector.process(observation).query_id] = pose
    recognizer = make_peer_recognizer(LoopClosureConfig(), detector.memory, CAMERA.K)
    linker = InterAgentLinker("c3po", CollaborationConfig(budget_ms=60_000.0))

    for index, (x, y, yaw) in enumerate(PLACES):
        seen_from = camera_pose(x + 0.15, y - 0.1, yaw + 6.0)  # the peer passes near each place
        keypoints, points, descriptors = features_of(seen_from, CAMERA, textures)
        in_peer_map = invert(PEER_MAP) @ seen_from
        linker.queue_summary(summarize("r2d2", 100 + index, 0, in_peer_map, CAMERA, keypoints, points, descriptors))
        linker.queue_summary(summarize("c3po", 5, 0, np.eye(4), CAMERA, keypoints, points, descriptors))  # own: ignored
        matches = linker.step(recognizer, own_poses)
        assert len(matches) == 1, linker.peers["r2d2"].decision
        if index < 2:
            assert linker.alignment("r2d2") is None  # not before three closures at two places

    alignment = linker.alignment("r2d2")
    assert alignment is not None, linker.peers["r2d2"].decision
    error = invert(PEER_MAP) @ alignment
    assert np.linalg.norm(error[:3, 3]) < 0.05
    assert np.degrees(rotation_angle(error)) < 1.0
    # The reference agent's frame is the fleet frame; this agent is placed through its aligned peer.
    assert linker.fleet_transform("c3po", {}) is not None
    fleet_from_r2d2 = pose_from_xyz_rpy(1.0, 2.0, 0.0, 0.0, 0.0, 0.3)
    placed = InterAgentLinker("r2d2")
    assert placed.fleet_transform("c3po", {"c3po": np.eye(4)}) is None  # no closures yet
    own = linker.fleet_transform("r2d2", {"r2d2": fleet_from_r2d2})
    np.testing.assert_allclose(own, fleet_from_r2d2 @ invert(alignment))


def test_a_flooding_peer_cannot_grow_the_queue() -> None:
    linker = InterAgentLinker("c3po", CollaborationConfig(max_queued=5))
    summary = summarize(
        "r2d2", 1, 0, np.eye(4), CAMERA, np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 32), np.uint8)
    )
    for _ in range(50):
        linker.queue_summary(summary)
    assert len(linker.queue) == 5 and linker.dropped == 45


def test_a_restarted_peer_loses_its_closures_and_queued_keyframes() -> None:
    linker = InterAgentLinker("c3po")
    empty = (np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 32), np.uint8))
    linker.queue_summary(summarize("r2d2", 1, 0, np.eye(4), CAMERA, *empty, epoch=11))
    state = linker.peer("r2d2")
    state.closures.add(PairClosure(1, 1, np.eye(4), np.eye(4), np.eye(4)))
    assert len(state.closures.closures) == 1 and state.epoch == 11
    linker.queue_summary(summarize("r2d2", 1, 0, np.eye(4), CAMERA, *empty, epoch=12))  # r2d2 restarted
    state = linker.peer("r2d2")
    assert state.restarts == 1 and state.epoch == 12 and state.closures.closures == []
    assert [s.epoch for s in linker.queue] == [12]


def test_a_summary_that_names_no_run_is_still_recognised() -> None:
    """Epoch 0 (a sender that does not say which run) is not taken for a restarted peer's old keyframe."""
    linker = InterAgentLinker("c3po", CollaborationConfig(budget_ms=60_000.0))
    recognizer = make_peer_recognizer(
        LoopClosureConfig(), make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(), CAMERA.K).memory, CAMERA.K
    )
    empty = (np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 32), np.uint8))
    linker.peer("r2d2").epoch = 5
    linker.queue_summary(summarize("r2d2", 1, 0, np.eye(4), CAMERA, *empty))
    linker.queue_summary(summarize("r2d2", 2, 0, np.eye(4), CAMERA, *empty, epoch=5))
    linker.step(recognizer, {})
    assert linker.peer("r2d2").recognised == 2 and not linker.queue
