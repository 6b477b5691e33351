"""A small real robot for the console: a node publishing a map, camera frames and odometry under /c3po,
a real `cmd_vel` subscriber and a real `e_stop` service."""

from __future__ import annotations

import os
import shutil
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.typesys import get_type, header
from fleetslam.station.server import STATIC_DIR


def pointcloud2(points: np.ndarray) -> Any:
    field_type = get_type("sensor_msgs/msg/PointField")
    cloud = get_type("sensor_msgs/msg/PointCloud2")
    data = np.asarray(points, dtype=np.float32)
    return cloud(
        header=header("map", time.time_ns()), height=1, width=len(data),
        fields=[field_type(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
        is_bigendian=False, point_step=12, row_step=12 * len(data),
        data=np.frombuffer(data.tobytes(), dtype=np.uint8), is_dense=True,
    )  # fmt: skip


@dataclass
class RobotUnderTest:
    node: Node
    commands: list[tuple[float, float, float]] = field(default_factory=list)
    """(published, v, ω): ``published`` is the console's publication time (``time.time()`` clock, from the
    message's attachment), so a slow delivery on a loaded machine cannot make a command look late."""
    estop_requests: list[bool] = field(default_factory=list)
    frames: int = 0


@pytest.fixture
def test_robot(make_context: Callable[..., Context]) -> Iterator[RobotUnderTest]:
    node = Node("robot", context=make_context("c3po"))
    robot = RobotUnderTest(node)
    twist_type = "geometry_msgs/msg/Twist"
    node.create_subscription(
        twist_type,
        "cmd_vel",
        lambda m, info: robot.commands.append((info.source_timestamp_ns * 1e-9, m.linear.x, m.angular.z)),
    )
    response = get_type("std_srvs/srv/SetBool_Response")

    def on_estop(request: Any) -> Any:
        robot.estop_requests.append(bool(request.data))
        return response(success=True, message="engaged" if request.data else "released")

    node.create_service("std_srvs/srv/SetBool", "e_stop", on_estop)
    cloud_pub = node.create_publisher("sensor_msgs/msg/PointCloud2", "map/occupied", QoSProfile(depth=1))
    image_pub = node.create_publisher("sensor_msgs/msg/Image", "camera/rgb/image_raw", QoSProfile(depth=1))
    odom_pub = node.create_publisher("nav_msgs/msg/Odometry", "odom", QoSProfile(depth=1))
    image_type, odom_type = get_type("sensor_msgs/msg/Image"), get_type("nav_msgs/msg/Odometry")
    from fleetslam.msg.typesys import message_from_dict

    grid = np.stack(np.meshgrid(np.arange(20), np.arange(10), [0, 1, 2], indexing="ij"), -1).reshape(-1, 3)
    walls = (grid * 0.05 + 0.025) + [1.0, 0.0, 0.0]
    stop = threading.Event()

    def publish() -> None:
        i = 0
        while not stop.is_set():
            i += 1
            pixels = np.zeros((120, 160, 3), dtype=np.uint8)
            pixels[:, :, 0] = (i * 20) % 255
            pixels[40:80, (i * 5) % 160 :, 1] = 255
            image_pub.publish(
                image_type(
                    header=header("camera", time.time_ns()),
                    height=120,
                    width=160,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=480,
                    data=pixels.reshape(-1),
                )
            )
            robot.frames += 1
            cloud_pub.publish(pointcloud2(walls[: min(len(walls), 100 + 20 * i)]))
            odom = message_from_dict("nav_msgs/msg/Odometry", {"pose": {"pose": {"position": {"x": 0.01 * i}}}})
            odom.pose.pose.orientation.w = 1.0
            assert isinstance(odom, odom_type)
            odom_pub.publish(odom)
            time.sleep(0.1)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    yield robot
    stop.set()
    thread.join()


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
    "--disable-sync", "--no-first-run", "--disable-dev-shm-usage", "--use-gl=swiftshader",
    "--enable-unsafe-swiftshader",
]  # fmt: skip


@pytest.fixture
def browser_page(tmp_path: Path):  # type: ignore[no-untyped-def]
    playwright_api = pytest.importorskip("playwright.sync_api")
    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed (scripts/setup installs it as root)")
    if not (STATIC_DIR / "vendor" / "three.module.js").is_file():
        pytest.skip("front-end dependencies missing: run scripts/setup-frontend")
    with playwright_api.sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(tmp_path / "profile"), executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS,
            viewport={"width": 1400, "height": 820},
        )  # fmt: skip
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        yield page, errors
        context.close()


def save_screenshot(page, tmp_path: Path, name: str) -> Path:  # type: ignore[no-untyped-def]
    path = tmp_path / name
    page.screenshot(path=str(path))
    artifacts = os.environ.get("FLEETSLAM_ARTIFACTS")
    if artifacts:
        Path(artifacts).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(artifacts) / name)
    return path
