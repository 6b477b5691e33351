"""RViz 1 (Debian's, under Xvfb with software OpenGL) shows a fleet map through the bridge.

The screenshot is Xvfb's own framebuffer (``-fbdir``, an XWD file), saved as ``rviz.png`` in the test's folder.
"""

from __future__ import annotations

import os
import shutil
import signal
import struct
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.typesys import message_from_dict
from fleetslam.ros1.bridge import Ros1Bridge, TopicRule
from fleetslam.ros1.node import Ros1Node
from fleetslam.ros1.rviz import rviz_config

from ..support import wait_until
from .conftest import Master, need_ros1


def read_xwd(path: Path) -> np.ndarray:
    """H×W×3 RGB of a 24/32-bit ZPixmap XWD file (what Xvfb keeps in its -fbdir)."""
    data = path.read_bytes()
    header = struct.unpack(">25I", data[:100])
    header_size, width, height, bits_per_pixel, bytes_per_line, ncolors = (
        header[0], header[4], header[5], header[11], header[12], header[19],
    )  # fmt: skip
    assert bits_per_pixel == 32, f"unexpected XWD depth {bits_per_pixel}"
    offset = header_size + 12 * ncolors
    pixels = np.frombuffer(data, np.uint8, count=bytes_per_line * height, offset=offset).reshape(height, bytes_per_line)
    return pixels[:, : 4 * width].reshape(height, width, 4)[..., [2, 1, 0]]


def _cloud(points: np.ndarray) -> object:
    msg = message_from_dict(
        "sensor_msgs/msg/PointCloud2",
        {"header": {"frame_id": "map"}, "height": 1, "width": len(points), "point_step": 12,
         "row_step": 12 * len(points), "is_dense": True,
         "fields": [{"name": n, "offset": 4 * i, "datatype": 7, "count": 1} for i, n in enumerate("xyz")]},
    )  # fmt: skip
    msg.data = np.frombuffer(points.astype(np.float32).tobytes(), np.uint8)  # type: ignore[attr-defined]
    return msg


def test_rviz_shows_the_fleet_map(roscore: Master, make_context: Callable[..., Context], tmp_path: Path) -> None:
    need_ros1("rviz", "xvfb-run")
    config = tmp_path / "fleet.rviz"
    config.write_text(rviz_config(["c3po"]), encoding="utf-8")
    fbdir = tmp_path / "fb"
    fbdir.mkdir()
    # A 2 m cube of occupied cells, as the mapping node publishes them (latched: RViz may come late).
    grid = np.stack(np.meshgrid(*[np.arange(-1.0, 1.0, 0.1)] * 3), axis=-1).reshape(-1, 3)
    with (
        Node("mapping", context=make_context(), namespace="/c3po") as mapping,
        Ros1Node("fleetslam_bridge", master_uri=roscore.uri) as ros1,
        Node("fleetslam_bridge", context=make_context()) as node,
        Ros1Bridge(node, ros1, to_ros1=[TopicRule.parse("/c3po/*")], scan_period_s=0.2) as bridge,
    ):
        occupied = mapping.create_publisher(
            "sensor_msgs/msg/PointCloud2", "map/occupied", QoSProfile(durability="transient_local", depth=1)
        )
        occupied.publish(_cloud(grid))
        assert wait_until(lambda: "/c3po/map/occupied" in bridge.bridged_to_ros1, timeout_s=10)
        rviz = subprocess.Popen(
            ["xvfb-run", "-a", "-s", f"-screen 0 1024x768x24 -fbdir {fbdir}", "rviz", "-d", str(config)],
            env={**roscore.env, "LIBGL_ALWAYS_SOFTWARE": "1"}, stdout=(tmp_path / "rviz.log").open("wb"),
            stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
        try:
            shot = fbdir / "Xvfb_screen0"
            reddish = 0
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and reddish < 5000:
                time.sleep(2)
                if shot.exists():
                    rgb = read_xwd(shot).astype(int)
                    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
                    reddish = int(((r > 120) & (r > g + 60) & (r > b + 50)).sum())
            shutil.copy(shot, tmp_path / "rviz.xwd")
        finally:
            os.killpg(rviz.pid, signal.SIGINT)
            try:
                rviz.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(rviz.pid, signal.SIGKILL)
                rviz.wait()
    image = read_xwd(tmp_path / "rviz.xwd")
    try:
        from PIL import Image

        Image.fromarray(np.ascontiguousarray(image)).save(tmp_path / "rviz.png")
    except ImportError:
        pass
    background = (np.abs(image.astype(int) - 48).sum(axis=-1) == 0).sum()
    assert background > 10_000, "RViz's 3D view (background 48,48,48) is not on screen"
    assert reddish >= 5000, f"c3po's map (red boxes) not drawn: {reddish} red pixels; see {tmp_path}"
