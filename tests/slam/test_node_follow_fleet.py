"""A SLAM node that follows the fleet back-end (``follow_fleet``), over a real router: once the back-end placed it
and corrected keyframes of its run, its ``fleet → map`` is the back-end's placement and its ``slam/fleet_pose``
moves as the back-end corrected its newest corrected keyframe; its own localisation stays its own."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from fleetslam import topics
from fleetslam.datasets.base import Intrinsics
from fleetslam.geometry import invert, pose_from_planar, pose_from_xyz_rpy
from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import pose_matrix, pose_msgs, transform_matrix, transform_msg
from fleetslam.msg.typesys import get_type, header, message_from_dict
from fleetslam.slam.frame_queue import FramePair
from fleetslam.slam.node import SlamNode, SlamNodeConfig

from ..support import wait_until
from .textured_room import image_messages, make_textures

BASE_CAMERA = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0, 0, 0, 1.0]])
INTRINSICS = Intrinsics(80.0, 80.0, 40.0, 30.0, 80, 60)


def _feed(slam: SlamNode, frames: range, textures: list[Any]) -> None:
    for k in frames:
        stamp_ns = 1_000_000_000 + k * 100_000_000
        pose = pose_from_planar(0.02 * k, 0.0, 0.0) @ BASE_CAMERA
        pair = FramePair(stamp_ns, *image_messages(pose, stamp_ns, INTRINSICS, textures), time.monotonic())
        with slam._lock:
            assert slam.process(pair) is not None


def test_the_fleet_pose_follows_the_back_end_once_it_corrected_this_run(make_context: Callable[..., Context]) -> None:
    slam = SlamNode(Node("slam", context=make_context("c3po")),
                    SlamNodeConfig(use_wheel_odometry=False, follow_fleet=True))  # fmt: skip
    viewer = Node("viewer", context=make_context())
    fleet_poses: list[Any] = []
    transforms: list[Any] = []
    viewer.create_subscription(topics.FLEET_POSE.type, topics.FLEET_POSE.of("c3po"), fleet_poses.append,
                               topics.FLEET_POSE.qos(depth=50))  # fmt: skip
    viewer.create_subscription(topics.FLEET_TRANSFORM.type, topics.FLEET_TRANSFORM.of("c3po"), transforms.append,
                               topics.FLEET_TRANSFORM.qos(depth=5))  # fmt: skip
    backend = Node("fleet_backend", context=make_context())
    placements_pub = backend.create_publisher(topics.FLEET_PLACEMENTS.type, topics.FLEET_PLACEMENTS.name,
                                              topics.FLEET_PLACEMENTS.qos())  # fmt: skip
    path_pub = backend.create_publisher(topics.FLEET_PATH.type, topics.FLEET_PATH.of("c3po"), topics.FLEET_PATH.qos())
    info = message_from_dict("sensor_msgs/msg/CameraInfo", {"width": 80, "height": 60})
    info.k[:] = [80.0, 0.0, 40.0, 0.0, 80.0, 30.0, 0.0, 0.0, 1.0]
    slam.on_camera_info(info)
    textures = make_textures(np.random.default_rng(0))

    placement = pose_from_xyz_rpy(4.0, -2.0, 0.0, 0.0, 0.0, 0.6)
    # A placement alone (or one left from a run before a reset) is not followed: no keyframe of this run corrected.
    placements_pub.publish(transform_msg(placement, "fleet", "c3po/map", 0))
    assert wait_until(lambda: slam.fleet_correction.T_fleet_map is not None, 10.0)
    _feed(slam, range(8), textures)
    # Not followed: alone, c3po is its own fleet's reference (its map frame is the fleet frame).
    assert wait_until(lambda: len(fleet_poses) == 8 and bool(transforms), 10.0)
    np.testing.assert_allclose(transform_matrix(transforms[-1].transform), np.eye(4), atol=1e-9)
    fleet_poses.clear()

    # The back-end corrected this run's keyframes: shifted 5 cm and turned 1° in the agent's own map frame.
    assert slam.pipeline is not None
    own, stamps = slam.pipeline.keyframe_poses(), slam.pipeline.keyframe_stamps
    correction = pose_from_xyz_rpy(0.05, 0.0, 0.0, 0.0, 0.0, np.radians(1.0))
    corrected = [placement @ correction @ own[i] for i in sorted(own)]

    def fleet_path() -> Any:
        return get_type("nav_msgs/msg/Path")(header=header("fleet", 0), poses=[
            get_type("geometry_msgs/msg/PoseStamped")(header=header("fleet", round(stamps[i] * 1e9)), pose=pose)
            for i, pose in zip(sorted(own), pose_msgs(corrected), strict=True)
        ])  # fmt: skip

    path, bad = fleet_path(), fleet_path()
    bad.poses[0].pose.orientation.w = float("nan")
    path_pub.publish(bad)  # malformed: counted, nothing changes
    assert wait_until(lambda: slam.counts["bad_peer_messages"] == 1, 10.0)
    assert not slam.fleet_correction.corrected
    path_pub.publish(path)
    assert wait_until(lambda: len(slam.fleet_correction.corrected) == len(own), 10.0)
    _feed(slam, range(8, 12), textures)

    assert wait_until(lambda: len(fleet_poses) == 4 and len(transforms) == 2, 10.0)
    np.testing.assert_allclose(transform_matrix(transforms[-1].transform), placement, atol=1e-6)
    assert transforms[-1].header.frame_id == "fleet" and transforms[-1].child_frame_id == "c3po/map"
    newest = max(own)  # the newest corrected keyframe moved the camera as it was moved
    chain = placement @ correction @ own[newest] @ invert(slam.pipeline.keyframe_poses()[newest])
    last = slam.pipeline.result().trajectory.poses[-1]
    got = pose_matrix(fleet_poses[-1].pose)
    np.testing.assert_allclose(got, chain @ last, atol=2e-3)
    # Not the agent's own placement of itself: the correction shows (5 cm).
    assert np.linalg.norm(got[:3, 3] - (placement @ last)[:3, 3]) > 0.03
