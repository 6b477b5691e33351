"""The bridge between a real fleet (Zenoh router, fleetslam nodes) and a real ROS 1 master, checked with the
ROS 1 tools themselves: rostopic echo/hz/pub, rosbag record/info, and a rospy camera node."""

from __future__ import annotations

import re
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from fleetslam.cli.main import main
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.typesys import message_from_dict
from fleetslam.ros1.bridge import Ros1Bridge, TopicRule
from fleetslam.ros1.node import Ros1Node

from ..support import free_port, wait_until
from .conftest import Master, need_ros1

CAMERA = Path(__file__).resolve().parents[2] / "benchmarks" / "ros1_camera.py"


@pytest.fixture
def bridge(roscore: Master, make_context: Callable[..., Context]) -> Iterator[Ros1Bridge]:
    need_ros1("rostopic", "rosbag")
    with (
        Ros1Node("fleetslam_bridge", master_uri=roscore.uri) as ros1,
        Node("fleetslam_bridge", context=make_context()) as node,
        Ros1Bridge(node, ros1, to_ros1=[TopicRule.parse("/c3po/*")], from_ros1=[TopicRule.parse("/ros1/*")],
                   scan_period_s=0.2) as bridge,
    ):  # fmt: skip
        yield bridge


@pytest.fixture
def fleet_talker(make_context: Callable[..., Context]) -> Iterator[Node]:
    """/c3po/chatter (std_msgs/String, 20 Hz) and a latched /c3po/map/info, from an ordinary fleet node."""
    node = Node("talker", context=make_context())
    chatter = node.create_publisher("std_msgs/msg/String", "/c3po/chatter")
    latched = node.create_publisher(
        "std_msgs/msg/String", "/c3po/map/info", QoSProfile(durability="transient_local", depth=1)
    )
    latched.publish(message_from_dict("std_msgs/msg/String", {"data": "map v1"}))
    count = iter(range(1 << 30))
    node.create_timer(
        0.05, lambda: chatter.publish(message_from_dict("std_msgs/msg/String", {"data": f"hi {next(count)}"}))
    )
    yield node
    node.destroy()


def _tool(master: Master, *args: str, timeout_s: float = 30.0) -> str:
    done = subprocess.run(list(args), env=master.env, capture_output=True, text=True, timeout=timeout_s)
    return done.stdout + done.stderr


def test_rostopic_echo_and_hz_see_a_fleet_topic(roscore: Master, bridge: Ros1Bridge, fleet_talker: Node) -> None:
    assert wait_until(lambda: "/c3po/chatter" in bridge.bridged_to_ros1, timeout_s=10)
    assert re.search(r'data: "hi \d+"', _tool(roscore, "rostopic", "echo", "-n", "1", "/c3po/chatter"))
    hz = _tool(roscore, "timeout", "-s", "INT", "6", "rostopic", "hz", "/c3po/chatter")
    rates = [float(r) for r in re.findall(r"average rate: ([\d.]+)", hz)]
    assert rates and 15.0 < rates[-1] < 25.0, hz
    # Latched in the fleet (transient local) -> latched in ROS 1: a late rostopic gets the one message.
    assert 'data: "map v1"' in _tool(roscore, "rostopic", "echo", "-n", "1", "/c3po/map/info")
    assert "Type: std_msgs/String" in _tool(roscore, "rostopic", "info", "/c3po/chatter")


