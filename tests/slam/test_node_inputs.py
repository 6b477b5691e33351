"""The SLAM node's wheel-odometry inputs over a real router: good poses become priors, bad ones are ignored."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fleetslam.geometry import pose_from_planar
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.conversions import transform_msg
from fleetslam.middleware.typesys import message_from_dict, stamp_from_ns
from fleetslam.slam.node import SlamNode, SlamNodeConfig

from ..support import wait_until


def odometry(x: float, stamp_s: float, quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)):  # type: ignore[no-untyped-def]
    msg = message_from_dict(
        "nav_msgs/msg/Odometry",
        {"child_frame_id": "base_link",
         "pose": {"pose": {"position": {"x": x, "y": 0.0, "z": 0.0},
                           "orientation": dict(zip("xyzw", quaternion, strict=True))}}},
    )  # fmt: skip
    msg.header.frame_id = "odom"
    msg.header.stamp = stamp_from_ns(round(stamp_s * 1e9))
    return msg


def test_wheel_poses_become_priors_and_malformed_ones_are_ignored(make_context: Callable[..., Context]) -> None:
    slam = SlamNode(Node("slam", context=make_context("c3po")), SlamNodeConfig())
    robot = Node("base", context=make_context("c3po"))
    odom_pub = robot.create_publisher("nav_msgs/msg/Odometry", "odom", QoSProfile(depth=50))
    tf_pub = robot.create_publisher("tf2_msgs/msg/TFMessage", "tf_static", QoSProfile(durability="transient_local"))
    base_camera = np.array([[0.0, 0.0, 1.0, 0.1], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.5], [0, 0, 0, 1.0]])
    bad_tf = transform_msg(base_camera, "base_link", "camera_optical_frame", 0)
    rotation = bad_tf.transforms[0].transform.rotation
    rotation.x = rotation.y = rotation.z = rotation.w = 0.0  # a zero quaternion
    tf_pub.publish(bad_tf)
    assert wait_until(lambda: slam.bad_inputs >= 1, 5.0)
    assert slam.base_camera is None
    tf_pub.publish(transform_msg(base_camera, "base_link", "camera_optical_frame", 0))
    assert wait_until(lambda: slam.base_camera is not None, 5.0)
    np.testing.assert_allclose(slam.base_camera, base_camera, atol=1e-12)

    odom_pub.publish(odometry(float("nan"), 0.95))
    odom_pub.publish(odometry(0.0, 0.97, (0.0, 0.0, 0.0, 0.0)))
    for k in range(11):
        odom_pub.publish(odometry(0.1 * k, 1.0 + 0.1 * k))  # 1 m/s along x
    assert wait_until(lambda: len(slam.wheel_poses) == 11, 5.0), len(slam.wheel_poses)
    assert slam.bad_inputs == 3
    prior = slam.wheel_prior(1.55)
    assert prior is not None
    np.testing.assert_allclose(prior, pose_from_planar(0.55, 0.0, 0.0) @ base_camera, atol=1e-9)
    assert slam.wheel_prior(5.0) is None  # long after the last wheel pose: no stale prior
