"""ROS 1 types and conversions, checked against Debian's own ROS 1 message classes (genpy) where installed."""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
from importlib import resources

import numpy as np
import pytest

from fleetslam.errors import MessageError
from fleetslam.msg import typesys
from fleetslam.ros1 import messages

TYPES = [
    "std_msgs/String",
    "geometry_msgs/Twist",
    "nav_msgs/Odometry",
    "nav_msgs/Path",
    "sensor_msgs/Image",
    "sensor_msgs/CameraInfo",
    "sensor_msgs/PointCloud2",
    "tf2_msgs/TFMessage",
    "visualization_msgs/MarkerArray",
]

_GENPY = """
import importlib, json, sys
out = {}
for name in json.loads(sys.argv[1]):
    pkg, cls = name.split("/")
    t = getattr(importlib.import_module(pkg + ".msg"), cls)
    out[name] = [t._md5sum, t._full_text]
print(json.dumps(out))
"""


def _genpy(names: list[str]) -> dict[str, list[str]]:
    python = shutil.which("python3", path="/usr/bin")
    if python is None:
        pytest.skip("Debian's /usr/bin/python3 not found")
    done = subprocess.run([python, "-c", _GENPY, json.dumps(names)], capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        pytest.skip(f"Debian's ROS 1 message packages not importable: {done.stderr.strip()[-200:]}")
    return dict(json.loads(done.stdout))


def test_md5sums_match_debians_ros1_messages() -> None:
    reference = _genpy(TYPES)
    for name in TYPES:
        assert messages.type_info(name).md5sum == reference[name][0], name
        assert messages.type_info(name).ros1_name == name


def test_image_converts_both_ways_byte_exactly() -> None:
    image = typesys.message_from_dict(
        "sensor_msgs/msg/Image",
        {"header": {"frame_id": "camera_rgb_optical_frame", "stamp": {"sec": 7, "nanosec": 9}}, "height": 4,
         "width": 3, "encoding": "rgb8", "step": 9},
    )  # fmt: skip
    image.data = np.arange(36, dtype=np.uint8)
    cdr = typesys.serialize(image, "sensor_msgs/msg/Image")
    raw = messages.cdr_to_ros1(cdr, "sensor_msgs/msg/Image")
    # ROS 1 layout: seq, stamp (secs, nsecs), frame_id, height, width, ...
    assert raw[:12] == np.array([0, 7, 9], dtype="<u4").tobytes()
    assert raw.endswith(np.arange(36, dtype=np.uint8).tobytes())
    assert messages.ros1_to_cdr(raw, "sensor_msgs/Image") == cdr


_GENPY_CAMERA_INFO = """
import sys
from sensor_msgs.msg import CameraInfo
info = CameraInfo()
info.deserialize(sys.stdin.buffer.read())
print(info.width, info.height, info.distortion_model, list(info.D), list(info.K), list(info.R), list(info.P),
      info.binning_x, info.roi.width)
"""


def test_camera_info_keeps_its_calibration_both_ways() -> None:
    """ROS 2 spells CameraInfo's D, K, R, P in lower case: a copy by exact name zeroed them both ways (a ROS 1
    Kinect driver's camera_info reached SLAM with K all zeros), so they are matched up to case."""
    k = [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0]
    r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    p = [525.0, 0.0, 319.5, 0.0, 0.0, 525.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    d = [0.1, -0.2, 0.001, 0.002, 0.0]
    info = typesys.message_from_dict(
        "sensor_msgs/msg/CameraInfo",
        {"header": {"frame_id": "camera_rgb_optical_frame"}, "width": 640, "height": 480,
         "distortion_model": "plumb_bob", "d": d, "k": k, "r": r, "p": p, "binning_x": 2, "roi": {"width": 320}},
    )  # fmt: skip
    cdr = typesys.serialize(info, "sensor_msgs/msg/CameraInfo")
    raw = messages.cdr_to_ros1(cdr, "sensor_msgs/msg/CameraInfo")
    ros1 = messages.ros1_typestore().deserialize_ros1(raw, "sensor_msgs/msg/CameraInfo")
    assert (list(ros1.K), list(ros1.D), list(ros1.R), list(ros1.P)) == (k, d, r, p)
    assert messages.ros1_to_cdr(raw, "sensor_msgs/CameraInfo") == cdr
    python = shutil.which("python3", path="/usr/bin")
    if python is None:
        pytest.skip("Debian's /usr/bin/python3 not found")
    done = subprocess.run([python, "-c", _GENPY_CAMERA_INFO], input=raw, capture_output=True, timeout=60)
    if done.returncode != 0:
        pytest.skip(f"Debian's sensor_msgs not importable: {done.stderr.decode()[-200:]}")
    assert done.stdout.decode().split("\n")[0] == f"640 480 plumb_bob {d} {k} {r} {p} 2 320"


def test_no_field_is_renamed_between_ros1_and_ros2_beyond_case() -> None:
    """The conversion copies fields by name up to case: every other field of every type both stores know must be one
    that one side lacks (Header.seq, ROS 2 additions), or it would be silently zeroed."""
    ros1, ros2 = messages.ros1_typestore(), typesys.get_typestore()
    one_sided = {
        "std_msgs/msg/Header": {"seq"},
        "sensor_msgs/msg/Range": {"variance"},
        "shape_msgs/msg/SolidPrimitive": {"polygon"},
        "visualization_msgs/msg/Marker": {"texture_resource", "texture", "uv_coordinates", "mesh_file"},
    }
    for name in sorted(set(ros1.fielddefs) & set(ros2.fielddefs)):
        names1 = {n.lower() for n, _ in ros1.fielddefs[name][1]}
        names2 = {n.lower() for n, _ in ros2.fielddefs[name][1]}
        assert names1 ^ names2 <= one_sided.get(name, set()), (name, names1 ^ names2)


def test_marker_fields_added_in_ros2_are_dropped_and_zeroed() -> None:
    array = typesys.message_from_dict(
        "visualization_msgs/msg/MarkerArray",
        {"markers": [{"ns": "map", "id": 3, "type": 6, "points": [{"x": 1.0}, {"y": 2.0}], "mesh_file": {}}]},
    )
    raw = messages.cdr_to_ros1(
        typesys.serialize(array, "visualization_msgs/msg/MarkerArray"), "visualization_msgs/MarkerArray"
    )
    back = typesys.deserialize(
        messages.ros1_to_cdr(raw, "visualization_msgs/MarkerArray"), "visualization_msgs/msg/MarkerArray"
    )
    marker = back.markers[0]
    assert (marker.ns, marker.id, marker.type, marker.points[1].y) == ("map", 3, 6, 2.0)


def test_bad_bytes_and_names_raise_clear_errors() -> None:
    with pytest.raises(MessageError, match="sensor_msgs/msg/Image from ROS 1"):
        messages.ros1_to_cdr(b"\x01\x02\x03", "sensor_msgs/Image")
    with pytest.raises(MessageError, match="not a ROS 1 message type name"):
        messages.ros2_name("Image")
    with pytest.raises(MessageError, match="not known on the ROS 1 side"):
        messages.type_info("nosuch_msgs/Thing")


_GENMSG_SERVICES = """
import json, os, sys, tempfile
import genmsg, genmsg.gentools, genmsg.msg_loader
import std_srvs.srv
from geometry_msgs.msg import Point
out = {name: getattr(std_srvs.srv, name)._md5sum for name in ("Empty", "SetBool", "Trigger")}
folder = tempfile.mkdtemp()
os.makedirs(os.path.join(folder, "geometry_msgs"))
with open(os.path.join(folder, "geometry_msgs", "Point.msg"), "w") as file:
    file.write(Point._full_text)
for name, text in json.loads(sys.argv[1]).items():
    context = genmsg.MsgContext.create_default()
    spec = genmsg.msg_loader.load_srv_from_string(context, text, "fleetslam_msgs/" + name)
    genmsg.msg_loader.load_depends(context, spec, {"geometry_msgs": [os.path.join(folder, "geometry_msgs")]})
    out[name] = genmsg.gentools.compute_md5(context, spec)
print(json.dumps(out))
"""


def test_service_md5sums_match_debians_genmsg() -> None:
    """std_srvs from Debian's python3-std-srvs; our own .srv files through Debian's genmsg, as catkin would."""
    python = shutil.which("python3", path="/usr/bin")
    if python is None:
        pytest.skip("Debian's /usr/bin/python3 not found")
    own = {name: (resources.files("fleetslam.msg") / f"{name}.srv").read_text() for name in ("SaveMap", "ClearBbx")}
    done = subprocess.run([python, "-c", _GENMSG_SERVICES, json.dumps(own)], capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        pytest.skip(f"Debian's std_srvs or genmsg not importable (python3-std-srvs): {done.stderr.strip()[-200:]}")
    reference = json.loads(done.stdout)
    for name, md5sum in reference.items():
        package = "std_srvs" if name in ("Empty", "SetBool", "Trigger") else "fleetslam_msgs"
        info = messages.service_info(f"{package}/{name}")
        assert info.md5sum == md5sum, name
        assert (info.ros1_name, info.request.ros1_name) == (f"{package}/{name}", f"{package}/{name}Request")


def test_service_requests_and_responses_convert_both_ways() -> None:
    clear = messages.service_info("fleetslam_msgs/srv/ClearBbx")
    request = typesys.message_from_dict(clear.request_name, {"min": {"x": -1.0, "y": -2.0}, "max": {"z": 3.5}})
    raw = messages.message_to_ros1(request, clear.request_name)
    assert raw == struct.pack("<6d", -1.0, -2.0, 0.0, 0.0, 0.0, 3.5)  # ROS 1: the six doubles, nothing else
    back = messages.ros1_to_message(raw, clear.request_name)
    assert (back.min.y, back.max.z) == (-2.0, 3.5)
    trigger = messages.service_info("std_srvs/Trigger")
    assert messages.message_to_ros1(messages.ros1_to_message(b"", trigger.request_name), trigger.request_name) == b""
    with pytest.raises(MessageError, match="not one that ROS 1 and the fleet both define"):
        messages.service_info("example_interfaces/srv/AddTwoInts")
    with pytest.raises(MessageError, match="cannot convert a std_srvs/srv/SetBool_Request from ROS 1"):
        messages.ros1_to_message(b"", "std_srvs/srv/SetBool_Request")
