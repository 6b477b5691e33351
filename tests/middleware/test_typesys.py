import numpy as np
import pytest

from fleetslam.errors import MessageError
from fleetslam.middleware import typesys as ts

SPEC_HASHES = {
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/Image": "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    "example_interfaces/srv/AddTwoInts": "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a",
}
OWN = [
    "fleetslam_msgs/msg/TopicStatistics",
    "fleetslam_msgs/msg/GraphConstraint",
    "fleetslam_msgs/msg/Keyframe",
    "fleetslam_msgs/msg/KeyframeGraph",
]


@pytest.mark.parametrize(("name", "expected"), SPEC_HASHES.items())
def test_spec_type_hashes(name: str, expected: str) -> None:
    assert ts.type_hash(name) == expected


def test_own_type_hashes_are_distinct_and_well_formed() -> None:
    names = [*OWN, "fleetslam_msgs/srv/SaveMap", "fleetslam_msgs/srv/ClearBbx", "std_srvs/srv/Trigger"]
    hashes = [ts.type_hash(n) for n in names]
    assert len(set(hashes)) == len(hashes)
    assert all(h.startswith("RIHS01_") and len(h) == 7 + 64 for h in hashes)
    # A service hash differs from its request's hash.
    assert ts.type_hash("std_srvs/srv/SetBool") != ts.type_hash("std_srvs/srv/SetBool_Request")


def test_message_hashes_agree_with_rosbags_reference() -> None:
    store = ts.get_typestore()
    for name in ["geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry", "sensor_msgs/msg/PointCloud2", *OWN]:
        assert ts.type_hash(name) == store.hash_rihs01(name)


def test_cdr_round_trip_with_header() -> None:
    string = ts.get_type("std_msgs/msg/String")
    data = ts.serialize(string(data="hi"), "std_msgs/msg/String")
    assert data == bytes.fromhex("0001000003000000686900")
    assert ts.deserialize(data, "std_msgs/msg/String").data == "hi"


@pytest.mark.parametrize("name", OWN)
def test_own_types_round_trip(name: str) -> None:
    msg = ts.message_from_dict(name, {})
    again = ts.deserialize(ts.serialize(msg, name), name)
    assert ts.message_to_dict(again) == ts.message_to_dict(msg)


def test_keyframe_with_data_round_trips() -> None:
    msg = ts.message_from_dict(
        "fleetslam_msgs/msg/Keyframe",
        {"agent": "c3po", "id": 7, "rgb": [1, 2, 3], "keypoints": [1.5, 2.5], "pose": {"position": {"x": 1.0}}},
    )
    back = ts.deserialize(ts.serialize(msg, "fleetslam_msgs/msg/Keyframe"), "fleetslam_msgs/msg/Keyframe")
    assert back.agent == "c3po" and back.id == 7 and back.pose.position.x == 1.0
    np.testing.assert_array_equal(back.rgb, [1, 2, 3])
    np.testing.assert_allclose(back.keypoints, [1.5, 2.5])


@pytest.mark.parametrize(
    "payload",
    [b"", b"\x00\x01", b"\x07\x07\x00\x00\x05\x00\x00\x00", b"\x00\x01\x00\x00\xff\xff\xff\x7fabc"],
)
def test_malformed_payloads_raise_message_error(payload: bytes) -> None:
    with pytest.raises(MessageError, match="std_msgs/msg/String"):
        ts.deserialize(payload, "std_msgs/msg/String")


def test_unknown_type_suggests_close_names() -> None:
    with pytest.raises(MessageError, match="did you mean std_msgs/msg/String"):
        ts.get_type("std_msgs/msg/Strin")
    with pytest.raises(MessageError, match="unknown service type"):
        ts.service_types("std_srvs/srv/Nope")


def test_dds_names() -> None:
    assert ts.dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"
    assert ts.dds_type_name("std_srvs/srv/Trigger") == "std_srvs::srv::dds_::Trigger_"
    assert ts.ros_type_name("sensor_msgs::msg::dds_::Image_") == "sensor_msgs/msg/Image"
    with pytest.raises(MessageError):
        ts.ros_type_name("std_msgs/String")


def test_message_from_dict_errors_name_the_field() -> None:
    with pytest.raises(MessageError, match=r"unknown field\(s\) \['lin'\]"):
        ts.message_from_dict("geometry_msgs/msg/Twist", {"lin": {}})
    with pytest.raises(MessageError, match=r"field 'linear\.x': 'fast' is not a float64"):
        ts.message_from_dict("geometry_msgs/msg/Twist", {"linear": {"x": "fast"}})


def test_stamps() -> None:
    stamp = ts.stamp_from_ns(1_700_000_000_123_456_789)
    assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert ts.ns_from_stamp(stamp) == 1_700_000_000_123_456_789
    assert ts.header("map", 5).frame_id == "map"
