"""Adding a camera driver: a synthetic RGB-D camera published through the driver seam to a Zenoh router.

A driver is a class with ``intrinsics``, ``name``, ``__iter__`` (frames as the device delivers them) and ``close``
(:class:`fleetslam.drivers.CameraDriver`); :class:`fleetslam.drivers.node.CameraNode` publishes its frames on
``camera/rgb/image_raw``, ``camera/depth/image_raw`` and their ``camera_info``, where the SLAM node reads them. No
simulator code is involved. A real device's driver has the same shape: its ``__iter__`` waits for the device's
next frame (e.g. pyrealsense2's ``wait_for_frames``, aligned to colour) and converts depth to float32 metres.

    fleetslam router --listen tcp/127.0.0.1:7447 &
    python examples/camera_driver.py --router tcp/127.0.0.1:7447 --namespace /c3po --frames 50 &
    FLEETSLAM_ROUTER=tcp/127.0.0.1:7447 fleetslam topic hz /c3po/camera/rgb/image_raw

Frame ``i`` shows a checkerboard shifted ``i`` pixels to the right in front of a wall 2 m away.
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Iterator

import numpy as np

from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.drivers.node import CameraNode
from fleetslam.geometry import make_pose
from fleetslam.middleware import Context, Node

#: T_base_camera: 0.3 m up, looking forward (optical x right, y down, z along the base's x).
BASE_CAMERA = make_pose([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], [0.0, 0.0, 0.3])


def checkerboard(width: int, height: int, shift: int, square: int = 16) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB: black and white squares, shifted ``shift`` pixels to the right."""
    u = (np.arange(width) - shift) // square
    v = np.arange(height) // square
    grey = np.where((u[None, :] + v[:, None]) % 2 == 0, 255, 0).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


class SyntheticCamera:
    """An RGB-D camera at ``rate`` Hz: frames paced on the monotonic clock, stamped on the system clock."""

    name = "synthetic"

    def __init__(self, frames: int, rate: float = 15.0, width: int = 160, height: int = 120) -> None:
        self.intrinsics = Intrinsics(0.8 * width, 0.8 * width, (width - 1) / 2, (height - 1) / 2, width, height)
        self.frames = frames
        self.period = 1.0 / rate
        self.closed = False

    def __iter__(self) -> Iterator[RGBDFrame]:
        k = self.intrinsics
        depth = np.full((k.height, k.width), 2.0, np.float32)
        depth[:, : k.width // 8] = 0.0  # a band the sensor does not see (0 = invalid)
        next_frame = time.monotonic()
        for i in range(self.frames):
            if self.closed:
                return
            time.sleep(max(0.0, next_frame - time.monotonic()))
            next_frame += self.period
            yield RGBDFrame(i, time.time(), checkerboard(k.width, k.height, i), depth)

    def close(self) -> None:
        self.closed = True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--router", help="router endpoint (default: FLEETSLAM_ROUTER or the local default)")
    parser.add_argument("--namespace", default="/camera", help="the robot's namespace")
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--rate", type=float, default=15.0, help="frames per second")
    parser.add_argument("--wait-subscriber", type=float, default=0.0, metavar="S",
                        help="first wait up to S seconds for subscribers of the colour, depth and camera_info "
                        "topics")  # fmt: skip
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    camera = SyntheticCamera(args.frames, args.rate)
    with Context(router=args.router) as context, Node("camera", context=context, namespace=args.namespace) as node:
        publisher = CameraNode(node, camera, base_camera=BASE_CAMERA)
        deadline = time.monotonic() + args.wait_subscriber
        # Each topic is matched on its own: a reader's three subscriptions need not all be known at once.
        streams = (publisher.rgb_pub, publisher.depth_pub, publisher.rgb_info_pub)
        while any(p.matched_subscriptions == 0 for p in streams) and time.monotonic() < deadline:
            time.sleep(0.02)
        if args.wait_subscriber > 0:
            # A subscription shows in the graph a moment before the router routes to it: without this the first
            # frame of a stream could miss a reader that was already listed.
            time.sleep(0.5)
        publisher.run()
        # Images are large: let the last ones leave before the session closes.
        time.sleep(0.2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
