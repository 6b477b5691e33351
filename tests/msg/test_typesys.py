import hashlib
import json
import math
import random
import subprocess
import sys

import numpy as np
import pytest

from fleetslam.errors import MessageError
from fleetslam.msg import typesys as ts

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


def test_message_from_dict_takes_numeric_arrays_whole() -> None:
    """A grid's or a map's payload as one NumPy array, with the same checks as element by element."""
    grid = ts.message_from_dict("nav_msgs/msg/OccupancyGrid", {"data": np.array([0, 100, -1], np.int64)})
    assert grid.data.dtype == np.int8 and grid.data.tolist() == [0, 100, -1]
    with pytest.raises(MessageError, match=r"field 'data': values outside the range of int8"):
        ts.message_from_dict("nav_msgs/msg/OccupancyGrid", {"data": np.array([0, 200])})
    with pytest.raises(MessageError, match=r"field 'covariance': expected 36 values, got 2"):
        ts.message_from_dict("geometry_msgs/msg/PoseWithCovariance", {"covariance": np.zeros(2)})
    # Floats for an integer field go element by element and are truncated as int() does.
    assert ts.message_from_dict("nav_msgs/msg/OccupancyGrid", {"data": np.array([1.7, -1.0])}).data.tolist() == [1, -1]
    cloud = ts.message_from_dict("sensor_msgs/msg/PointCloud2", {"data": np.arange(4, dtype=np.uint8)})
    assert cloud.data.dtype == np.uint8 and cloud.data.tolist() == [0, 1, 2, 3]


def test_stamps() -> None:
    stamp = ts.stamp_from_ns(1_700_000_000_123_456_789)
    assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert ts.ns_from_stamp(stamp) == 1_700_000_000_123_456_789
    assert ts.header("map", 5).frame_id == "map"


# Hashes that rosidl ships in ROS 2's generated type description files (independent of rosbags and of the
# spec's three vectors); reproducing them checks field type ids, placeholders and the service/event synthesis.
ROSIDL_HASHES = {
    "std_msgs/msg/Empty": "RIHS01_20b625256f32d5dbc0d04fee44f43c41e51c70d3502f84b4a08e7a9c26a96312",
    "std_msgs/msg/Bool": "RIHS01_feb91e995ff9ebd09c0cb3d2aed18b11077585839fb5db80193b62d74528f6c9",
    "std_msgs/msg/Header": "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "geometry_msgs/msg/Vector3": "RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
    "geometry_msgs/msg/Twist": "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "std_srvs/srv/Trigger": "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f",
    "std_srvs/srv/Trigger_Request": "RIHS01_d010825374ce8918e72bfd826c82603e60f45419e932ea976f807b74a863a199",
    "std_srvs/srv/SetBool": "RIHS01_abe9e4bb6b41b40e6789712c00ec8871923e089af3f667a79992a428cff2da0a",
    "std_srvs/srv/SetBool_Request": "RIHS01_c62fbb99d94e1b25e8ef9e109f9581956bb1b3361a45a4e5810c36a90d29932e",
    "std_srvs/srv/SetBool_Response": "RIHS01_d0814e7f7b4880ab77e9c57426c7aa1562ab69f11eef8e2e968812f9cbd0b059",
    "std_srvs/srv/SetBool_Event": "RIHS01_3c4c20015afb4303eafd347b1d6a786f171a89c814726961a9593ef10df878cf",
}

