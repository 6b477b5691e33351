"""Findings in a real headless Chromium: the operator clicks on the live camera image, fills in the form, and the
finding lands where the camera really saw that pixel; it moves with its keyframe when the graph is corrected.

The robot is a real node publishing what the simulator's would: colour and depth frames of a known scene (a tilted
wall, rendered exactly: the depth of each pixel is where its ray meets the wall), the camera's intrinsics, SLAM's
camera pose (of every other frame: the console interpolates) and the keyframe path. The camera moves all along, so
the console must match the frame the operator saw with its depth and pose.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fleetslam import topics
from fleetslam.geometry import pose_from_xyz_rpy, transform_points
from fleetslam.inspection.node import FindingsNode
from fleetslam.intrinsics import Intrinsics
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import camera_info_msg, image_msg, odometry_msg, pose_msg, pose_msgs
from fleetslam.msg.typesys import get_type, header
from fleetslam.station.protocol import VoxelDiff
from fleetslam.station.server import StationServer

from ..support import wait_until
from .conftest import save_screenshot

INTRINSICS = Intrinsics(120.0, 120.0, 79.5, 59.5, 160, 120)
WALL_NORMAL, WALL_OFFSET = np.array([1.0, -0.3, 0.1]), 3.0  # the wall: n · X = b in the map frame
OPTICAL = pose_from_xyz_rpy(0.0, 0.0, 0.0, -np.pi / 2, 0.0, -np.pi / 2)  # optical axes of a camera looking along +x


def camera_pose(t: float) -> np.ndarray:
    """The camera in the map at time t (s): sways along x and turns a little."""
    base = pose_from_xyz_rpy(0.5 + 0.3 * np.sin(0.5 * t), 0.1 * np.sin(0.3 * t), 0.3, 0.0, 0.0, 0.15 * np.sin(0.4 * t))
    return base @ OPTICAL


def wall_hit(T_map_camera: np.ndarray, u: float, v: float) -> np.ndarray:
    """Where the ray of pixel (u, v) meets the wall, and the depth (optical z) there."""
    ray = np.array([(u - INTRINSICS.cx) / INTRINSICS.fx, (v - INTRINSICS.cy) / INTRINSICS.fy, 1.0])
    direction, origin = T_map_camera[:3, :3] @ ray, T_map_camera[:3, 3]
    z = (WALL_OFFSET - WALL_NORMAL @ origin) / (WALL_NORMAL @ direction)
    return np.append(origin + z * direction, z)


def render(T_map_camera: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray]:
    u, v = np.meshgrid(np.arange(INTRINSICS.width), np.arange(INTRINSICS.height))
    rays = np.stack([(u - INTRINSICS.cx) / INTRINSICS.fx, (v - INTRINSICS.cy) / INTRINSICS.fy, np.ones(u.shape)], -1)
    directions = rays @ T_map_camera[:3, :3].T
    depth = (WALL_OFFSET - WALL_NORMAL @ T_map_camera[:3, 3]) / (directions @ WALL_NORMAL)
    hits = T_map_camera[:3, 3] + depth[..., None] * directions
    checker = ((np.floor(hits[..., 1] * 4) + np.floor(hits[..., 2] * 4)) % 2).astype(np.uint8)
    rgb = np.stack([60 + 150 * checker, np.full(checker.shape, 90 + i % 50), 200 - 120 * checker], -1).astype(np.uint8)
    return rgb, depth.astype(np.float32)


KEYFRAMES = [pose_from_xyz_rpy(x, 0.0, 0.3, 0.0, 0.0, 0.0) @ OPTICAL for x in (0.2, 0.5, 0.8)]


@dataclass
class CameraRobot:
    poses: dict[int, np.ndarray] = field(default_factory=dict)
    """The camera's true pose at each frame's stamp (ns)."""
    keyframes: list[np.ndarray] = field(default_factory=lambda: list(KEYFRAMES))


@pytest.fixture
def camera_robot(make_context: Callable[..., Context]) -> Iterator[CameraRobot]:
    node = Node("robot", context=make_context("c3po"))
    robot = CameraRobot()
    qos = QoSProfile(depth=2)
    rgb_pub = node.create_publisher(topics.RGB_IMAGE.type, topics.RGB_IMAGE.name, qos)
    depth_pub = node.create_publisher(topics.DEPTH_IMAGE.type, topics.DEPTH_IMAGE.name, qos)
    info_pub = node.create_publisher(topics.CAMERA_INFO.type, topics.CAMERA_INFO.name, qos)
    odom_pub = node.create_publisher(topics.SLAM_ODOM.type, topics.SLAM_ODOM.name, qos)
    path_pub = node.create_publisher(topics.PATH.type, topics.PATH.name, topics.PATH.qos())
    stop = threading.Event()

    def publish() -> None:
        start_ns, i = time.time_ns(), 0
        while not stop.is_set():
            stamp = start_ns + i * 100_000_000
            pose = camera_pose(i * 0.1)
            robot.poses[stamp] = pose
            rgb, depth = render(pose, i)
            if i % 2 == 0:  # SLAM tracks every other frame: the console interpolates between them
                odom_pub.publish(odometry_msg(pose_msg(pose), frame_id="map", child_frame_id="camera", stamp_ns=stamp))
            info_pub.publish(camera_info_msg(INTRINSICS, frame_id="camera", stamp_ns=stamp))
            depth_pub.publish(image_msg(depth, "32FC1", frame_id="camera", stamp_ns=stamp))
            rgb_pub.publish(image_msg(rgb, "rgb8", frame_id="camera", stamp_ns=stamp))
            if i % 5 == 0:
                stamped = get_type("geometry_msgs/msg/PoseStamped")
                h = header("map", stamp)
                poses = [stamped(header=h, pose=p) for p in pose_msgs(robot.keyframes)]
                path_pub.publish(get_type("nav_msgs/msg/Path")(header=h, poses=poses))
            i += 1
            time.sleep(0.1)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    yield robot
    stop.set()
    thread.join()
    node.destroy()


def test_a_finding_clicked_on_the_camera_lands_where_the_camera_saw_it(
    browser_page: Any, make_context: Callable[..., Context], camera_robot: CameraRobot, tmp_path: Path
) -> None:
    page, errors = browser_page
    folder = tmp_path / "findings"
    u, v = 100.0, 40.0  # the pixel the operator clicks
    title = "<img src=x onerror=window.injected=1> cracked weld"
    with (
        FindingsNode(make_context(), folder, position_period_s=0.2) as findings_node,
        StationServer(make_context(), port=0) as server,
    ):
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.lastFrameSeq > 2", timeout=30000)
        assert page.evaluate("window.fleetslam.selected") == "c3po"
        box = page.locator("#camera").bounding_box()
        assert box is not None
        scale = min(box["width"] / INTRINSICS.width, box["height"] / INTRINSICS.height)
        left = (box["width"] - INTRINSICS.width * scale) / 2
        top = (box["height"] - INTRINSICS.height * scale) / 2
        page.click("#camera", position={"x": left + (u + 0.5) * scale, "y": top + (v + 0.5) * scale})
        page.wait_for_selector("#finding-form:not([hidden])", timeout=10000)
        page.fill("#finding-title", title)
        page.select_option("#finding-severity", "high")
        page.fill("#finding-note", "north flange, 2 cm")
        page.click("#finding-save")
        page.wait_for_function("window.fleetslam.findings.length === 1", timeout=20000)
        page.wait_for_function("Object.values(window.fleetslam.findingMarkers()).every((p) => p)", timeout=20000)

        finding = findings_node.store.get("F001")
        assert (finding.title, finding.severity, finding.note, finding.agent) == (title, "high", "north flange, 2 cm",
                                                                                  "c3po")  # fmt: skip
        assert abs(finding.pixel[0] - u) < 0.6 and abs(finding.pixel[1] - v) < 0.6, finding.pixel
        # The frame the operator clicked on is the one the finding was taken from: its pose gives the truth.
        assert str(finding.stamp_ns) == page.evaluate("window.fleetslam.lastFindingPick.stamp")
        truth = wall_hit(camera_robot.poses[finding.stamp_ns], u, v)[:3]
        drawn = np.array(page.evaluate("window.fleetslam.findingMarkers()")["F001"])
        error = np.linalg.norm(drawn - truth)
        print(f"finding {error * 100:.2f} cm from the true point ({truth[0]:.2f}, {truth[1]:.2f}, {truth[2]:.2f})")
        assert error < 0.05, (drawn, truth)
        save_screenshot(page, tmp_path, "console-finding.png")

        # The list shows it (as text: nothing injected), clicking it shows the photo.
        assert page.evaluate("window.injected") is None
        assert title in page.inner_text("#findings-list")
        page.click("#findings-list li")
        page.wait_for_function("document.getElementById('finding-photo').src.startsWith('data:image/jpeg')")
        assert "north flange" in page.inner_text("#finding-text")

        # The graph is corrected (a loop closure moves every keyframe): the finding moves with its keyframe.
        correction = pose_from_xyz_rpy(0.3, -0.2, 0.0, 0.0, 0.0, 0.2)
        camera_robot.keyframes = [correction @ k for k in KEYFRAMES]
        moved = transform_points(correction, [drawn])[0]

        def marker() -> np.ndarray:
            return np.array(page.evaluate("window.fleetslam.findingMarkers()")["F001"])

        assert wait_until(lambda: np.linalg.norm(marker() - moved) < 1e-3, 10.0), (marker(), moved)

        def stored() -> list[float] | None:
            position = json.loads((folder / "findings.json").read_text())["findings"][0]["position"]
            return None if position is None else list(position)

        assert wait_until(lambda: stored() is not None and np.linalg.norm(np.array(stored()) - moved) < 1e-3, 10.0)
        # Closing it from the console reaches the fleet's store.
        page.click("#finding-toggle")
        assert wait_until(lambda: findings_node.store.get("F001").status == "closed", 10.0)
    assert (folder / "F001.jpg").read_bytes()[:2] == b"\xff\xd8"
    assert not errors, errors


def test_measuring_between_two_pixels_of_the_camera_image(
    browser_page: Any, make_context: Callable[..., Context], camera_robot: CameraRobot
) -> None:
    """Two clicks on the image (the camera moves between them): the distance between the wall points seen there."""
    page, errors = browser_page
    with StationServer(make_context(), port=0) as server:
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.lastFrameSeq > 2", timeout=30000)
        page.check("#measure-toggle")
        box = page.locator("#camera").bounding_box()
        assert box is not None
        scale = min(box["width"] / INTRINSICS.width, box["height"] / INTRINSICS.height)
        left = (box["width"] - INTRINSICS.width * scale) / 2
        top = (box["height"] - INTRINSICS.height * scale) / 2
        picked = []
        for u, v in ((20.0, 30.0), (140.0, 100.0)):
            page.click("#camera", position={"x": left + (u + 0.5) * scale, "y": top + (v + 0.5) * scale})
            count = len(picked) + 1
            page.wait_for_function(f"window.fleetslam.measure.points.length === {count}", timeout=15000)
            stamp = int(page.evaluate(f"window.fleetslam.measure.points[{count - 1}].stamp"))
            picked.append(wall_hit(camera_robot.poses[stamp], u, v)[:3])
            time.sleep(0.5)  # the camera moves on: the second pixel is of another frame
        distance = page.evaluate("window.fleetslam.measure.distance")
        truth = float(np.linalg.norm(picked[1] - picked[0]))
        print(f"measured {distance:.3f} m, true {truth:.3f} m")
        assert abs(distance - truth) < 0.05, (distance, truth)
        assert page.inner_text("#measure-result") == f"distance {distance:.3f} m"
    assert not errors, errors


def _voxels_stable(page: Any) -> bool:
    """Whether the map's voxel count stayed the same for a second and a half."""
    first = page.evaluate("window.fleetslam.voxelCount")
    time.sleep(1.5)
    return bool(first > 0 and first == page.evaluate("window.fleetslam.voxelCount"))


