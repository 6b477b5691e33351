"""Wheel poses looked up at camera stamps: interpolation, tolerance at the ends, horizon."""

from __future__ import annotations

import numpy as np

from fleetslam.geometry import interpolate_pose, pose_from_planar, rotation_angle, yaw_of
from fleetslam.slam.pose_buffer import PoseBuffer


def test_interpolation_is_linear_in_translation_and_geodesic_in_rotation() -> None:
    a, b = pose_from_planar(0.0, 0.0, 0.0), pose_from_planar(1.0, 2.0, 0.8)
    middle = interpolate_pose(a, b, 0.25)
    np.testing.assert_allclose(middle[:3, 3], [0.25, 0.5, 0.0])
    assert abs(yaw_of(middle) - 0.2) < 1e-12
    np.testing.assert_allclose(interpolate_pose(a, b, 1.0), b, atol=1e-12)


def test_lookup_between_at_and_beyond_the_buffered_stamps() -> None:
    buffer = PoseBuffer(horizon=1.0, tolerance=0.05)
    assert buffer.at(0.0) is None
    for k in range(30):  # 20 Hz along x at 1 m/s, turning at 0.5 rad/s; added out of order in pairs
        stamp = (k ^ 1) * 0.05
        buffer.add(stamp, pose_from_planar(stamp, 0.0, 0.5 * stamp))
    assert len(buffer) <= 21  # one second of poses, not thirty
    pose = buffer.at(1.2125)
    assert pose is not None
    np.testing.assert_allclose(pose[:3, 3], [1.2125, 0.0, 0.0], atol=1e-12)
    assert abs(rotation_angle(pose) - 0.60625) < 1e-9
    newest = buffer.at(1.45 + 0.04)
    assert newest is not None and abs(newest[0, 3] - 1.45) < 1e-12
    assert buffer.at(1.45 + 0.06) is None  # beyond the tolerance: no prior rather than a stale one
    assert buffer.at(0.0) is None  # older than the horizon


def test_one_far_future_stamp_is_held_aside_and_a_real_clock_jump_is_followed() -> None:
    """Issue 18: one odometry message stamped far in the future used to evict every buffered pose, and every later
    genuine one fell beyond the horizon at once: no wheel prior for SLAM ever again."""
    buffer = PoseBuffer(horizon=1.0, tolerance=0.05, confirm=3)
    for k in range(10):
        buffer.add(10.0 + 0.05 * k, pose_from_planar(0.05 * k, 0.0, 0.0))
    buffer.add(1e9, pose_from_planar(99.0, 0.0, 0.0))  # forged
    buffer.add(-1e9, pose_from_planar(-99.0, 0.0, 0.0))  # forged, the other way
    for k in range(10, 20):
        buffer.add(10.0 + 0.05 * k, pose_from_planar(0.05 * k, 0.0, 0.0))
    pose = buffer.at(10.9)
    assert pose is not None and abs(pose[0, 3] - 0.9) < 1e-9 and buffer.newest_stamp == 10.95
    assert buffer.jumps_ignored == 2
    for k in range(3):  # the simulation restarted: its clock begins again at 0, and stays there
        buffer.add(0.05 * k, pose_from_planar(5.0 + 0.05 * k, 0.0, 0.0))
    assert buffer.newest_stamp == 0.1 and len(buffer) == 3
    pose = buffer.at(0.05)
    assert pose is not None and abs(pose[0, 3] - 5.05) < 1e-9