# Our own types' hashes, pinned: a change here changes every key of the type on the wire, so it must be
# deliberate (update the value together with the .msg/.srv file).
OWN_HASHES = {
    "fleetslam_msgs/msg/GraphConstraint": "RIHS01_1262d1fec1c60c2808714736b6d73c88f55078a8757e1bab1fb1b596e9af0966",
    "fleetslam_msgs/msg/Keyframe": "RIHS01_543c3636a0e5bc7efe2c34e18b47ca3d1236627499a6cfe4ec0b0109960aa79b",
    "fleetslam_msgs/msg/KeyframeGraph": "RIHS01_99e50b76c267db818286c0aab70ba14f85d6edb4092b9f557e595209d8e7e129",
    "fleetslam_msgs/msg/KeyframeSummary": "RIHS01_801e7ce1182611a70785fdf180107625114573817ab34832c7902008a8a814a5",
    "fleetslam_msgs/msg/TopicStatistics": "RIHS01_0590184078b17dff505612860e427c5e9c7bbda0266338982a6d9dd887ac2349",
    "fleetslam_msgs/srv/SaveMap": "RIHS01_d610d53a3cfbc6580bae8d894bb394ef66eb3c76b8b4a3d538e641e3dfa27df3",
    "fleetslam_msgs/srv/ClearBbx": "RIHS01_5a9f7281918c9db4914931a3b64faca748b4b1b0271808e14db3a5bdda3dabea",
    "fleetslam_msgs/srv/GetGraph": "RIHS01_25d8c6f069b8083ccec601f1afd0bf17fc1d26f0e1c30999c30ba088e56917b4",
    "fleetslam_msgs/srv/GetKeyframeSummaries": (
        "RIHS01_928513aad536422b553cf0e2a3a107dfb779f34f562678b24f0c4a15b04fa451"
    ),
    "fleetslam_msgs/srv/GetTrajectory": "RIHS01_a087c970eb72cd01b66f5ee0b19527d90c08be0cc10f7f1ac457a5397cf77091",
    "fleetslam_msgs/msg/Finding": "RIHS01_c422378124f91dca23b64e135afa1f381348ce39e43d88ebcc2ae3be7e06e446",
    "fleetslam_msgs/msg/FindingArray": "RIHS01_ea5441b06b4b8488b4a81f5b9ea46d9b58c9835d924d3a0d4545b780adaeadd8",
    "fleetslam_msgs/srv/CreateFinding": "RIHS01_82ff938e003f4b932c292c00ba9232818ff2d9780fb32de9b2b242e51649ecb5",
    "fleetslam_msgs/srv/UpdateFinding": "RIHS01_ecf1cde74fcf8de558e0d57ef4f09af380bbbbdc6a45f356d5045a247b7297ca",
}


@pytest.mark.parametrize(("name", "expected"), ROSIDL_HASHES.items())
def test_rosidl_reference_hashes(name: str, expected: str) -> None:
    assert ts.type_hash(name) == expected


@pytest.mark.parametrize(("name", "expected"), OWN_HASHES.items())
def test_own_hashes_are_stable(name: str, expected: str) -> None:
    assert ts.type_hash(name) == expected


def _nested_names(description: dict) -> set[str]:
    return {f["type"]["nested_type_name"] for f in description["fields"]} - {""}


@pytest.mark.parametrize(
    "name",
    [
        "nav_msgs/msg/Odometry",
        "sensor_msgs/msg/CameraInfo",
        "tf2_msgs/msg/TFMessage",
        "fleetslam_msgs/msg/KeyframeGraph",
        "fleetslam_msgs/srv/ClearBbx",
        "example_interfaces/srv/AddTwoInts",
    ],
)
def test_type_descriptions_are_closed_sorted_and_hashed(name: str) -> None:
    document = ts.type_description(name)
    referenced = [d["type_name"] for d in document["referenced_type_descriptions"]]
    assert referenced == sorted(set(referenced)) and name not in referenced
    # Every nested type of every description is itself described, and nothing else is.
    needed = _nested_names(document["type_description"])
    for description in document["referenced_type_descriptions"]:
        needed |= _nested_names(description)
    assert needed == set(referenced)
    digest = hashlib.sha256(json.dumps(document, separators=(", ", ": ")).encode()).hexdigest()
    assert ts.type_hash(name) == f"RIHS01_{digest}"


def test_service_description_layout() -> None:
    document = ts.type_description("fleetslam_msgs/srv/SaveMap")
    fields = {f["name"]: f["type"] for f in document["type_description"]["fields"]}
    assert list(fields) == ["request_message", "response_message", "event_message"]
    assert fields["event_message"]["nested_type_name"] == "fleetslam_msgs/srv/SaveMap_Event"
    described = {d["type_name"]: d for d in document["referenced_type_descriptions"]}
    event = {f["name"]: f["type"] for f in described["fleetslam_msgs/srv/SaveMap_Event"]["fields"]}
    assert event["request"] == {
        "type_id": 97, "capacity": 1, "string_capacity": 0, "nested_type_name": "fleetslam_msgs/srv/SaveMap_Request",
    }  # fmt: skip
    info = {f["name"]: f["type"] for f in described["service_msgs/msg/ServiceEventInfo"]["fields"]}
    assert (info["client_gid"]["type_id"], info["client_gid"]["capacity"]) == (48 + 3, 16)  # uint8[16]


