"""Camera poses in a robot's recording: where the base was (an Odometry topic) times where the camera sits on
the base (the transforms of ``tf_static``).

A recording carries the base's poses as ``nav_msgs/Odometry`` of ``child_frame_id`` (``base_link``) in
``header.frame_id`` (``world`` for the simulator's ``ground_truth/odom``, ``odom`` for the wheel odometry), and
the camera's mounting on ``tf_static`` as a chain of ``T_parent_child`` transforms from the base's frame to the
image's frame (``camera_optical_frame``). The camera's trajectory is ``T_world_camera = T_world_base ·
T_base_camera``. The functions take decoded messages (rosbags' classes or anything with the same fields).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.msg.conversions import pose_matrix, transform_matrix
from fleetslam.trajectory import Trajectory


def _frame(name: str) -> str:
    # tf2 frame ids carry no leading slash; ROS 1 recordings and hand-written ones sometimes do.
    return str(name).lstrip("/")


def stamp_seconds(message: Any) -> float:
    """A stamped message's header stamp in seconds."""
    return float(message.header.stamp.sec) + 1e-9 * float(message.header.stamp.nanosec)


def static_transforms(messages: Iterable[Any]) -> dict[str, tuple[str, NDArray[np.float64]]]:
    """The transforms of ``tf2_msgs/TFMessage`` messages by child frame: ``child -> (parent, T_parent_child)``;
    a later message's transform of a child replaces an earlier one (a re-published mounting)."""
    transforms: dict[str, tuple[str, NDArray[np.float64]]] = {}
    for message in messages:
        for stamped in message.transforms:
            matrix = transform_matrix(stamped.transform)
            transforms[_frame(stamped.child_frame_id)] = (_frame(stamped.header.frame_id), matrix)
    return transforms


def mounting(
    transforms: dict[str, tuple[str, NDArray[np.float64]]], base_frame: str, camera_frame: str
) -> NDArray[np.float64] | None:
    """``T_base_camera`` along the chain of parents from ``camera_frame`` up to ``base_frame``, or None when the
    chain does not reach it (a frame without a parent, or a loop)."""
    base, frame = _frame(base_frame), _frame(camera_frame)
    pose = np.eye(4)
    seen = {frame}
    while frame != base:
        if frame not in transforms:
            return None
        parent, parent_child = transforms[frame]
        pose = parent_child @ pose
        if parent in seen:
            return None
        seen.add(parent)
        frame = parent
    return pose


def odometry_trajectory(messages: Iterable[Any]) -> tuple[str, str, Trajectory]:
    """``(frame, child frame, trajectory of T_frame_child)`` of ``nav_msgs/Odometry`` messages, by header stamp;
    the frames are those of the first message."""
    stamps: list[float] = []
    poses: list[NDArray[np.float64]] = []
    frame = child = ""
    for message in messages:
        if not stamps:
            frame, child = _frame(message.header.frame_id), _frame(message.child_frame_id)
        stamps.append(stamp_seconds(message))
        poses.append(pose_matrix(message.pose.pose))
    return frame, child, Trajectory.from_lists(stamps, poses)


def camera_trajectory(base: Trajectory, base_camera: NDArray[np.float64]) -> Trajectory:
    """``T_world_camera`` at the base trajectory's stamps, from ``T_world_base`` and the mounting ``T_base_camera``."""
    return Trajectory(base.stamps.copy(), base.poses @ base_camera)
