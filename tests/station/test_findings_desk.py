"""The console's findings desk on a real node: frames found by their stamp, SLAM poses interpolated, refusals named."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from fleetslam.errors import FindingError
from fleetslam.geometry import invert, pose_from_xyz_rpy
from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import image_msg, odometry_msg, pose_msg
from fleetslam.msg.typesys import serialize
from fleetslam.station import findings as desk_module
from fleetslam.station.findings import FindingsDesk, cdr_image_stamp


def test_an_images_stamp_is_read_without_decoding_it() -> None:
    stamp = 1_764_000_123_456_789_012
    payload = serialize(image_msg(np.zeros((4, 6), np.float32), "32FC1", frame_id="camera", stamp_ns=stamp),
                        "sensor_msgs/msg/Image")  # fmt: skip
    assert cdr_image_stamp(payload) == stamp


def test_poses_are_interpolated_and_refusals_name_the_reason(
    make_context: Callable[..., Context], monkeypatch: pytest.MonkeyPatch
) -> None:
    node = Node("station", context=make_context())
    desk = FindingsDesk(node, lambda message, agent: None)
    try:
        a, b = pose_from_xyz_rpy(0, 0, 0, 0, 0, 0), pose_from_xyz_rpy(1.0, 0, 0, 0, 0, 0.2)
        for stamp, pose in ((2_000_000_000, b), (1_800_000_000, a), (5_000_000_000, a)):  # out of order
            desk.record_pose("c3po", odometry_msg(pose_msg(pose), frame_id="map", child_frame_id="cam", stamp_ns=stamp))
        middle = desk._pose_at("c3po", 1_900_000_000)
        assert np.allclose(middle[:3, 3], [0.5, 0, 0]) and np.isclose(np.arctan2(middle[1, 0], middle[0, 0]), 0.1)
        assert np.allclose(desk._pose_at("c3po", 2_000_000_000), b)
        with pytest.raises(FindingError, match="no pose of the picked frame"):
            desk._pose_at("c3po", 1_000_000_000)  # before every pose kept
        with pytest.raises(FindingError, match="no pose of the picked frame"):
            desk._pose_at("c3po", 3_000_000_000)  # between poses 3 s apart: not tracked
        monkeypatch.setattr(desk_module, "POSE_WAIT_S", 0.2)
        with pytest.raises(FindingError, match="no pose of the picked frame"):
            desk._pose_at("c3po", 6_000_000_000)  # SLAM never catches up
        assert desk.pick("c3po", 1, 10.0, 10.0) == {"type": "finding_pick", "ok": False,
                                                     "message": "no camera frame of 'c3po' yet"}  # fmt: skip
        created = desk.create("p9", "title", "high", "")
        assert not created["ok"] and "expired" in created["message"]
    finally:
        node.destroy()


def test_a_frame_slam_skipped_is_placed_by_the_wheel_odometry_within_5_cm(make_context: Callable[..., Context]) -> None:
    """SLAM tracks only some frames (the newest wins): a finding picked on a frame it skipped is placed from the
    nearest SLAM pose moved by the wheel odometry (50 Hz, drifting 3 % in scale) through the camera's mounting."""
    rng = np.random.default_rng(7)

    # The robot drives an arc (0.4 m/s, 0.8 rad/s) in the world; its camera is mounted ahead, above, pitched down.
    def base(t: float) -> np.ndarray:
        yaw = 0.8 * t
        return pose_from_xyz_rpy(0.5 * np.sin(yaw), 0.5 * (1 - np.cos(yaw)), 0.0, 0.0, 0.0, yaw + 0.3)

    level = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    mounting = pose_from_xyz_rpy(0.15, 0.02, 0.3, 0.0, 0.2, 0.0) @ level  # base_link → optical frame
    T_map_world = invert(base(0.0) @ mounting)  # SLAM's map frame: the camera's at start
    T_odom_world = pose_from_xyz_rpy(-1.0, 2.0, 0.0, 0.0, 0.0, 0.7)  # odometry's own frame

    def odom(t: float) -> np.ndarray:  # 3 % scale drift of every increment, in the odom frame
        pose = T_odom_world @ base(t)
        pose[:3, 3] *= 1.03
        return pose

    node = Node("station", context=make_context())
    desk = FindingsDesk(node, lambda message, agent: None)
    try:
        desk.record_mounting("c3po", mounting)
        ns = 1_000_000_000
        for k in range(200):  # 4 s of odometry at 50 Hz, a sample in six lost at the busy station
            if k % 6 != 5:
                t = 0.02 * k
                desk.record_odom("c3po", odometry_msg(pose_msg(odom(t)), frame_id="odom", child_frame_id="base_link",
                                                      stamp_ns=int(t * ns)))  # fmt: skip
        # Camera frames at 10 Hz: SLAM tracked every second one, then skipped 0.8 s (more than interpolation bridges).
        tracked = [0.0, 0.2, 0.4, 0.6, 0.8, 1.6, 1.8, 2.0]
        for t in tracked:
            camera = T_map_world @ base(t) @ mounting
            desk.record_pose("c3po", odometry_msg(pose_msg(camera), frame_id="map", child_frame_id="camera",
                                                  stamp_ns=int(t * ns)))  # fmt: skip
        for t in (0.1, 0.5, 0.9, 1.1, 1.3, 1.5, 1.9):  # frames SLAM skipped
            point_camera = np.array([rng.uniform(-1, 1), rng.uniform(-0.5, 0.5), rng.uniform(1.0, 3.0)])
            truth = T_map_world @ base(t) @ mounting
            placed = desk._pose_at("c3po", round(t * ns))
            error = np.linalg.norm(
                placed[:3, :3] @ point_camera + placed[:3, 3] - (truth[:3, :3] @ point_camera + truth[:3, 3])
            )
            assert error < 0.05, (t, error)
            assert np.linalg.norm(placed[:3, 3] - truth[:3, 3]) < 0.02, t
        # Without the mounting no odometry can bridge the 0.8 s: the frame is refused, as before.
        desk._feeds["c3po"].mounting = None
        with pytest.raises(FindingError, match="no pose of the picked frame"):
            desk._pose_at("c3po", int(1.2 * ns))
    finally:
        node.destroy()