def test_typestore_is_shared_and_lists_every_type() -> None:
    assert ts.get_typestore() is ts.get_typestore()
    names = ts.all_type_names()
    for name in [*OWN, *OWN_HASHES, "std_srvs/srv/Empty", "example_interfaces/srv/AddTwoInts_Request"]:
        assert name in names
    assert ts.is_service_type("fleetslam_msgs/srv/SaveMap") and not ts.is_service_type("std_msgs/msg/String")
    assert ts.service_types("fleetslam_msgs/srv/ClearBbx") == (
        "fleetslam_msgs/srv/ClearBbx_Request",
        "fleetslam_msgs/srv/ClearBbx_Response",
    )
    assert ts.get_type("fleetslam_msgs/msg/GraphConstraint").INTER_AGENT == 2


def _full_messages() -> dict[str, object]:
    nan = float("nan")
    return {
        "fleetslam_msgs/msg/TopicStatistics": ts.message_from_dict(
            "fleetslam_msgs/msg/TopicStatistics",
            {
                "topic": "/c3po/odom",
                "type": "nav_msgs/msg/Odometry",
                "node_pub": "/c3po/base",
                "agent_pub": "c3po",
                "publisher_gid": list(range(16)),
                "window_start": {"sec": 3, "nanosec": 4},
                "delivered_msgs": 99,
                "dropped_msgs": 1,
                "error_msgs": 2,
                "traffic": 2**40,
                "period_max": {"sec": -1, "nanosec": 5},
            },
        ),
        "fleetslam_msgs/msg/GraphConstraint": ts.message_from_dict(
            "fleetslam_msgs/msg/GraphConstraint",
            {
                "from_id": 1,
                "to_id": 2,
                "from_agent": "c3po",
                "to_agent": "r2d2",
                "kind": 2,
                "relative": {"orientation": {"w": 1.0}},
                "information": [float(i) for i in range(36)],
            },
        ),
        "fleetslam_msgs/msg/Keyframe": ts.message_from_dict(
            "fleetslam_msgs/msg/Keyframe",
            {
                "header": {"frame_id": "map", "stamp": {"sec": 5}},
                "agent": "c3po",
                "id": 3,
                "camera_info": {"width": 640, "height": 480, "k": [500.0, 0, 320, 0, 500, 240, 0, 0, 1], "d": [0.1]},
                "rgb_format": "jpeg",
                "rgb": [255, 216, 255],
                "depth_format": "png16_mm",
                "depth": [1, 2],
                "keypoints": [1.0, 2.0],
                "points": [0.5, nan, 2.0],
                "descriptor_length": 32,
                "descriptors": list(range(32)),
                "word_ids": [7, 2**32 - 1],
                "word_weights": [0.25],
            },
        ),
        "fleetslam_msgs/msg/KeyframeGraph": ts.message_from_dict(
            "fleetslam_msgs/msg/KeyframeGraph",
            {
                "agent": "c3po",
                "keyframe_ids": [1, 2],
                "stamps": [{"sec": 1}, {"sec": 2}],
                "poses": [{"position": {"x": 1.0}}, {"position": {"y": 2.0}}],
                "constraints": [{"from_id": 1, "to_id": 2, "kind": 0}],
                "optimized": True,
            },
        ),
        "fleetslam_msgs/srv/SaveMap_Request": ts.message_from_dict("fleetslam_msgs/srv/SaveMap_Request", {"path": "x"}),
        "fleetslam_msgs/srv/SaveMap_Response": ts.message_from_dict(
            "fleetslam_msgs/srv/SaveMap_Response", {"success": True, "message": "ok", "path": "/tmp/m.bt"}
        ),
        "fleetslam_msgs/srv/ClearBbx_Request": ts.message_from_dict(
            "fleetslam_msgs/srv/ClearBbx_Request", {"min": {"x": -1.0}, "max": {"z": 2.0}}
        ),
        "fleetslam_msgs/srv/ClearBbx_Response": ts.message_from_dict("fleetslam_msgs/srv/ClearBbx_Response", {}),
        "std_srvs/srv/SetBool_Request": ts.message_from_dict("std_srvs/srv/SetBool_Request", {"data": True}),
        "nav_msgs/msg/Odometry": ts.message_from_dict(
            "nav_msgs/msg/Odometry",
            {
                "header": {"frame_id": "odom"},
                "child_frame_id": "base_link",
                "twist": {"twist": {"linear": {"x": 0.3}}, "covariance": [0.01] * 36},
            },
        ),
        "sensor_msgs/msg/Image": ts.message_from_dict(
            "sensor_msgs/msg/Image",
            {"height": 2, "width": 3, "encoding": "rgb8", "step": 9, "data": list(range(18))},
        ),
        "sensor_msgs/msg/PointCloud2": ts.message_from_dict(
            "sensor_msgs/msg/PointCloud2",
            {
                "height": 1,
                "width": 1,
                "fields": [{"name": "x", "offset": 0, "datatype": 7, "count": 1}],
                "point_step": 4,
                "row_step": 4,
                "data": [0, 0, 128, 63],
                "is_dense": True,
            },
        ),
        "tf2_msgs/msg/TFMessage": ts.message_from_dict(
            "tf2_msgs/msg/TFMessage", {"transforms": [{"child_frame_id": "a", "transform": {"rotation": {"w": 1}}}]}
        ),
    }


