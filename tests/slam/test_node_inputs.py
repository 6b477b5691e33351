"""The SLAM node's wheel-odometry inputs over a real router: good poses become priors, bad ones are ignored."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

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


def test_images_are_decoded_with_their_row_step_and_byte_order() -> None:
    from functools import partial

    from fleetslam.middleware.typesys import get_type, header
    from fleetslam.slam.node import image_to_array

    image = partial(get_type("sensor_msgs/msg/Image"), header=header("camera", 0))
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    padded = np.zeros((2, 12), np.uint8)  # rows padded to 12 bytes, as some drivers align them
    padded[:, :9] = rgb.reshape(2, 9)
    msg = image(height=2, width=3, encoding="rgb8", is_bigendian=0, step=12, data=padded.reshape(-1))
    np.testing.assert_array_equal(image_to_array(msg), rgb)
    depth_mm = np.array([[1000, 2500], [0, 65535]], dtype=">u2")  # big-endian 16UC1, millimetres
    msg = image(height=2, width=2, encoding="16UC1", is_bigendian=1, step=4,
                data=np.frombuffer(depth_mm.tobytes(), np.uint8).copy())  # fmt: skip
    np.testing.assert_allclose(image_to_array(msg), [[1.0, 2.5], [0.0, 65.535]], rtol=1e-6)
    short = image(height=4, width=3, encoding="rgb8", is_bigendian=0, step=9, data=np.zeros(20, np.uint8))
    with pytest.raises(ValueError, match="does not fit"):
        image_to_array(short)


def test_save_map_writes_only_plain_names_inside_the_maps_directory(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    from fleetslam.middleware.typesys import get_type

    SlamNode(Node("slam", context=make_context("c3po")), SlamNodeConfig(maps_dir=str(tmp_path / "maps")))
    save = Node("operator", context=make_context()).create_client("fleetslam_msgs/srv/SaveMap", "/c3po/slam/save_map")
    assert save.wait_for_service(5.0)
    request = get_type("fleetslam_msgs/srv/SaveMap_Request")
    (tmp_path / "victim.db").write_text("keep me")
    for path in (str(tmp_path / "victim.db"), "../victim.db", "nested/dir/map.db", "map.bt"):
        response = save.call(request(path=path), timeout=10)
        assert not response.success and "save path" in response.message, (path, response.message)
    assert (tmp_path / "victim.db").read_text() == "keep me" and not (tmp_path / "nested").exists()
    response = save.call(request(path="c3po.db"), timeout=10)  # a fair name: refused only for want of a map
    assert not response.success and response.message.startswith("nothing to save yet")
    assert Path(response.path) == tmp_path / "maps" / "c3po.db"
