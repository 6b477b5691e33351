"""Messages ⇄ arrays, each through CDR and back: images, camera info, odometry, point clouds, poses and TF."""

from __future__ import annotations

import math
import subprocess
import sys
from functools import partial

import numpy as np
import pytest

from fleetslam.errors import MessageError
from fleetslam.geometry import pose_from_planar, random_pose
from fleetslam.intrinsics import Intrinsics
from fleetslam.msg import conversions as cv
from fleetslam.msg.typesys import deserialize, get_type, header, ns_from_stamp, serialize

RNG = np.random.default_rng(7)


def _wire(msg: object, type_name: str) -> object:
    """The message as a subscriber receives it (zero-copy views on the CDR payload)."""
    return deserialize(serialize(msg, type_name), type_name)


# -- images ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("encoding", "shape", "dtype"),
    [
        ("rgb8", (5, 7, 3), np.uint8),
        ("bgr8", (5, 7, 3), np.uint8),
        ("rgba8", (5, 7, 4), np.uint8),
        ("mono8", (5, 7), np.uint8),
        ("mono16", (5, 7), np.uint16),
        ("16UC1", (5, 7), np.uint16),
        ("32FC1", (5, 7), np.float32),
    ],
)
def test_image_round_trip(encoding: str, shape: tuple[int, ...], dtype: type) -> None:
    pixels = (RNG.random(shape) * 60000).astype(dtype)
    msg = _wire(cv.image_msg(pixels, encoding, frame_id="cam", stamp_ns=12), "sensor_msgs/msg/Image")
    assert msg.step == shape[1] * (shape[2] if len(shape) == 3 else 1) * np.dtype(dtype).itemsize  # type: ignore[attr-defined]
    back = cv.image_to_array(msg)
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, pixels)


def test_image_rows_padded_to_their_step_and_big_endian() -> None:
    image = partial(get_type("sensor_msgs/msg/Image"), header=header("camera", 0))
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    padded = np.zeros((2, 12), np.uint8)  # rows padded to 12 bytes, as some drivers align them
    padded[:, :9] = rgb.reshape(2, 9)
    msg = _wire(image(height=2, width=3, encoding="rgb8", is_bigendian=0, step=12, data=padded.reshape(-1)),
                "sensor_msgs/msg/Image")  # fmt: skip
    np.testing.assert_array_equal(cv.image_to_array(msg), rgb)
    np.testing.assert_array_equal(cv.rgb_from_image(msg), rgb)
    bgr = image(height=2, width=3, encoding="bgr8", is_bigendian=0, step=12, data=padded.reshape(-1))
    np.testing.assert_array_equal(cv.rgb_from_image(bgr), rgb[:, :, ::-1])
    depth_mm = np.array([[1000, 2500, 7], [0, 65535, 9]], dtype=">u2")  # big-endian 16UC1, millimetres
    rows = np.zeros((2, 8), np.uint8)
    rows[:, :6] = np.frombuffer(depth_mm.tobytes(), np.uint8).reshape(2, 6)
    msg = _wire(image(height=2, width=3, encoding="16UC1", is_bigendian=1, step=8, data=rows.reshape(-1)),
                "sensor_msgs/msg/Image")  # fmt: skip
    np.testing.assert_array_equal(cv.image_to_array(msg), depth_mm.astype(np.uint16))
    np.testing.assert_allclose(cv.depth_from_image(msg), [[1.0, 2.5, 0.007], [0.0, 65.535, 0.009]], rtol=1e-6)
    metres = np.array([[1.5, np.nan], [np.inf, 2.0]], dtype=">f4")
    msg = image(height=2, width=2, encoding="32FC1", is_bigendian=1, step=8,
                data=np.frombuffer(metres.tobytes(), np.uint8).copy())  # fmt: skip
    np.testing.assert_array_equal(cv.depth_from_image(msg), [[1.5, 0.0], [0.0, 2.0]])