def _same(a: object, b: object) -> bool:
    """Equality of plain data where NaN equals NaN."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


@pytest.mark.parametrize("name", sorted(_full_messages()))
def test_full_messages_round_trip(name: str) -> None:
    msg = _full_messages()[name]
    data = ts.serialize(msg, name)
    assert type(data) is bytes and data[:4] == ts.CDR_HEADER
    back = ts.deserialize(memoryview(data), name)
    assert _same(ts.message_to_dict(back), ts.message_to_dict(msg))
    # The dict form is plain data that builds the same message again (YAML echo → pub).
    again = ts.message_from_dict(name, ts.message_to_dict(back))
    assert ts.serialize(again, name) == data


def test_known_cdr_bytes() -> None:
    request = ts.get_type("example_interfaces/srv/AddTwoInts_Request")(a=2, b=-3)
    data = ts.serialize(request, "example_interfaces/srv/AddTwoInts_Request")
    assert data == bytes.fromhex("00010000" + "0200000000000000" + "fdffffffffffffff")
    # A field-less request carries rosidl's one-byte placeholder, as FastCDR writes and expects.
    trigger = ts.serialize(ts.get_type("std_srvs/srv/Trigger_Request")(), "std_srvs/srv/Trigger_Request")
    assert trigger == bytes.fromhex("0001000000")


def test_random_payloads_only_ever_raise_message_error() -> None:
    rng = random.Random(7)
    names = ["sensor_msgs/msg/Image", "nav_msgs/msg/Odometry", "fleetslam_msgs/msg/Keyframe", "std_msgs/msg/String"]
    valid = {name: ts.serialize(ts.message_from_dict(name, {}), name) for name in names}
    for _ in range(300):
        name = rng.choice(names)
        body = bytearray(valid[name][4:] + bytes(rng.randrange(256) for _ in range(rng.randrange(0, 24))))
        for _ in range(rng.randrange(1, 4)):
            if body:
                body[rng.randrange(len(body))] = rng.randrange(256)
        payload = ts.CDR_HEADER + bytes(body[: rng.randrange(len(body) + 1)])
        try:
            ts.deserialize(payload, name)
        except MessageError as err:
            assert name in str(err)


def test_truncated_and_bad_header_payloads() -> None:
    image = _full_messages()["sensor_msgs/msg/Image"]
    data = ts.serialize(image, "sensor_msgs/msg/Image")
    with pytest.raises(MessageError, match="sensor_msgs/msg/Image"):
        ts.deserialize(data[:-5], "sensor_msgs/msg/Image")
    with pytest.raises(MessageError, match="CDR header"):
        ts.deserialize(b"\x01\x00\x00\x00" + data[4:], "sensor_msgs/msg/Image")
    with pytest.raises(MessageError, match="unknown message type 'nope/msg/X'"):
        ts.deserialize(data, "nope/msg/X")
    with pytest.raises(MessageError, match="std_msgs/msg/String"):
        ts.serialize(ts.get_type("std_msgs/msg/String")(data=5), "std_msgs/msg/String")


def test_message_from_dict_checks_shapes() -> None:
    with pytest.raises(MessageError, match=r"field 'information': expected 36 values, got 2"):
        ts.message_from_dict("fleetslam_msgs/msg/GraphConstraint", {"information": [1.0, 2.0]})
    with pytest.raises(MessageError, match=r"unknown field\(s\) \['w'\] at 'relative.position'"):
        ts.message_from_dict("fleetslam_msgs/msg/GraphConstraint", {"relative": {"position": {"w": 1}}})
    with pytest.raises(MessageError, match="expected a mapping"):
        ts.message_from_dict("std_msgs/msg/String", "hello")  # type: ignore[arg-type]
    assert ts.message_from_dict("std_msgs/msg/String", None).data == ""


def test_durations_and_headers() -> None:
    duration = ts.duration_from_ns(-1)
    assert (duration.sec, duration.nanosec) == (-1, 999_999_999)
    assert ts.ns_from_stamp(duration) == -1
    header = ts.header("c3po/odom", 1_500_000_000)
    assert (header.stamp.sec, header.stamp.nanosec, header.frame_id) == (1, 500_000_000, "c3po/odom")


def test_payload_must_be_bytes() -> None:
    with pytest.raises(MessageError, match="payload must be bytes, got int"):
        ts.deserialize(5, "std_msgs/msg/String")  # type: ignore[arg-type]


def test_typestore_is_built_lazily_once_across_threads() -> None:
    script = """
