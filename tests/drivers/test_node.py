"""The driver seam over a real router: a camera driver's frames, published by CameraNode, arrive bit-exact on
the camera topics and the SLAM node tracks them."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from functools import partial
from typing import Any

import numpy as np

from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.drivers import CameraDriver
from fleetslam.drivers.node import CameraNode
from fleetslam.geometry import invert, pose_from_planar, translation_distance
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import pose_matrix, transform_matrix
from fleetslam.msg.typesys import ns_from_stamp
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.node import SlamNode, SlamNodeConfig
from fleetslam.slam.pipeline import SlamPipeline

from ..slam.textured_room import make_textures, render
from ..support import wait_until

BASE_CAMERA = np.array([[0.0, 0.0, 1.0, 0.1], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.5], [0, 0, 0, 1.0]])


class FrameListCamera:
    """A driver over frames made beforehand, delivered at ``rate`` Hz once ``go`` is set; with ``ready``, frame
    ``i`` also waits (up to 10 s) until ``ready(i)`` holds, as a camera triggered by its reader."""

    name = "frame_list"

    def __init__(
        self,
        intrinsics: Intrinsics,
        frames: list[RGBDFrame],
        rate: float,
        ready: Callable[[int], bool] | None = None,
    ) -> None:
        self.intrinsics = intrinsics
        self._frames = frames
        self._period = 1.0 / rate
        self._ready = ready
        self.go = threading.Event()
        self.closed = 0

    def __iter__(self) -> Iterator[RGBDFrame]:
        self.go.wait(10.0)
        for i, frame in enumerate(self._frames):
            if self._ready is not None:
                wait_until(partial(self._ready, i), 10.0)
            yield frame
            time.sleep(self._period)

    def close(self) -> None:
        self.closed += 1


def test_camera_node_publishes_a_drivers_frames_bit_exact(make_context: Callable[..., Context]) -> None:
    rng = np.random.default_rng(3)
    intrinsics = Intrinsics(100.0, 101.0, 39.5, 29.5, 80, 60)
    frames = [
        RGBDFrame(i, 1000.0 + 0.1 * i, rng.integers(0, 256, (60, 80, 3), np.uint8),
                  rng.uniform(0.0, 5.0, (60, 80)).astype(np.float32))
        for i in range(5)
    ]  # fmt: skip
    driver = FrameListCamera(intrinsics, frames, rate=20.0)
    assert isinstance(driver, CameraDriver)
    received: dict[str, list[Any]] = {k: [] for k in ("rgb", "depth", "rgb_info", "depth_info", "tf_static")}
    with Node("listener", context=make_context()) as listener:
        for key, type_name, topic in (
            ("rgb", "sensor_msgs/msg/Image", "/c3po/camera/rgb/image_raw"),
            ("depth", "sensor_msgs/msg/Image", "/c3po/camera/depth/image_raw"),
            ("rgb_info", "sensor_msgs/msg/CameraInfo", "/c3po/camera/rgb/camera_info"),
            ("depth_info", "sensor_msgs/msg/CameraInfo", "/c3po/camera/depth/camera_info"),
        ):
            listener.create_subscription(type_name, topic, received[key].append, QoSProfile(depth=10))
        listener.create_subscription(
            "tf2_msgs/msg/TFMessage", "/c3po/tf_static", received["tf_static"].append,
            QoSProfile(durability="transient_local", depth=1),
        )  # fmt: skip
        node = Node("camera", context=make_context(), namespace="/c3po")
        camera = CameraNode(node, driver, base_camera=BASE_CAMERA)
        publishers = (camera.rgb_pub, camera.depth_pub, camera.rgb_info_pub, camera.depth_info_pub)
        assert wait_until(lambda: all(p.matched_subscriptions > 0 for p in publishers), 10.0)
        camera.start()
        driver.go.set()
        assert camera.join(10.0)
        assert driver.closed == 1  # by the thread that read it, once the frames ended
        streams = ("rgb", "depth", "rgb_info", "depth_info")
        assert wait_until(lambda: all(len(received[k]) == 5 for k in streams) and received["tf_static"], 5.0)
        node.destroy()
    assert camera.frames_published == 5
    for frame, rgb, depth, info in zip(frames, received["rgb"], received["depth"], received["rgb_info"], strict=True):
        stamp_ns = round(frame.stamp * 1e9)
        assert ns_from_stamp(rgb.header.stamp) == ns_from_stamp(depth.header.stamp) == stamp_ns
        assert rgb.header.frame_id == depth.header.frame_id == info.header.frame_id == "camera_optical_frame"
        assert (rgb.encoding, rgb.width, rgb.height, rgb.step) == ("rgb8", 80, 60, 240)
        np.testing.assert_array_equal(np.asarray(rgb.data).reshape(60, 80, 3), frame.rgb)
        assert (depth.encoding, depth.step) == ("32FC1", 320)
        np.testing.assert_array_equal(np.frombuffer(np.asarray(depth.data).tobytes(), "<f4").reshape(60, 80),
                                      frame.depth)  # fmt: skip
        assert (info.width, info.height) == (80, 60)
        np.testing.assert_array_equal(np.asarray(info.k).reshape(3, 3), intrinsics.K)
    (transform,) = received["tf_static"][-1].transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("base_link", "camera_optical_frame")
    np.testing.assert_allclose(transform_matrix(transform.transform), BASE_CAMERA, atol=1e-12)


def test_the_slam_node_tracks_a_drivers_frames(make_context: Callable[..., Context]) -> None:
    intrinsics = Intrinsics(262.5, 262.5, 159.5, 119.5, 320, 240)
    textures = make_textures(np.random.default_rng(0))
    truth = [pose_from_planar(0.01 * k, 0.0, 0.0) @ BASE_CAMERA for k in range(15)]
    frames = [RGBDFrame(k, 2000.0 + 0.2 * k, *render(pose, intrinsics, textures)) for k, pose in enumerate(truth)]
    poses: dict[int, np.ndarray] = {}
    # Frame i once the SLAM node has published the poses of the frames before it (the first one may come before
    # camera_info has started the pipeline): on a busy machine the node would otherwise drop the stale ones.
    driver = FrameListCamera(intrinsics, frames, rate=5.0, ready=lambda i: len(poses) >= i - 1)
    # The first frames of a process compile and import the SLAM's kernels (seconds): done here, the node keeps up.
    warm = SlamPipeline(SlamConfig(), intrinsics=intrinsics)
    for frame in frames[:3]:
        warm.step(frame)
    slam = SlamNode(Node("slam", context=make_context("c3po")), SlamNodeConfig())
    with Node("listener", context=make_context()) as listener:
        listener.create_subscription(
            "nav_msgs/msg/Odometry", "/c3po/slam/odom",
            lambda msg: poses.__setitem__(ns_from_stamp(msg.header.stamp), pose_matrix(msg.pose.pose)),
        )  # fmt: skip
        camera = CameraNode(Node("camera", context=make_context(), namespace="/c3po"), driver, base_camera=BASE_CAMERA)
        assert wait_until(lambda: camera.rgb_pub.matched_subscriptions >= 1 and slam.base_camera is not None, 10.0)
        camera.start()
        driver.go.set()
        assert camera.join(20.0)
        assert wait_until(lambda: len(poses) >= 14, 10.0), (len(poses), slam.counts)
        camera.close()
    index = {round(f.stamp * 1e9): f.index for f in frames}
    tracked = sorted(index[stamp] for stamp in poses)
    assert len(tracked) >= 14 and slam.counts["lost_frames"] == 0
    first = tracked[0]
    pose_of = {index[stamp]: pose for stamp, pose in poses.items()}
    for k in tracked:
        estimate = invert(pose_of[first]) @ pose_of[k]
        expected = invert(truth[first]) @ truth[k]
        assert translation_distance(estimate, expected) < 0.005, (k, estimate[:3, 3], expected[:3, 3])
