"""The console's findings desk on a real node: frames found by their stamp, SLAM poses interpolated, refusals named."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from fleetslam.errors import FindingError
from fleetslam.geometry import pose_from_xyz_rpy
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