def test_measuring_between_two_voxels_of_the_3d_view(
    browser_page: Any, make_context: Callable[..., Context], test_robot: Any
) -> None:
    """Two clicks on the map in the 3D view: the distance between the voxels under the pointer."""
    page, errors = browser_page
    # The voxels the console draws of the robot's block (conftest's test_robot), and two top corners of it.
    grid = np.stack(np.meshgrid(np.arange(20), np.arange(10), [0, 1, 2], indexing="ij"), -1).reshape(-1, 3)
    voxels = VoxelDiff(0.05)
    voxels.update(((grid * 0.05 + 0.025) + [1.0, 0.0, 0.0]).astype(np.float32).astype(np.float64))
    centres = voxels.centres(voxels.keys())
    top = centres[np.isclose(centres[:, 2], centres[:, 2].max())]
    a, b = top[np.argmin(top[:, 0] + top[:, 1])], top[np.argmax(top[:, 0] + top[:, 1])]
    with StationServer(make_context(), port=0) as server:
        page.goto(server.url)
        # The whole block has arrived (the robot sends it growing, 20 points a frame): the count stops changing.
        page.wait_for_function("window.fleetslam && window.fleetslam.voxelCount > 0", timeout=30000)
        assert wait_until(lambda: _voxels_stable(page), 30.0, 0.1)
        page.check("#measure-toggle")
        for count, point in enumerate((a, b), start=1):
            x, y = page.evaluate(f"window.fleetslam.screenOf({point[0]}, {point[1]}, {point[2]})")
            page.mouse.click(x, y)
            page.wait_for_function(f"window.fleetslam.measure.points.length === {count}", timeout=10000)
        distance = page.evaluate("window.fleetslam.measure.distance")
        picked = np.array(page.evaluate("window.fleetslam.measure.points.map((p) => p.world)"))
        truth = float(np.linalg.norm(b - a))
        print(f"measured {distance:.3f} m on the map, true {truth:.3f} m; picked {picked.round(3).tolist()}")
        # The voxel under the pointer, or a neighbour along the ray (at most one voxel away in each axis).
        assert np.linalg.norm(picked - [a, b], axis=1).max() < 0.09, picked
        assert abs(distance - np.linalg.norm(picked[1] - picked[0])) < 1e-6
    assert not errors, errors


