from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer
from rosbags.typesys import Stores, get_typestore

from fleetslam.datasets import guess_kind, open_source

STORE = get_typestore(Stores.ROS2_HUMBLE)
Image = STORE.types["sensor_msgs/msg/Image"]
CameraInfo = STORE.types["sensor_msgs/msg/CameraInfo"]
Header = STORE.types["std_msgs/msg/Header"]
Time = STORE.types["builtin_interfaces/msg/Time"]
RegionOfInterest = STORE.types["sensor_msgs/msg/RegionOfInterest"]


def _header(stamp: float) -> object:
    sec = int(stamp)
    return Header(stamp=Time(sec=sec, nanosec=round((stamp - sec) * 1e9)), frame_id="camera")


def _write(path: Path, n: int) -> None:
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("ros2", "fleetslam-test")
        channels = {}
        for topic, typename in (
            ("/cam/color/image_raw", "sensor_msgs/msg/Image"),
            ("/cam/depth/image_raw", "sensor_msgs/msg/Image"),
            ("/cam/color/camera_info", "sensor_msgs/msg/CameraInfo"),
        ):
            schema = writer.register_schema(typename, "ros2msg", STORE.generate_msgdef(typename)[0].encode())
            channels[topic] = writer.register_channel(topic, "cdr", schema)

        def put(topic: str, msg: object, typename: str, stamp: float) -> None:
            data = bytes(STORE.serialize_cdr(msg, typename))
            writer.add_message(channels[topic], int(stamp * 1e9), data, int(stamp * 1e9))

        info = CameraInfo(
            header=_header(0.0),
            height=4,
            width=6,
            distortion_model="plumb_bob",
            d=np.zeros(5),
            k=np.array([100.0, 0, 2.5, 0, 101.0, 1.5, 0, 0, 1]),
            r=np.eye(3).ravel(),
            p=np.zeros(12),
            binning_x=0,
            binning_y=0,
            roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        )
        put("/cam/color/camera_info", info, "sensor_msgs/msg/CameraInfo", 0.0)
        for i in range(n):
            stamp = 10.0 + i / 30.0
            bgr = np.zeros((4, 6, 3), np.uint8)
            bgr[:, :, 2] = 10 * i
            color = Image(
                header=_header(stamp), height=4, width=6, encoding="bgr8", is_bigendian=0, step=18, data=bgr.ravel()
            )
            depth_mm = np.full((4, 6), 1000 + i, np.uint16)
            depth = Image(
                header=_header(stamp + 0.005),
                height=4,
                width=6,
                encoding="16UC1",
                is_bigendian=0,
                step=12,
                data=depth_mm.view(np.uint8).ravel(),
            )
            put("/cam/color/image_raw", color, "sensor_msgs/msg/Image", stamp)
            put("/cam/depth/image_raw", depth, "sensor_msgs/msg/Image", stamp + 0.005)
        writer.finish()


def test_mcap_pairs_colour_and_depth(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _write(path, 4)
    assert guess_kind(path) == "mcap"
    source = open_source(path)
    assert len(source) == 4
    assert source.intrinsics.fy == 101.0 and source.intrinsics.width == 6
    frames = list(source)
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert frames[2].rgb[0, 0, 0] == 20  # BGR converted to RGB
    assert frames[3].depth[0, 0] == pytest.approx(1.003)
    assert frames[1].stamp == pytest.approx(10.0 + 1 / 30.0)


def test_mcap_every_other_frame_decodes_only_those(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _write(path, 5)
    source = open_source(path)
    everything = list(source)
    every_other = list(source.frames(every=2))
    assert [f.index for f in every_other] == [0, 2, 4]
    for frame in every_other:
        assert frame.stamp == everything[frame.index].stamp
        np.testing.assert_array_equal(frame.rgb, everything[frame.index].rgb)
        np.testing.assert_array_equal(frame.depth, everything[frame.index].depth)