def test_rostopic_pub_reaches_fleetslam_topic_echo(
    roscore: Master, bridge: Ros1Bridge, fleet_env: str, capsys: pytest.CaptureFixture[str]
) -> None:
    pub = subprocess.Popen(
        ["rostopic", "pub", "-r", "5", "/ros1/cmd_vel", "geometry_msgs/Twist",
         "{linear: {x: 0.25}, angular: {z: -0.5}}"],
        env=roscore.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        assert wait_until(lambda: "/ros1/cmd_vel" in bridge.bridged_from_ros1, timeout_s=15)
        assert main(["topic", "echo", "/ros1/cmd_vel", "--count", "1", "--timeout", "20"]) == 0
    finally:
        pub.terminate()
        pub.wait(timeout=10)
    out = capsys.readouterr().out
    assert "x: 0.25" in out and "z: -0.5" in out, out


def test_rosbag_records_bridged_topics(roscore: Master, bridge: Ros1Bridge, fleet_talker: Node, tmp_path: Path) -> None:
    assert wait_until(lambda: len(bridge.bridged_to_ros1) == 2, timeout_s=10)
    bag = tmp_path / "fleet.bag"
    record = subprocess.Popen(
        ["rosbag", "record", "-O", str(bag), "/c3po/chatter", "/c3po/map/info"],
        env=roscore.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path,
    )  # fmt: skip
    time.sleep(4)
    _tool(roscore, "rosnode", "kill", "-a")  # rosbag flushes and closes the bag when asked to stop this way
    record.wait(timeout=20)
    info = _tool(roscore, "rosbag", "info", str(bag))
    chatter = re.search(r"/c3po/chatter\s+(\d+) msgs\s+: std_msgs/String", info)
    assert chatter and int(chatter.group(1)) >= 30, info
    assert re.search(r"/c3po/map/info\s+1 msg\s+: std_msgs/String", info), info


def test_a_rospy_camera_streams_into_the_fleet(
    roscore: Master, bridge: Ros1Bridge, make_context: Callable[..., Context]
) -> None:
    need_ros1()
    frames: list[tuple[int, int, str, int]] = []
    lock = threading.Lock()

    def on_image(msg: object) -> None:
        with lock:
            frames.append((msg.height, msg.width, msg.encoding, len(msg.data)))  # type: ignore[attr-defined]

    with Node("viewer", context=make_context()) as viewer:
        viewer.create_subscription("sensor_msgs/msg/Image", "/ros1/camera/rgb/image_raw", on_image)
        camera = subprocess.Popen(
            ["/usr/bin/python3", str(CAMERA), "--topic", "/ros1/camera/rgb/image_raw", "--rate", "10",
             "--width", "160", "--height", "120"],
            env=roscore.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert wait_until(lambda: len(frames) >= 10, timeout_s=30), camera.poll()
        finally:
            camera.terminate()
            camera.wait(timeout=10)
    assert frames[-1] == (120, 160, "rgb8", 120 * 160 * 3)
    assert bridge.topic_counts()["/ros1/camera/rgb/image_raw"]["errors"] == 0


def test_cli_names_an_unreachable_master(
    fleet_env: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    uri = f"http://127.0.0.1:{free_port()}"
    monkeypatch.setenv("ROS_MASTER_URI", uri)
    assert main(["bridge", "ros1", "--all", "--duration", "1"]) != 0
    assert f"ROS master at {uri} is unreachable" in capsys.readouterr().err


def test_ros1_odometry_in_and_fleet_cmd_vel_out(
    roscore: Master, bridge: Ros1Bridge, make_context: Callable[..., Context]
) -> None:
    """A ROS 1 robot's wheel odometry reaches fleetslam; fleetslam's cmd_vel reaches the ROS 1 base."""
    poses: list[tuple[float, float, str]] = []
    odom = subprocess.Popen(
        ["rostopic", "pub", "-r", "5", "/ros1/odom", "nav_msgs/Odometry",
         "{header: {frame_id: odom}, child_frame_id: base_link, pose: {pose: {position: {x: 1.5, y: -2.0}, "
         "orientation: {w: 1.0}}}}"],
        env=roscore.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    with Node("base", context=make_context(), namespace="/c3po") as base:
        base.create_subscription(
            "nav_msgs/msg/Odometry", "/ros1/odom",
            lambda m: poses.append((m.pose.pose.position.x, m.pose.pose.position.y, m.child_frame_id)),
        )  # fmt: skip
        cmd_vel = base.create_publisher("geometry_msgs/msg/Twist", "cmd_vel")
        twist = message_from_dict("geometry_msgs/msg/Twist", {"linear": {"x": 0.3}, "angular": {"z": 0.7}})
        base.create_timer(0.1, lambda: cmd_vel.publish(twist))
        try:
            assert wait_until(lambda: len(poses) >= 2, timeout_s=20)
            assert wait_until(lambda: "/c3po/cmd_vel" in bridge.bridged_to_ros1, timeout_s=10)
            echoed = _tool(roscore, "rostopic", "echo", "-n", "1", "/c3po/cmd_vel")
        finally:
            odom.terminate()
            odom.wait(timeout=10)
    assert poses[-1] == (1.5, -2.0, "base_link")
    assert re.search(r"linear:\s+x: 0\.3", echoed) and re.search(r"angular:\s+x: 0\.0\s+y: 0\.0\s+z: 0\.7", echoed), (
        echoed
    )
