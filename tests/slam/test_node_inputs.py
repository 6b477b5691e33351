"""The SLAM node's wheel-odometry inputs over a real router: good poses become priors, bad ones are ignored."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.geometry import pose_from_planar
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import transform_msg
from fleetslam.msg.typesys import message_from_dict, stamp_from_ns
from fleetslam.slam.frame_queue import FramePair
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


def test_frames_wait_for_published_wheels_to_start_and_a_camera_without_wheels_does_not(
    make_context: Callable[..., Context],
) -> None:
    """Tracked without the wheels, a first frame starts the map where the next (with them) cannot follow: while an
    ``odom`` publisher is known and silent, frames wait for ``wheels_gone_after``; with no publisher, none do."""
    slam = SlamNode(Node("slam", context=make_context("c3po")), SlamNodeConfig(wheels_gone_after=1.5))
    assert not slam.wheels_starting()  # nobody publishes odom: a camera without wheels goes on at once
    robot = Node("base", context=make_context("c3po"))
    robot.create_publisher("nav_msgs/msg/Odometry", "odom", QoSProfile(depth=50))
    assert wait_until(lambda: slam.wheels_starting(), 1.0)  # the publisher is known, no pose has come
    time.sleep(1.6)
    assert not slam.wheels_starting()  # waited long enough: the wheels are taken as gone


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

    # A frame the wheels have not reached yet is skipped (they are late under load, not gone): processed without
    # its prior, a ground robot facing a blank wall would be lost instead of coasting. Once the wheels have been
    # silent for wheels_gone_after (2 s), frames go on without them.
    assert not slam.wheels_behind(1.55) and slam.wheels_behind(2.5) and not slam.wheels_behind(5.0)
    uncalibrated = message_from_dict("sensor_msgs/msg/CameraInfo", {"width": 320, "height": 240})  # k all zero
    slam.on_camera_info(uncalibrated)  # ignored and counted: a pipeline started on it would never see a point
    assert slam.pipeline is None and slam.camera_info is None and slam.bad_inputs == 4
    info = message_from_dict("sensor_msgs/msg/CameraInfo", {"width": 320, "height": 240})
    info.k[:] = [262.5, 0.0, 159.5, 0.0, 262.5, 119.5, 0.0, 0.0, 1.0]
    slam.on_camera_info(info)
    slam.on_camera_info(uncalibrated)  # nor does a later one replace the intrinsics the keyframes carry
    assert slam.camera_info is info and slam.bad_inputs == 5
    assert slam.pipeline is not None and slam.pipeline.intrinsics.fx == 262.5
    assert slam.process(FramePair(round(2.5e9), None, None, time.monotonic())) is None  # images never decoded
    assert slam.counts["late_wheel_frames"] == 1 and slam.frames == 0
    # A frame older than every wheel pose held (a late sample from the camera's start, the robot since driven on) is
    # stale: the wheels cannot place it, and tracked without them it would start the map in a frame of its own.
    assert slam.before_wheels(0.5) and not slam.before_wheels(1.0) and not slam.before_wheels(1.55)
    assert slam.process(FramePair(round(0.5e9), None, None, time.monotonic())) is None
    assert slam.counts["stale_frames"] == 1 and slam.frames == 0


def test_save_map_writes_only_plain_names_inside_the_maps_directory(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    from fleetslam.msg.typesys import get_type

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


def test_images_and_odometry_stamped_far_in_the_future_do_not_stall_slam(
    make_context: Callable[..., Context],
) -> None:
    """Issue 18, D1, replayed over a real router: 5 colour and 5 depth 8×6 images stamped far in the future (paired
    and unpaired), and odometry stamped far in the future, sent into a node tracking a 5 Hz camera. Before: slam/odom
    5 Hz → 0 and no wheel prior ever again; now the node goes on at the camera's rate with its priors."""
    from fleetslam.datasets.base import Intrinsics
    from fleetslam.msg.typesys import get_type, header

    from .textured_room import make_textures, render

    slam = SlamNode(Node("slam", context=make_context("c3po")), SlamNodeConfig())
    camera = Node("camera", context=make_context("c3po"))
    poses: list[float] = []
    viewer = Node("viewer", context=make_context())
    viewer.create_subscription("nav_msgs/msg/Odometry", "/c3po/slam/odom", lambda m: poses.append(time.monotonic()))
    qos = QoSProfile(depth=5)
    rgb_pub = camera.create_publisher("sensor_msgs/msg/Image", "camera/rgb/image_raw", qos)
    depth_pub = camera.create_publisher("sensor_msgs/msg/Image", "camera/depth/image_raw", qos)
    info_pub = camera.create_publisher("sensor_msgs/msg/CameraInfo", "camera/rgb/camera_info", qos)
    odom_pub = camera.create_publisher("nav_msgs/msg/Odometry", "odom", QoSProfile(depth=50))
    tf_pub = camera.create_publisher("tf2_msgs/msg/TFMessage", "tf_static", QoSProfile(durability="transient_local"))
    base_camera = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0, 0, 0, 1.0]])
    tf_pub.publish(transform_msg(base_camera, "base_link", "camera_optical_frame", 0))
    intrinsics = Intrinsics(80.0, 80.0, 40.0, 30.0, 80, 60)
    textures = make_textures(np.random.default_rng(0))
    image = get_type("sensor_msgs/msg/Image")
    info = message_from_dict(
        "sensor_msgs/msg/CameraInfo",
        {"width": 80, "height": 60, "distortion_model": "plumb_bob", "d": [0.0] * 5,
         "k": [80.0, 0, 40.0, 0, 80.0, 30.0, 0, 0, 1]},
    )  # fmt: skip

    def images(stamp_ns: int, rgb: np.ndarray, depth: np.ndarray) -> tuple[Any, Any]:
        h, w = depth.shape
        return (
            image(header=header("camera", stamp_ns), height=h, width=w, encoding="rgb8", is_bigendian=0, step=w * 3,
                  data=np.ascontiguousarray(rgb).reshape(-1)),
            image(header=header("camera", stamp_ns), height=h, width=w, encoding="32FC1", is_bigendian=0, step=w * 4,
                  data=np.ascontiguousarray(depth, np.float32).view(np.uint8).reshape(-1)),
        )  # fmt: skip

    views = [render(pose_from_planar(0.01 * k, 0.0, 0.0) @ base_camera, intrinsics, textures) for k in range(20)]
    start_ns = time.time_ns()
    frame = 0

    def stream(seconds: float) -> int:
        """The camera and the wheels at 5 Hz for ``seconds``; returns the slam/odom messages meanwhile."""
        nonlocal frame
        before = len(poses)
        for _ in range(round(seconds * 5)):
            stamp_ns = start_ns + frame * 200_000_000
            info_pub.publish(info)
            odom_pub.publish(odometry(0.01 * (frame % 20), stamp_ns / 1e9))
            rgb, depth = images(stamp_ns, *views[frame % 20])
            rgb_pub.publish(rgb)
            depth_pub.publish(depth)
            frame += 1
            time.sleep(0.2)
        return len(poses) - before

    assert wait_until(lambda: rgb_pub.matched_subscriptions > 0 and odom_pub.matched_subscriptions > 0, 10.0)
    stream(2.0)  # the pipeline starts
    before = stream(4.0)
    assert before >= 10, before  # ~20 at 5 Hz; a busy machine may drop some
    future_ns = time.time_ns() + 10**6 * 10**9  # 11.6 days ahead
    tiny_rgb, tiny_depth = np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32)
    for k in range(5):
        rgb, depth = images(future_ns + k, tiny_rgb, tiny_depth)
        rgb_pub.publish(rgb)
        depth_pub.publish(depth)  # pairs, stamped in the future
        rgb_pub.publish(images(future_ns + 1000 + k, tiny_rgb, tiny_depth)[0])  # and halves that never pair
        depth_pub.publish(images(future_ns + 2000 + k, tiny_rgb, tiny_depth)[1])
        odom_pub.publish(odometry(50.0, future_ns / 1e9 + k))
    priors = slam.priors_used
    after = stream(4.0)
    assert after >= 0.8 * before, (before, after)
    assert slam.priors_used - priors >= 0.8 * after  # the wheel prior survived the forged stamps


