"""The camera node: publishes a :class:`~fleetslam.drivers.base.CameraDriver`'s frames on the topics the SLAM node
reads, as the simulator does for its cameras.

In the node's namespace: ``camera/rgb/image_raw`` (sensor_msgs/Image rgb8), ``camera/depth/image_raw`` (32FC1,
metres, 0 = invalid), ``camera/rgb/camera_info`` and ``camera/depth/camera_info`` (plumb_bob, zero distortion)
with the frame's stamp, and, when the mounting is given, ``tf_static`` (``base_link`` → the optical frame), which
lets the SLAM node use the wheel odometry and planar motion.
"""

from __future__ import annotations

import logging
import threading
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.drivers.base import CameraDriver
from fleetslam.middleware import Node, QoSProfile
from fleetslam.msg.conversions import camera_info_msg, image_msg, transform_msg

log = logging.getLogger(__name__)

OPTICAL_FRAME = "camera_optical_frame"


class StampedRGBD(Protocol):
    """What the camera topics carry of a frame (a dataset's, a driver's or the simulator's)."""

    @property
    def rgb(self) -> NDArray[np.uint8]: ...
    @property
    def depth(self) -> NDArray[Any]: ...
    @property
    def stamp(self) -> float: ...


def image_messages(frame: StampedRGBD, frame_id: str) -> tuple[Any, Any]:
    """(rgb8 Image, 32FC1 Image) of a frame (depth in metres, 0 = invalid), stamped with its capture time."""
    stamp_ns = round(frame.stamp * 1e9)
    return (
        image_msg(frame.rgb, "rgb8", frame_id=frame_id, stamp_ns=stamp_ns),
        image_msg(frame.depth, "32FC1", frame_id=frame_id, stamp_ns=stamp_ns),
    )


def camera_info_message(intrinsics: Intrinsics, frame_id: str, stamp_ns: int) -> Any:
    """sensor_msgs/CameraInfo of an ideal pinhole camera."""
    return camera_info_msg(intrinsics, frame_id=frame_id, stamp_ns=stamp_ns)


class CameraNode:
    """Publishes a driver's frames (see the module docstring); :meth:`run` in the caller's thread or
    :meth:`start` in its own. Closing the node (or :meth:`close`) stops it and closes the driver.

    Args:
        node: the middleware node, in the robot's namespace.
        driver: the device.
        frame_id: the optical frame (x right, y down, z forward) the images are in.
        base_frame: the robot's base frame, parent of ``frame_id`` on ``tf_static``.
        base_camera: the camera's mounting ``T_base_camera``; None publishes no ``tf_static``.
    """

    def __init__(
        self,
        node: Node,
        driver: CameraDriver,
        *,
        frame_id: str = OPTICAL_FRAME,
        base_frame: str = "base_link",
        base_camera: NDArray[np.float64] | None = None,
    ) -> None:
        self.node = node
        self.driver = driver
        self.frame_id = frame_id
        sensor_qos = QoSProfile(depth=2)
        self.rgb_pub = node.create_publisher("sensor_msgs/msg/Image", "camera/rgb/image_raw", sensor_qos)
        self.depth_pub = node.create_publisher("sensor_msgs/msg/Image", "camera/depth/image_raw", sensor_qos)
        self.rgb_info_pub = node.create_publisher("sensor_msgs/msg/CameraInfo", "camera/rgb/camera_info", sensor_qos)
        self.depth_info_pub = node.create_publisher(
            "sensor_msgs/msg/CameraInfo", "camera/depth/camera_info", sensor_qos
        )
        if base_camera is not None:
            self.static_tf_pub = node.create_publisher(
                "tf2_msgs/msg/TFMessage", "tf_static", QoSProfile(durability="transient_local", depth=1)
            )
            self.static_tf_pub.publish(transform_msg(base_camera, base_frame, frame_id, 0))
        self.frames_published = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        node.add_on_destroy(self.close)

    def publish(self, frame: RGBDFrame) -> None:
        """Publish one frame: both images and both camera_info, with the frame's stamp."""
        rgb, depth = image_messages(frame, self.frame_id)
        info = camera_info_message(self.driver.intrinsics, self.frame_id, round(frame.stamp * 1e9))
        self.rgb_pub.publish(rgb)
        self.depth_pub.publish(depth)
        self.rgb_info_pub.publish(info)
        self.depth_info_pub.publish(info)
        self.frames_published += 1

    def run(self) -> None:
        """Publish every frame until the driver ends or the node is closed; then close the driver."""
        try:
            for frame in self.driver:
                if self._stop.is_set():
                    break
                self.publish(frame)
        finally:
            self.driver.close()
        log.info("%s: %d frames published", self.driver.name, self.frames_published)

    def start(self) -> None:
        """:meth:`run` in a thread of its own."""
        self._thread = threading.Thread(target=self.run, name=f"{self.node.fq_name}/camera", daemon=True)
        self._thread.start()

    def join(self, timeout_s: float | None = None) -> bool:
        """Wait for the thread started by :meth:`start`; whether it ended."""
        if self._thread is not None:
            self._thread.join(timeout_s)
            return not self._thread.is_alive()
        return True

    def close(self) -> None:
        """Stop after the frame being published (the driver is closed by the thread that read it)."""
        self._stop.set()
        if self._thread is None:
            self.driver.close()
        elif self._thread is not threading.current_thread():
            self._thread.join(10.0)