@dataclass
class SimCamera:
    plant: Any
    T_world_camera: np.ndarray
    intrinsics: Intrinsics
    keyframes: list[np.ndarray] = field(default_factory=list)


@pytest.fixture
def sim_camera(make_context: Callable[..., Context]) -> Iterator[SimCamera]:
    """c3po standing in the simulator's hall: its camera's frames (MuJoCo rendering, the Kinect depth model) published
    as the simulator node would, SLAM's pose taken as the true one (the console is under test, not SLAM)."""
    pytest.importorskip("mujoco")
    from fleetslam.sim.config import RobotPlacement, SimConfig
    from fleetslam.sim.plant import Plant

    plant = Plant(SimConfig(), [RobotPlacement(name="c3po", x=-12.0, y=-7.5, yaw=-np.pi / 2)], controllers=False)
    plant.step(0.2)
    camera = SimCamera(plant, plant.camera_pose("c3po"), plant.intrinsics_at(160, 120))
    camera.keyframes = [
        camera.T_world_camera @ pose_from_xyz_rpy(-0.2, 0.0, -0.3, 0.0, 0.0, 0.0),
        camera.T_world_camera,
    ]
    node = Node("sim", context=make_context("c3po"))
    qos = QoSProfile(depth=2)
    rgb_pub = node.create_publisher(topics.RGB_IMAGE.type, topics.RGB_IMAGE.name, qos)
    depth_pub = node.create_publisher(topics.DEPTH_IMAGE.type, topics.DEPTH_IMAGE.name, qos)
    info_pub = node.create_publisher(topics.CAMERA_INFO.type, topics.CAMERA_INFO.name, qos)
    odom_pub = node.create_publisher(topics.SLAM_ODOM.type, topics.SLAM_ODOM.name, qos)
    path_pub = node.create_publisher(topics.PATH.type, topics.PATH.name, topics.PATH.qos())
    stop = threading.Event()

    def publish() -> None:
        i = 0
        while not stop.is_set():
            frame = plant.render("c3po", width=160, height=120)  # MuJoCo's GL context lives in this thread
            stamp = time.time_ns()
            pose = pose_msg(frame.T_world_camera)
            odom_pub.publish(odometry_msg(pose, frame_id="map", child_frame_id="camera", stamp_ns=stamp))
            info_pub.publish(camera_info_msg(frame.intrinsics, frame_id="camera", stamp_ns=stamp))
            depth_pub.publish(image_msg(frame.depth, "32FC1", frame_id="camera", stamp_ns=stamp))
            rgb_pub.publish(image_msg(frame.rgb, "rgb8", frame_id="camera", stamp_ns=stamp))
            if i % 3 == 0:
                stamped = get_type("geometry_msgs/msg/PoseStamped")
                h = header("map", stamp)
                poses = [stamped(header=h, pose=p) for p in pose_msgs(camera.keyframes)]
                path_pub.publish(get_type("nav_msgs/msg/Path")(header=h, poses=poses))
            i += 1
            time.sleep(0.2)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    yield camera
    stop.set()
    thread.join()
    node.destroy()
    plant.close()