def test_trajectory_service_returns_every_processed_frame_on_the_optimised_keyframes(
    make_context: Callable[..., Context],
) -> None:
    """``slam/trajectory`` over a real router: refused before any frame; then every frame the node tracked, stamped
    as its camera frame, on its keyframe's optimised pose (what an offline run's result holds), near the truth."""
    from fleetslam.datasets.base import Intrinsics
    from fleetslam.msg.conversions import pose_matrix
    from fleetslam.msg.typesys import get_type, ns_from_stamp

    from .textured_room import image_messages, make_textures

    slam = SlamNode(Node("slam", context=make_context("c3po")), SlamNodeConfig())
    client = Node("operator", context=make_context()).create_client(
        "fleetslam_msgs/srv/GetTrajectory", "/c3po/slam/trajectory"
    )
    assert client.wait_for_service(5.0)
    request = get_type("fleetslam_msgs/srv/GetTrajectory_Request")()
    response = client.call(request, timeout=10)
    assert not response.success and "no trajectory yet" in response.message and not response.trajectory.poses

    intrinsics = Intrinsics(80.0, 80.0, 40.0, 30.0, 80, 60)
    info = message_from_dict("sensor_msgs/msg/CameraInfo", {"width": 80, "height": 60})
    info.k[:] = [80.0, 0.0, 40.0, 0.0, 80.0, 30.0, 0.0, 0.0, 1.0]
    slam.on_camera_info(info)
    textures = make_textures(np.random.default_rng(0))
    base_camera = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0, 0, 0, 1.0]])
    truth = [pose_from_planar(0.02 * k, 0.0, 0.0) @ base_camera for k in range(12)]  # 2 cm forward per frame
    stamps_ns = [1_000_000_000 + k * 100_000_000 for k in range(len(truth))]
    for pose, stamp_ns in zip(truth, stamps_ns, strict=True):
        pair = FramePair(stamp_ns, *image_messages(pose, stamp_ns, intrinsics, textures), time.monotonic())
        with slam._lock:
            assert slam.process(pair) is not None

    response = client.call(request, timeout=10)
    assert response.success, response.message
    assert response.keyframes >= 1 and response.trajectory.header.frame_id == "map"
    stamps = [ns_from_stamp(p.header.stamp) for p in response.trajectory.poses]
    assert stamps == stamps_ns
    assert {p.header.frame_id for p in response.trajectory.poses} == {"map"}
    assert slam.pipeline is not None
    expected = slam.pipeline.result().trajectory.poses
    got = np.stack([pose_matrix(p.pose) for p in response.trajectory.poses])
    np.testing.assert_allclose(got, expected, atol=1e-6)
    relative = [np.linalg.inv(truth[0]) @ t for t in truth]  # the map frame is the first camera's
    np.testing.assert_allclose(got[:, :3, 3], [r[:3, 3] for r in relative], atol=0.01)