def test_received_image_is_a_view_on_the_payload() -> None:
    pixels = RNG.integers(0, 255, (4, 6, 3), dtype=np.uint8)
    msg = _wire(cv.image_msg(pixels, "rgb8", frame_id="cam", stamp_ns=0), "sensor_msgs/msg/Image")
    view = cv.image_to_array(msg)
    assert np.shares_memory(view, msg.data) and not view.flags.writeable  # type: ignore[attr-defined]


def test_malformed_images_are_refused() -> None:
    image = partial(get_type("sensor_msgs/msg/Image"), header=header("camera", 0))
    short = image(height=4, width=3, encoding="rgb8", is_bigendian=0, step=9, data=np.zeros(20, np.uint8))
    with pytest.raises(MessageError, match="does not fit"):
        cv.image_to_array(short)
    with pytest.raises(MessageError, match="unsupported image encoding 'yuv422'"):
        cv.image_to_array(image(height=1, width=1, encoding="yuv422", is_bigendian=0, step=2, data=np.zeros(2)))
    depth = cv.image_msg(np.zeros((2, 2), np.float32), "32FC1", frame_id="", stamp_ns=0)
    with pytest.raises(MessageError, match="not a colour encoding"):
        cv.rgb_from_image(depth)
    with pytest.raises(MessageError, match="not a depth encoding"):
        cv.depth_from_image(cv.image_msg(np.zeros((2, 2, 3), np.uint8), "rgb8", frame_id="", stamp_ns=0))
    with pytest.raises(MessageError, match=r"needs shape \(H, W, 3\)"):
        cv.image_msg(np.zeros((2, 2), np.uint8), "rgb8", frame_id="", stamp_ns=0)


# -- camera info -----------------------------------------------------------------------------------------------
def test_camera_info_round_trip() -> None:
    intrinsics = Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480)
    msg = _wire(cv.camera_info_msg(intrinsics, frame_id="cam", stamp_ns=5), "sensor_msgs/msg/CameraInfo")
    assert cv.intrinsics_from_camera_info(msg) == intrinsics
    assert msg.header.frame_id == "cam" and msg.distortion_model == "plumb_bob"  # type: ignore[attr-defined]
    np.testing.assert_array_equal(np.asarray(msg.p).reshape(3, 4)[:, :3], intrinsics.K)  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("k_values", "size", "named"),
    [
        ([0.0] * 9, (640, 480), "focal lengths must be positive"),  # ROS's "uncalibrated"
        ([-500.0, 0, 320, 0, 500, 240, 0, 0, 1], (640, 480), "fx=-500.0"),
        ([500.0, 0, float("nan"), 0, 500, 240, 0, 0, 1], (640, 480), "not all finite"),
        ([500.0, 0, 320, 0, 500, 240, 0, 0, 1], (0, 480), "size 0x480"),
    ],
)
def test_camera_info_that_is_not_a_camera_is_refused_naming_the_values(
    k_values: list[float], size: tuple[int, int], named: str
) -> None:
    msg = cv.camera_info_msg(Intrinsics(500.0, 500.0, 320.0, 240.0), frame_id="cam", stamp_ns=5)
    msg.k = np.array(k_values, dtype=np.float64)
    msg.width, msg.height = size
    with pytest.raises(MessageError, match=named):
        cv.intrinsics_from_camera_info(_wire(msg, "sensor_msgs/msg/CameraInfo"))


# -- poses, TF and odometry ------------------------------------------------------------------------------------
def test_pose_and_transform_round_trip() -> None:
    poses = [random_pose(RNG, 5.0) for _ in range(20)]
    for pose in poses:
        np.testing.assert_allclose(cv.pose_matrix(_wire(cv.pose_msg(pose), "geometry_msgs/msg/Pose")), pose, atol=1e-12)
        tf = _wire(cv.transform_msg(pose, "map", "odom", 42), "tf2_msgs/msg/TFMessage")
        (stamped,) = tf.transforms  # type: ignore[attr-defined]
        assert (stamped.header.frame_id, stamped.child_frame_id, ns_from_stamp(stamped.header.stamp)) == (
            "map", "odom", 42,
        )  # fmt: skip
        np.testing.assert_allclose(cv.transform_matrix(stamped.transform), pose, atol=1e-12)
    for pose, msg in zip(poses, cv.pose_msgs(poses), strict=True):
        np.testing.assert_allclose(cv.pose_matrix(msg), pose, atol=1e-12)
    assert cv.pose_msgs([]) == []


