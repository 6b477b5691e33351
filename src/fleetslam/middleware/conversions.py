"""Conversions between 4×4 poses and ROS geometry messages (geometry_msgs Pose/Transform, tf2_msgs TFMessage)."""

from __future__ import annotations

from typing import Any

import numpy as np

from fleetslam.geometry import pose_from_quat, pose_to_quat
from fleetslam.middleware.typesys import get_type, header


def pose_matrix(pose: Any) -> np.ndarray:
    """4×4 matrix of a geometry_msgs/Pose."""
    p, q = pose.position, pose.orientation
    return pose_from_quat([p.x, p.y, p.z], [q.x, q.y, q.z, q.w])


def transform_matrix(transform: Any) -> np.ndarray:
    """4×4 matrix of a geometry_msgs/Transform."""
    t, q = transform.translation, transform.rotation
    return pose_from_quat([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


def transform_msg(pose: np.ndarray, parent: str, child: str, stamp_ns: int) -> Any:
    """tf2_msgs/msg/TFMessage with one transform ``T_parent_child``."""
    t, q = pose_to_quat(pose)
    vec3 = get_type("geometry_msgs/msg/Vector3")
    transform = get_type("geometry_msgs/msg/TransformStamped")(
        header=header(parent, stamp_ns),
        child_frame_id=child,
        transform=get_type("geometry_msgs/msg/Transform")(
            translation=vec3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
            rotation=get_type("geometry_msgs/msg/Quaternion")(
                x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
            ),
        ),
    )
    return get_type("tf2_msgs/msg/TFMessage")(transforms=[transform])
