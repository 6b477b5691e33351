"""`fleetslam convert`: a recording becomes a ROS 1 bag that Debian's rosbag reads, message for message."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from fleetslam.cli.main import main
from fleetslam.errors import DatasetError
from fleetslam.middleware.recording import BagWriter
from fleetslam.msg.typesys import message_from_dict, serialize
from fleetslam.ros1.bag import convert_to_rosbag1

from .conftest import Master, need_ros1

_READ = """
import rosbag, sys
with rosbag.Bag(sys.argv[1]) as bag:
    for topic, msg, t in bag.read_messages():
        if topic == "/c3po/chatter":
            print("chatter", msg.data)
        elif topic == "/c3po/camera/rgb/image_raw":
            print("image", msg.width, msg.height, msg.encoding, msg.header.frame_id, sum(bytearray(msg.data)))
"""


def _recording(path: Path) -> int:
    image = message_from_dict(
        "sensor_msgs/msg/Image",
        {"header": {"frame_id": "camera_rgb_optical_frame"}, "height": 4, "width": 5, "encoding": "rgb8", "step": 15},
    )
    image.data = np.arange(60, dtype=np.uint8)
    with BagWriter(path) as bag:
        for i in range(10):
            text = message_from_dict("std_msgs/msg/String", {"data": f"hello {i}"})
            bag.write(
                "/c3po/chatter",
                "std_msgs/msg/String",
                1_000_000_000 + i * 100_000_000,
                serialize(text, "std_msgs/msg/String"),
            )
            bag.write("/c3po/camera/rgb/image_raw", "sensor_msgs/msg/Image", 1_000_000_000 + i * 100_000_000 + 1,
                      serialize(image, "sensor_msgs/msg/Image"))  # fmt: skip
        return int(np.arange(60).sum())


def test_converted_bag_is_read_by_rosbag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    need_ros1("rosbag")
    checksum = _recording(tmp_path / "run")
    out = tmp_path / "run.bag"
    assert main(["convert", str(tmp_path / "run"), str(out)]) == 0
    assert "wrote" in capsys.readouterr().err
    info = subprocess.run(["rosbag", "info", str(out)], capture_output=True, text=True, timeout=60).stdout
    assert re.search(r"/c3po/chatter\s+10 msgs\s+: std_msgs/String", info), info
    assert re.search(r"/c3po/camera/rgb/image_raw\s+10 msgs\s+: sensor_msgs/Image", info), info
    read = subprocess.run(["/usr/bin/python3", "-c", _READ, str(out)], capture_output=True, text=True, timeout=60)
    assert read.returncode == 0, read.stderr
    lines = read.stdout.splitlines()
    assert [x for x in lines if x.startswith("chatter")] == [f"chatter hello {i}" for i in range(10)]
    assert f"image 5 4 rgb8 camera_rgb_optical_frame {checksum}" in lines


def test_rosbag_play_replays_a_converted_bag(tmp_path: Path, roscore: Master) -> None:
    need_ros1("rosbag", "rostopic")
    _recording(tmp_path / "run")
    assert main(["convert", str(tmp_path / "run"), str(tmp_path / "run.bag")]) == 0
    echo = subprocess.Popen(["rostopic", "echo", "-n", "3", "/c3po/chatter"], env=roscore.env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        play = subprocess.run(["rosbag", "play", "--wait-for-subscribers", "--topics", "/c3po/chatter", "--",
                               str(tmp_path / "run.bag")], env=roscore.env, capture_output=True, text=True,
                              timeout=60)  # fmt: skip
        out, _ = echo.communicate(timeout=30)
    finally:
        echo.kill()
    assert play.returncode == 0, play.stderr
    assert re.findall(r'data: "(hello \d)"', out) == ["hello 0", "hello 1", "hello 2"], out


def test_existing_output_is_refused(tmp_path: Path) -> None:
    _recording(tmp_path / "run")
    (tmp_path / "run.bag").write_bytes(b"precious")
    with pytest.raises(DatasetError, match="already exists"):
        convert_to_rosbag1(tmp_path / "run", tmp_path / "run.bag")
    assert (tmp_path / "run.bag").read_bytes() == b"precious"