import sys
import threading
from fleetslam.msg import typesys
assert typesys._store is None, "built at import time"
assert "zenoh" not in sys.modules, "the type layer imports Zenoh"
stores = []
threads = [threading.Thread(target=lambda: stores.append(typesys.get_typestore())) for _ in range(8)]
for thread in threads:
    thread.start()
for thread in threads:
    thread.join()
assert len(stores) == 8 and all(store is stores[0] for store in stores)
assert typesys.is_service_type("std_srvs/srv/Trigger")
"""
    subprocess.run([sys.executable, "-c", script], check=True, timeout=120)


def test_octomap_msgs_types_for_octomap_server_tools() -> None:
    msg = ts.message_from_dict(
        "octomap_msgs/msg/Octomap", {"binary": True, "id": "OcTree", "resolution": 0.05, "data": [1, -2, 3]}
    )
    back = ts.deserialize(ts.serialize(msg, "octomap_msgs/msg/Octomap"), "octomap_msgs/msg/Octomap")
    assert back.id == "OcTree" and back.binary and list(back.data) == [1, -2, 3]
    assert ts.service_types("octomap_msgs/srv/GetOctomap") == (
        "octomap_msgs/srv/GetOctomap_Request",
        "octomap_msgs/srv/GetOctomap_Response",
    )


def test_deserialized_arrays_are_read_only_views_on_the_payload() -> None:
    image_type = ts.get_type("sensor_msgs/msg/Image")
    pixels = np.arange(480 * 640 * 3, dtype=np.uint32).astype(np.uint8)
    payload = ts.serialize(
        image_type(
            header=ts.header("cam", 5), height=480, width=640, encoding="rgb8", is_bigendian=0, step=1920, data=pixels
        ),
        "sensor_msgs/msg/Image",
    )
    msg = ts.deserialize(payload, "sensor_msgs/msg/Image")
    # No copy: the array's memory is inside the payload, at the data's offset after the CDR header.
    start = np.frombuffer(payload, np.uint8).ctypes.data
    assert start < msg.data.ctypes.data < start + len(payload)
    assert np.shares_memory(msg.data, np.frombuffer(payload, np.uint8))
    np.testing.assert_array_equal(msg.data, pixels)
    # Read-only, so nobody changes what another callback of the same sample sees; a copy is one's own.
    assert not msg.data.flags.writeable
    with pytest.raises(ValueError):
        msg.data[0] = 1
    mine = msg.data.copy()
    mine[0] = 1
    assert mine.flags.writeable and msg.data[0] == pixels[0]
    # The view keeps the payload alive after every other reference is gone.
    view = msg.data
    del msg, payload
    np.testing.assert_array_equal(view, pixels)


def test_deserialize_copies_mutable_buffers_first() -> None:
    array = ts.message_from_dict("std_msgs/msg/UInt8MultiArray", {"data": list(range(8))})
    payload = bytearray(ts.serialize(array, "std_msgs/msg/UInt8MultiArray"))
    msg = ts.deserialize(payload, "std_msgs/msg/UInt8MultiArray")
    payload[-1] = 99  # the caller changes its buffer: the message does not change with it
    assert msg.data.tolist() == list(range(8))
    view = ts.deserialize(memoryview(bytes(payload)), "std_msgs/msg/UInt8MultiArray")
    assert view.data[-1] == 99


def test_serialize_buffer_is_serialize_without_the_copy() -> None:
    msg = ts.get_type("std_msgs/msg/String")(data="hi")
    buffer = ts.serialize_buffer(msg, "std_msgs/msg/String")
    assert isinstance(buffer, bytearray) and bytes(buffer) == ts.serialize(msg, "std_msgs/msg/String")
    assert ts.serialize_buffer(msg, "std_msgs/msg/String") is not buffer  # a new buffer each time, the caller's own


def test_serialize_payload_is_serialize_in_the_object_it_was_written_into() -> None:
    string = ts.get_type("std_msgs/msg/String")(data="hi")
    assert type(ts.serialize_payload(string, "std_msgs/msg/String")) is bytes  # built in one piece
    array = ts.message_from_dict("std_msgs/msg/UInt8MultiArray", {"data": list(range(8))})
    payload = ts.serialize_payload(array, "std_msgs/msg/UInt8MultiArray")
    assert type(payload) is bytearray and bytes(payload) == ts.serialize(array, "std_msgs/msg/UInt8MultiArray")
    assert ts.serialize_payload(array, "std_msgs/msg/UInt8MultiArray") is not payload


def test_keyframe_arrays_are_views_too() -> None:
    msg = ts.message_from_dict(
        "fleetslam_msgs/msg/Keyframe",
        {"agent": "c3po", "rgb": list(range(100)), "keypoints": [0.5] * 64, "word_ids": [1, 2, 3]},
    )
    payload = ts.serialize(msg, "fleetslam_msgs/msg/Keyframe")
    back = ts.deserialize(payload, "fleetslam_msgs/msg/Keyframe")
    whole = np.frombuffer(payload, np.uint8)
    for array in (back.rgb, back.keypoints, back.word_ids, back.camera_info.k):
        assert np.shares_memory(array, whole) and not array.flags.writeable
    np.testing.assert_allclose(back.keypoints, 0.5)
    assert back.word_ids.tolist() == [1, 2, 3]


def test_trailing_bytes_beyond_padding_are_malformed() -> None:
    payload = ts.serialize(ts.get_type("std_msgs/msg/String")(data="hi"), "std_msgs/msg/String")
    assert ts.deserialize(payload + b"\x00" * 3, "std_msgs/msg/String").data == "hi"  # CDR's end padding
    with pytest.raises(MessageError, match="malformed CDR payload"):
        ts.deserialize(payload + b"\x00" * 8, "std_msgs/msg/String")
    with pytest.raises(MessageError, match="unknown message type"):
        ts.deserialize(payload, "std_msgs/msg/Strng")


def test_the_middleware_re_exports_the_message_layer() -> None:
    from fleetslam.middleware import typesys as old

    assert old.get_typestore is ts.get_typestore and old.deserialize is ts.deserialize
    assert set(old.__all__) == set(ts.__all__)
    assert all(getattr(old, name) is getattr(ts, name) for name in ts.__all__)