@pytest.mark.parametrize("frame_id", ["", "m", "map", "fleet", "fleet_1", "fleet_12", "r2d2/map", "flotte_ü"])
@pytest.mark.parametrize("count", [0, 1, 2, 7])
def test_path_cdr_is_the_bytes_of_the_path_message(frame_id: str, count: int) -> None:
    # Every length of frame name puts the first pose's doubles at another alignment.
    rng = np.random.default_rng(count)
    poses = np.stack([random_pose(rng) for _ in range(count)]) if count else np.zeros((0, 4, 4))
    stamps = rng.integers(0, 2_000_000_000 * 10**9, count)
    stamped = get_type("geometry_msgs/msg/PoseStamped")
    each = [stamped(header=header(frame_id, int(t)), pose=p)
            for t, p in zip(stamps, cv.pose_msgs(list(poses)), strict=True)]  # fmt: skip
    message = get_type("nav_msgs/msg/Path")(header=header(frame_id, 1_700_000_000_123_456_789), poses=each)
    data = cv.path_cdr(frame_id, 1_700_000_000_123_456_789, poses, stamps)
    assert bytes(data) == serialize(message, "nav_msgs/msg/Path")
    back = deserialize(bytes(data), "nav_msgs/msg/Path")
    assert [ns_from_stamp(p.header.stamp) for p in back.poses] == stamps.tolist()
    for pose, msg in zip(poses, back.poses, strict=True):
        np.testing.assert_allclose(cv.pose_matrix(msg.pose), pose, atol=1e-12)
    with pytest.raises(ValueError, match="stamps"):
        cv.path_cdr(frame_id, 0, poses, np.zeros(count + 1, dtype=np.int64))
    if count:
        with pytest.raises(ValueError, match="stamp"):  # builtin_interfaces/Time holds int32 seconds
            cv.path_cdr(frame_id, 0, poses, np.full(count, 2**62))


def test_planar_pose_is_the_pose_of_its_yaw() -> None:
    for yaw in (-3.0, -0.5, 0.0, 1.2, math.pi):
        msg = cv.planar_pose_msg(1.5, -2.0, yaw)
        np.testing.assert_allclose(cv.pose_matrix(msg), pose_from_planar(1.5, -2.0, yaw), atol=1e-12)
        assert (msg.orientation.z, msg.orientation.w) == (math.sin(yaw / 2), math.cos(yaw / 2))


def test_odometry_round_trip() -> None:
    pose = random_pose(RNG)
    covariance = np.diag(np.arange(1.0, 7.0))
    msg = _wire(
        cv.odometry_msg(cv.pose_msg(pose), frame_id="odom", child_frame_id="base_link", stamp_ns=1_500_000_000,
                        linear=(0.3, 0.0, 0.0), angular=(0.0, 0.0, -0.2), pose_covariance=covariance),
        "nav_msgs/msg/Odometry",
    )  # fmt: skip
    assert (msg.header.frame_id, msg.child_frame_id, ns_from_stamp(msg.header.stamp)) == (  # type: ignore[attr-defined]
        "odom", "base_link", 1_500_000_000,
    )  # fmt: skip
    np.testing.assert_allclose(cv.pose_matrix(msg.pose.pose), pose, atol=1e-12)  # type: ignore[attr-defined]
    np.testing.assert_array_equal(np.asarray(msg.pose.covariance).reshape(6, 6), covariance)  # type: ignore[attr-defined]
    np.testing.assert_array_equal(msg.twist.covariance, np.zeros(36))  # type: ignore[attr-defined]
    twist = msg.twist.twist  # type: ignore[attr-defined]
    assert (twist.linear.x, twist.angular.z) == (0.3, -0.2)


