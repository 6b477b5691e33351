"""The sim node on a real Zenoh router: camera images, camera_info, ground truth, /clock, cmd_vel."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("mujoco")

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.typesys import get_type, ns_from_stamp
from fleetslam.sim.config import RobotPlacement, SimConfig
from fleetslam.sim.node import SimNode
from fleetslam.sim.plant import Plant
from fleetslam.trajectory import read_tum

from ..support import wait_until


def test_sim_node_publishes_sensors_and_obeys_cmd_vel(make_context: Callable[..., Context], tmp_path: Path) -> None:
    received: dict[str, list[Any]] = {k: [] for k in ("rgb", "depth", "info", "truth", "clock", "odom", "tf_static")}
    with (
        Plant(SimConfig(), [RobotPlacement(name="c3po", x=-12.0, y=-7.5, yaw=0.0)], controllers=False) as plant,
        Node("listener", context=make_context()) as listener,
    ):
        sim = SimNode(make_context(), plant, camera_hz=10.0, width=160, height=120, rate=1.0,
                      ground_truth_dir=tmp_path / "truth")  # fmt: skip
        for key, type_name, topic in (
            ("rgb", "sensor_msgs/msg/Image", "/c3po/camera/rgb/image_raw"),
            ("depth", "sensor_msgs/msg/Image", "/c3po/camera/depth/image_raw"),
            ("info", "sensor_msgs/msg/CameraInfo", "/c3po/camera/rgb/camera_info"),
            ("truth", "nav_msgs/msg/Odometry", "/c3po/ground_truth/odom"),
            ("clock", "rosgraph_msgs/msg/Clock", "/clock"),
            ("odom", "nav_msgs/msg/Odometry", "/c3po/odom"),
        ):
            listener.create_subscription(type_name, topic, received[key].append)
        listener.create_subscription(
            "tf2_msgs/msg/TFMessage",
            "/c3po/tf_static",
            received["tf_static"].append,
            QoSProfile(durability="transient_local", depth=1),
        )
        cmd = listener.create_publisher("geometry_msgs/msg/Twist", "/c3po/cmd_vel")
        assert wait_until(lambda: cmd.matched_subscriptions > 0, 5.0)
        stop = threading.Event()
        thread = threading.Thread(target=sim.run, kwargs={"duration": 2.0, "stop": stop})
        thread.start()
        twist, vec3 = get_type("geometry_msgs/msg/Twist"), get_type("geometry_msgs/msg/Vector3")
        while thread.is_alive():
            cmd.publish(twist(linear=vec3(x=0.3, y=0.0, z=0.0), angular=vec3(x=0.0, y=0.0, z=0.0)))
            thread.join(0.05)
        stop.set()
        assert wait_until(lambda: len(received["rgb"]) >= 15 and len(received["truth"]) >= 50, 5.0)
        sim.close()
    rgb, depth, info = received["rgb"][-1], received["depth"][-1], received["info"][-1]
    assert (rgb.encoding, rgb.width, rgb.height, rgb.step, len(rgb.data)) == ("rgb8", 160, 120, 480, 160 * 120 * 3)
    assert (depth.encoding, depth.step) == ("32FC1", 640)
    metres = np.frombuffer(depth.data.tobytes(), dtype="<f4").reshape(120, 160)
    assert (metres > 0).mean() > 0.2 and metres.max() <= 4.5
    np.testing.assert_allclose(np.asarray(info.k).reshape(3, 3), sim.intrinsics.K)
    assert info.distortion_model == "plumb_bob" and not np.any(info.d)
    assert ns_from_stamp(rgb.header.stamp) == ns_from_stamp(depth.header.stamp)
    clocks = [ns_from_stamp(m.clock) for m in received["clock"]]
    assert clocks == sorted(clocks) and clocks[-1] >= 1.9e9
    start, end = received["truth"][0].pose.pose.position, received["truth"][-1].pose.pose.position
    assert end.x - start.x > 0.25 and abs(end.y - start.y) < 0.05  # cmd_vel 0.3 m/s for ~2 s
    assert received["odom"] and received["odom"][-1].pose.pose.position.x > 0.25
    assert 0.0 < sim.real_time_factor < 1.05  # paced: never faster than the requested rate
    static = received["tf_static"][-1].transforms[0]
    assert (static.header.frame_id, static.child_frame_id) == ("base_link", "camera_optical_frame")
    assert static.transform.translation.z == pytest.approx(0.5, abs=0.01)  # the model's 0.5 m mount (exact here)
    written = read_tum(tmp_path / "truth" / "c3po.txt")  # every published sample, also written to the file
    assert np.diff(written.stamps) == pytest.approx(0.02, abs=1e-6) and written.stamps[0] == pytest.approx(0.0)
    by_stamp = {round(t, 3): pose for t, pose in zip(written.stamps, written.poses, strict=True)}
    for message in received["truth"]:
        pose = by_stamp[round(ns_from_stamp(message.header.stamp) / 1e9, 3)]
        p = message.pose.pose.position
        assert pose[:3, 3] == pytest.approx([p.x, p.y, p.z], abs=1e-6)


def test_operator_takes_over_from_the_autopilot(make_context: Callable[..., Context]) -> None:
    """With an autopilot route the robot drives itself; an operator's cmd_vel (here: hold still) wins."""
    truth: list[Any] = []
    with (
        Plant(SimConfig(), [RobotPlacement(name="c3po", x=-12.0, y=-7.5, yaw=0.0)], controllers=False) as plant,
        Node("operator", context=make_context()) as operator,
    ):
        sim = SimNode(make_context(), plant, camera_hz=1.0, width=80, height=60, rate=1.0, autopilot="loop")
        operator.create_subscription("nav_msgs/msg/Odometry", "/c3po/ground_truth/odom", truth.append)
        cmd = operator.create_publisher("geometry_msgs/msg/Twist", "/c3po/cmd_vel")
        assert wait_until(lambda: cmd.matched_subscriptions > 0, 5.0)
        twist, vec3 = get_type("geometry_msgs/msg/Twist"), get_type("geometry_msgs/msg/Vector3")
        thread = threading.Thread(target=sim.run, kwargs={"duration": 3.0})
        thread.start()
        while thread.is_alive():  # the operator holds the robot still the whole time
            cmd.publish(twist(linear=vec3(x=0.0, y=0.0, z=0.0), angular=vec3(x=0.0, y=0.0, z=0.0)))
            thread.join(0.05)
        sim.close()
    start, end = truth[0].pose.pose.position, truth[-1].pose.pose.position
    assert abs(end.x - start.x) < 0.05 and abs(end.y - start.y) < 0.05  # the autopilot alone drives ~1 m