def test_a_finding_in_the_simulated_hall_lands_on_the_simulators_geometry(
    browser_page: Any, make_context: Callable[..., Context], sim_camera: SimCamera, tmp_path: Path
) -> None:
    """The simulator's own ray cast (MuJoCo's mj_ray against the hall's geometry) is the truth; the console's point
    comes from the noisy Kinect-model depth at the clicked pixel."""
    import mujoco

    page, errors = browser_page
    u, v = 100.0, 40.0
    K, T = sim_camera.intrinsics, sim_camera.T_world_camera
    direction = T[:3, :3] @ np.array([(u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0])
    body = sim_camera.plant.robot("c3po").body_id
    scale = mujoco.mj_ray(sim_camera.plant.model, sim_camera.plant.data, T[:3, 3], direction, None, 1, body,
                          np.zeros(1, np.int32))  # fmt: skip
    assert 0.5 < scale < 4.0, f"pixel ({u}, {v}) sees nothing in the camera's range ({scale} m)"
    truth = T[:3, 3] + scale * direction
    with (
        FindingsNode(make_context(), tmp_path / "findings") as findings_node,
        StationServer(make_context(), port=0) as server,
    ):
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.lastFrameSeq > 2", timeout=60000)
        box = page.locator("#camera").bounding_box()
        assert box is not None
        px = min(box["width"] / K.width, box["height"] / K.height)
        left, top = (box["width"] - K.width * px) / 2, (box["height"] - K.height * px) / 2
        page.click("#camera", position={"x": left + (u + 0.5) * px, "y": top + (v + 0.5) * px})
        page.wait_for_selector("#finding-form:not([hidden])", timeout=15000)
        page.fill("#finding-title", "oil stain")
        page.click("#finding-save")
        page.wait_for_function("Object.values(window.fleetslam.findingMarkers()).some((p) => p)", timeout=30000)
        drawn = np.array(page.evaluate("window.fleetslam.findingMarkers()")["F001"])
        error = float(np.linalg.norm(drawn - truth))
        print(f"finding {error * 100:.2f} cm from the simulator's point {truth.round(3).tolist()}")
        assert error < 0.05, (drawn, truth)
        save_screenshot(page, tmp_path, "console-finding-sim.png")
        # A loop closure moves the keyframes: the finding follows its keyframe.
        correction = pose_from_xyz_rpy(0.0, 0.5, 0.0, 0.0, 0.0, -0.1)
        sim_camera.keyframes = [correction @ k for k in sim_camera.keyframes]
        moved = transform_points(correction, [drawn])[0]
        assert wait_until(
            lambda: np.linalg.norm(np.array(page.evaluate("window.fleetslam.findingMarkers()")["F001"]) - moved) < 1e-3,
            15.0,
        )
        assert findings_node.store.get("F001").title == "oil stain"
    assert not errors, errors