# -- point clouds ----------------------------------------------------------------------------------------------
def test_pointcloud2_xyz_round_trip() -> None:
    points = RNG.normal(size=(17, 3))
    msg = _wire(cv.pointcloud2_msg(points, frame_id="map", stamp_ns=3), "sensor_msgs/msg/PointCloud2")
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [  # type: ignore[attr-defined]
        ("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1),
    ]  # fmt: skip
    assert (msg.point_step, msg.row_step, msg.width, msg.height) == (12, 12 * 17, 17, 1)  # type: ignore[attr-defined]
    np.testing.assert_array_equal(cv.pointcloud2_xyz(msg), points.astype(np.float32))
    empty = _wire(cv.pointcloud2_msg(np.zeros((0, 3)), frame_id="map", stamp_ns=0), "sensor_msgs/msg/PointCloud2")
    assert cv.pointcloud2_xyz(empty).shape == (0, 3)


def test_pointcloud2_rgb_round_trip() -> None:
    points = RNG.normal(size=(9, 3))
    colours = RNG.integers(0, 256, (9, 3), dtype=np.uint8)
    msg = _wire(cv.pointcloud2_msg(points, frame_id="map", stamp_ns=0, colors=colours), "sensor_msgs/msg/PointCloud2")
    assert [f.name for f in msg.fields] == ["x", "y", "z", "rgb"] and msg.point_step == 16  # type: ignore[attr-defined]
    np.testing.assert_array_equal(cv.pointcloud2_xyz(msg), points.astype(np.float32))
    np.testing.assert_array_equal(cv.pointcloud2_rgb(msg), colours)


def test_pointcloud2_of_another_layout() -> None:
    """A driver's cloud: 2 rows padded to row_step, float64 z before float32 x and y, big-endian, extra field."""
    points = RNG.normal(size=(2, 3, 3))
    point = np.dtype([("z", ">f8"), ("intensity", ">f4"), ("x", ">f4"), ("y", ">f4"), ("pad", "V4")])
    rows = np.zeros((2, 3 * point.itemsize + 8), np.uint8)
    for r in range(2):
        cells = np.zeros(3, point)
        cells["x"], cells["y"], cells["z"] = points[r, :, 0], points[r, :, 1], points[r, :, 2]
        rows[r, : 3 * point.itemsize] = np.frombuffer(cells.tobytes(), np.uint8)
    field = get_type("sensor_msgs/msg/PointField")
    msg = get_type("sensor_msgs/msg/PointCloud2")(
        header=header("lidar", 0), height=2, width=3,
        fields=[field(name="z", offset=0, datatype=8, count=1), field(name="intensity", offset=8, datatype=7, count=1),
                field(name="x", offset=12, datatype=7, count=1), field(name="y", offset=16, datatype=7, count=1)],
        is_bigendian=True, point_step=point.itemsize, row_step=rows.shape[1], data=rows.reshape(-1), is_dense=True,
    )  # fmt: skip
    np.testing.assert_array_equal(cv.pointcloud2_xyz(_wire(msg, "sensor_msgs/msg/PointCloud2")),
                                  points.reshape(-1, 3).astype(np.float32))  # fmt: skip
    msg.fields = msg.fields[1:]  # type: ignore[attr-defined]
    with pytest.raises(MessageError, match="no 'z' field"):
        cv.pointcloud2_xyz(msg)
    msg.data = msg.data[:40]  # type: ignore[attr-defined]
    with pytest.raises(MessageError, match="does not fit"):
        cv.pointcloud2_xyz(msg)


def test_the_message_layer_imports_without_zenoh() -> None:
    script = (
        "import sys\n"
        "import fleetslam.msg.conversions, fleetslam.datasets.mcap_source\n"
        "assert 'zenoh' not in sys.modules and 'fleetslam.middleware' not in sys.modules, sorted(sys.modules)\n"
    )
    subprocess.run([sys.executable, "-c", script], check=True, timeout=120)
