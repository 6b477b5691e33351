"""Conversions between ROS messages and arrays: the one place where fleetslam builds or reads them.

- poses: ``geometry_msgs/Pose`` ⇄ 4×4 (:func:`pose_msg`, :func:`pose_msgs`, :func:`planar_pose_msg`,
  :func:`pose_matrix`); ``geometry_msgs/Transform`` → 4×4 (:func:`transform_matrix`); a ``nav_msgs/Path`` of
  stamped 4×4 poses straight to its CDR bytes (:func:`path_cdr`);
- TF: ``tf2_msgs/TFMessage`` of one transform (:func:`transform_msg`, :func:`tf_msg`);
- odometry: ``nav_msgs/Odometry`` (:func:`odometry_msg`; its pose back with :func:`pose_matrix`);
- images: ``sensor_msgs/Image`` ⇄ arrays honouring ``step`` and ``is_bigendian`` (:func:`image_msg`,
  :func:`image_to_array`, :func:`rgb_from_image`, :func:`depth_from_image`) for the :data:`ENCODINGS`;
- camera info: ``sensor_msgs/CameraInfo`` ⇄ :class:`~fleetslam.intrinsics.Intrinsics`;
- point clouds: ``sensor_msgs/PointCloud2`` ⇄ ``(N, 3)`` xyz and optional RGB (:func:`pointcloud2_msg`,
  :func:`pointcloud2_xyz`, :func:`pointcloud2_rgb`).

Arrays read from a received message are, where the layout allows, read-only views on its payload (see
:func:`fleetslam.msg.typesys.deserialize`); ``.copy()`` gives one's own. Malformed input raises
:class:`~fleetslam.errors.MessageError` naming the field at fault.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.errors import MessageError
from fleetslam.geometry import pose_from_quat, pose_to_quat
from fleetslam.intrinsics import Intrinsics, pinhole_problem
from fleetslam.msg.typesys import get_type, header

__all__ = [
    "ENCODINGS",
    "POINTFIELD_FLOAT32",
    "camera_info_msg",
    "depth_from_image",
    "image_msg",
    "image_to_array",
    "intrinsics_from_camera_info",
    "odometry_msg",
    "path_cdr",
    "planar_pose_msg",
    "pointcloud2_msg",
    "pointcloud2_rgb",
    "pointcloud2_xyz",
    "pose_matrix",
    "pose_msg",
    "pose_msgs",
    "rgb_from_image",
    "tf_msg",
    "transform_matrix",
    "transform_msg",
]


# -- poses and TF --------------------------------------------------------------------------------------------
def pose_matrix(pose: Any) -> NDArray[np.float64]:
    """4×4 matrix of a geometry_msgs/Pose (of an Odometry: ``pose_matrix(msg.pose.pose)``)."""
    p, q = pose.position, pose.orientation
    return pose_from_quat([p.x, p.y, p.z], [q.x, q.y, q.z, q.w])


def transform_matrix(transform: Any) -> NDArray[np.float64]:
    """4×4 matrix of a geometry_msgs/Transform."""
    t, q = transform.translation, transform.rotation
    return pose_from_quat([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


def _pose(t: Sequence[float], q: Sequence[float]) -> Any:
    point, quat = get_type("geometry_msgs/msg/Point"), get_type("geometry_msgs/msg/Quaternion")
    return get_type("geometry_msgs/msg/Pose")(
        position=point(x=float(t[0]), y=float(t[1]), z=float(t[2])),
        orientation=quat(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
    )


def pose_msg(pose: ArrayLike) -> Any:
    """geometry_msgs/Pose of a 4×4 pose (quaternion with ``w >= 0``)."""
    t, q = pose_to_quat(pose)
    return _pose(t.tolist(), q.tolist())


def pose_msgs(poses: Sequence[ArrayLike]) -> list[Any]:
    """geometry_msgs/Pose of many 4×4 poses, the rotations converted in one batch (as :func:`pose_msg` each, but
    without forcing ``w >= 0``: a quaternion and its negation are the same rotation)."""
    if not poses:
        return []
    from scipy.spatial.transform import Rotation

    stacked = np.stack([np.asarray(p, dtype=np.float64) for p in poses])
    quats = Rotation.from_matrix(stacked[:, :3, :3]).as_quat()  # x, y, z, w
    return [_pose(t.tolist(), q.tolist()) for t, q in zip(stacked[:, :3, 3], quats, strict=True)]


def path_cdr(frame_id: str, stamp_ns: int, poses: NDArray[np.float64], stamps_ns: NDArray[np.int64]) -> bytearray:
    """The CDR bytes (as :func:`~fleetslam.msg.typesys.serialize` writes them) of a ``nav_msgs/Path`` in
    ``frame_id`` stamped ``stamp_ns``, of ``poses`` ((N, 4, 4); quaternions as :func:`pose_msgs`) each stamped with
    its ``stamps_ns`` in the same frame. Written from arrays: building the N ``PoseStamped`` objects for rosbags took
    14 µs per pose, and the fleet back-end sends every agent's path again as it corrects it."""
    from scipy.spatial.transform import Rotation

    stack = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    if len(stamps) != len(stack):
        raise ValueError(f"path_cdr: {len(stack)} poses but {len(stamps)} stamps")
    name = frame_id.encode() + b"\0"
    head = bytearray(b"\x00\x01\x00\x00")  # CDR, little-endian
    head += struct.pack("<iII", stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000, len(name)) + name
    head += bytes(-(len(head) - 4) % 4)
    head += struct.pack("<I", len(stack))
    if not len(stack):
        return head
    values = np.empty((len(stack), 7))
    values[:, :3] = stack[:, :3, 3]
    values[:, 3:] = Rotation.from_matrix(stack[:, :3, :3]).as_quat()
    seconds, nanoseconds = np.divmod(stamps, 1_000_000_000)
    if seconds.min() < -(2**31) or seconds.max() >= 2**31:
        raise ValueError(
            f"path_cdr: a stamp beyond builtin_interfaces/Time's int32 seconds: {stamps.min()}..{stamps.max()} ns"
        )
    # An element's stamp, frame and pose (8-aligned doubles): every element after the first starts 8-aligned, the
    # first may start 4 bytes past, and then its pose lies 4 bytes later relative to its start.
    first_shift = (len(head) - 4) % 8
    pose_at = -(-(12 + len(name)) // 8) * 8
    element = np.dtype({"names": ["sec", "nanosec", "length", "frame", "pose"],
                        "formats": ["<i4", "<u4", "<u4", f"S{len(name)}", ("<f8", 7)],
                        "offsets": [0, 4, 8, 12, pose_at], "itemsize": pose_at + 56})  # fmt: skip
    first_size = -(-(first_shift + 12 + len(name)) // 8) * 8 - first_shift + 56
    first = struct.pack("<iII", seconds[0], nanoseconds[0], len(name)) + name
    first += bytes(first_size - 56 - len(first)) + values[0].astype("<f8").tobytes()
    out = head + first + bytes((len(stack) - 1) * element.itemsize)
    rest = np.frombuffer(out, dtype=element, offset=len(head) + first_size)  # a view: written in place
    rest["sec"], rest["nanosec"], rest["length"] = seconds[1:], nanoseconds[1:], len(name)
    rest["frame"] = name
    rest["pose"] = values[1:]
    return out


def planar_pose_msg(x: float, y: float, yaw: float) -> Any:
    """geometry_msgs/Pose of a planar robot at ``(x, y, 0)`` heading ``yaw`` (quaternion ``(0, 0, sin, cos)`` of
    half the yaw, as a wheel odometry writes it)."""
    return _pose((x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))


def tf_msg(pose: Any, parent: str, child: str, stamp_ns: int) -> Any:
    """tf2_msgs/msg/TFMessage with one transform ``T_parent_child`` given as a geometry_msgs/Pose."""
    vec3 = get_type("geometry_msgs/msg/Vector3")
    p = pose.position
    transform = get_type("geometry_msgs/msg/TransformStamped")(
        header=header(parent, stamp_ns),
        child_frame_id=child,
        transform=get_type("geometry_msgs/msg/Transform")(
            translation=vec3(x=p.x, y=p.y, z=p.z), rotation=pose.orientation
        ),
    )
    return get_type("tf2_msgs/msg/TFMessage")(transforms=[transform])


def transform_msg(pose: ArrayLike, parent: str, child: str, stamp_ns: int) -> Any:
    """tf2_msgs/msg/TFMessage with one transform ``T_parent_child`` given as a 4×4 pose."""
    return tf_msg(pose_msg(pose), parent, child, stamp_ns)


# -- odometry ------------------------------------------------------------------------------------------------
def _covariance(values: ArrayLike | None) -> NDArray[np.float64]:
    if values is None:
        return np.zeros(36)
    return np.ascontiguousarray(values, dtype=np.float64).reshape(36)


def odometry_msg(
    pose: Any,
    *,
    frame_id: str,
    child_frame_id: str,
    stamp_ns: int,
    linear: ArrayLike = (0.0, 0.0, 0.0),
    angular: ArrayLike = (0.0, 0.0, 0.0),
    pose_covariance: ArrayLike | None = None,
    twist_covariance: ArrayLike | None = None,
) -> Any:
    """nav_msgs/msg/Odometry of ``child_frame_id`` in ``frame_id``.

    Args:
        pose: the pose, a geometry_msgs/Pose (:func:`pose_msg` of a 4×4, :func:`planar_pose_msg`).
        linear, angular: the body twist (m/s, rad/s).
        pose_covariance, twist_covariance: 6×6 (or 36 values, row-major); zero when None.
    """
    vec3 = get_type("geometry_msgs/msg/Vector3")
    linear, angular = np.asarray(linear, dtype=np.float64), np.asarray(angular, dtype=np.float64)
    return get_type("nav_msgs/msg/Odometry")(
        header=header(frame_id, stamp_ns),
        child_frame_id=child_frame_id,
        pose=get_type("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=_covariance(pose_covariance)),
        twist=get_type("geometry_msgs/msg/TwistWithCovariance")(
            twist=get_type("geometry_msgs/msg/Twist")(
                linear=vec3(x=float(linear[0]), y=float(linear[1]), z=float(linear[2])),
                angular=vec3(x=float(angular[0]), y=float(angular[1]), z=float(angular[2])),
            ),
            covariance=_covariance(twist_covariance),
        ),
    )


# -- images --------------------------------------------------------------------------------------------------
#: Image encodings understood here: channels and element type (before byte order).
ENCODINGS: Mapping[str, tuple[int, str]] = {
    "rgb8": (3, "u1"),
    "bgr8": (3, "u1"),
    "rgba8": (4, "u1"),
    "bgra8": (4, "u1"),
    "mono8": (1, "u1"),
    "mono16": (1, "u2"),
    "8UC1": (1, "u1"),
    "8UC3": (3, "u1"),
    "16UC1": (1, "u2"),
    "32FC1": (1, "f4"),
}
_COLOUR = ("rgb8", "bgr8", "rgba8", "bgra8")
_DEPTH_MM = ("16UC1", "mono16")


def _bytes_of(data: Any) -> NDArray[np.uint8]:
    """A message's ``uint8[]`` as an array without copying when it already is one (a received message's is)."""
    if isinstance(data, np.ndarray) and data.dtype == np.uint8 and data.ndim == 1:
        return data
    return np.frombuffer(bytes(data), dtype=np.uint8)


def image_to_array(msg: Any) -> NDArray[Any]:
    """Pixels of a sensor_msgs/Image: ``(H, W)`` for one channel, else ``(H, W, C)``, in the encoding's channel
    order and element type (native byte order), honouring the row ``step`` (rows may be padded) and
    ``is_bigendian``. A view on the message's data when no conversion is needed."""
    h, w, encoding = int(msg.height), int(msg.width), str(msg.encoding)
    if encoding not in ENCODINGS:
        raise MessageError(f"unsupported image encoding {encoding!r} (supported: {', '.join(ENCODINGS)})")
    channels, kind = ENCODINGS[encoding]
    dtype = np.dtype(kind)
    row = w * channels * dtype.itemsize
    step = int(msg.step) or row
    raw = _bytes_of(msg.data)
    if h <= 0 or w <= 0 or step < row or len(raw) < step * (h - 1) + row:
        raise MessageError(f"{encoding} image {w}x{h} with step {step} does not fit its {len(raw)} data bytes")
    if step == row:
        packed = raw[: h * row]
    else:
        rows = np.lib.stride_tricks.as_strided(raw, (h, row), (step, 1), writeable=False)
        packed = np.ascontiguousarray(rows).reshape(-1)
    pixels: NDArray[Any] = packed
    if dtype.itemsize > 1:
        wire = dtype.newbyteorder(">" if msg.is_bigendian else "<")
        pixels = packed.view(wire)
        if wire != dtype:
            pixels = pixels.astype(dtype)
    return pixels.reshape((h, w) if channels == 1 else (h, w, channels))


def rgb_from_image(msg: Any) -> NDArray[np.uint8]:
    """RGB ``(H, W, 3)`` uint8 of an rgb8/bgr8/rgba8/bgra8 image (alpha dropped)."""
    if msg.encoding not in _COLOUR:
        raise MessageError(f"image encoding {msg.encoding!r} is not a colour encoding ({', '.join(_COLOUR)})")
    pixels = image_to_array(msg)[:, :, :3]
    return np.ascontiguousarray(pixels[:, :, ::-1] if msg.encoding.startswith("bgr") else pixels)


def depth_from_image(msg: Any) -> NDArray[np.float32]:
    """Depth ``(H, W)`` float32 metres of a 32FC1 (m) or 16UC1/mono16 (mm) image; 0 where invalid (not finite)."""
    if msg.encoding == "32FC1":
        depth = image_to_array(msg).astype(np.float32)
        depth[~np.isfinite(depth)] = 0.0
        return depth
    if msg.encoding in _DEPTH_MM:
        return image_to_array(msg).astype(np.float32) / 1000.0
    raise MessageError(f"image encoding {msg.encoding!r} is not a depth encoding (32FC1, 16UC1, mono16)")


def image_msg(array: ArrayLike, encoding: str, *, frame_id: str, stamp_ns: int) -> Any:
    """sensor_msgs/msg/Image of an array laid out as :func:`image_to_array` returns it (little-endian, unpadded)."""
    if encoding not in ENCODINGS:
        raise MessageError(f"unsupported image encoding {encoding!r} (supported: {', '.join(ENCODINGS)})")
    channels, kind = ENCODINGS[encoding]
    pixels = np.asarray(array)
    expected = 2 if channels == 1 else 3
    if pixels.ndim != expected or (channels > 1 and pixels.shape[2] != channels):
        raise MessageError(f"{encoding} image needs shape (H, W{'' if channels == 1 else f', {channels}'}), "
                           f"got {pixels.shape}")  # fmt: skip
    h, w = pixels.shape[:2]
    data = np.ascontiguousarray(pixels, dtype=np.dtype(kind).newbyteorder("<")).view(np.uint8).reshape(-1)
    return get_type("sensor_msgs/msg/Image")(
        header=header(frame_id, stamp_ns), height=h, width=w, encoding=encoding, is_bigendian=0,
        step=w * channels * np.dtype(kind).itemsize, data=data,
    )  # fmt: skip


# -- camera info ---------------------------------------------------------------------------------------------
def camera_info_msg(intrinsics: Intrinsics, *, frame_id: str, stamp_ns: int) -> Any:
    """sensor_msgs/msg/CameraInfo of an ideal pinhole camera (plumb_bob, zero distortion)."""
    k = intrinsics
    roi = get_type("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return get_type("sensor_msgs/msg/CameraInfo")(
        header=header(frame_id, stamp_ns),
        height=k.height,
        width=k.width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=k.K.reshape(9).astype(np.float64),
        r=np.eye(3).reshape(9),
        p=np.array([k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0]),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def intrinsics_from_camera_info(msg: Any) -> Intrinsics:
    """Pinhole intrinsics of a sensor_msgs/CameraInfo (its ``k`` matrix and size; distortion is not kept)."""
    k = np.asarray(msg.k, dtype=np.float64).reshape(-1)
    if k.size != 9:
        raise MessageError(f"CameraInfo k has {k.size} values, expected 9")
    fx, fy, cx, cy = float(k[0]), float(k[4]), float(k[2]), float(k[5])
    # k all zero is ROS's "uncalibrated": nothing can be back-projected with it either.
    if problem := pinhole_problem(fx, fy, cx, cy):
        raise MessageError(f"CameraInfo k: {problem}")
    width, height = int(msg.width), int(msg.height)
    if width <= 0 or height <= 0:
        raise MessageError(f"CameraInfo size {width}x{height}: width and height must be positive")
    return Intrinsics(fx, fy, cx, cy, width, height)


# -- point clouds --------------------------------------------------------------------------------------------
#: sensor_msgs/PointField datatypes.
POINTFIELD_FLOAT32 = 7
_FIELD_TYPES: Mapping[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def pointcloud2_msg(
    points: ArrayLike, *, frame_id: str, stamp_ns: int, colors: ArrayLike | None = None
) -> Any:  # fmt: skip
    """sensor_msgs/msg/PointCloud2 of ``(N, 3)`` points as float32 x, y, z (little-endian, height 1, dense).

    With ``colors`` (``(N, 3)`` uint8 RGB) a fourth field ``rgb`` holds them packed as PCL does (``0x00RRGGBB``
    in a float32's bits).
    """
    xyz = np.asarray(points, dtype="<f4").reshape(-1, 3)
    names = ["x", "y", "z"]
    if colors is None:
        data = np.ascontiguousarray(xyz)
    else:
        rgb = np.asarray(colors, dtype=np.uint8).reshape(-1, 3)
        if len(rgb) != len(xyz):
            raise MessageError(f"point cloud: {len(xyz)} points but {len(rgb)} colours")
        packed = (rgb[:, 0].astype("<u4") << 16) | (rgb[:, 1].astype("<u4") << 8) | rgb[:, 2].astype("<u4")
        data = np.empty((len(xyz), 4), dtype="<f4")
        data[:, :3] = xyz
        data[:, 3] = packed.view("<f4")
        names.append("rgb")
    step = 4 * len(names)
    field = get_type("sensor_msgs/msg/PointField")
    return get_type("sensor_msgs/msg/PointCloud2")(
        header=header(frame_id, stamp_ns), height=1, width=len(xyz),
        fields=[field(name=n, offset=4 * i, datatype=POINTFIELD_FLOAT32, count=1) for i, n in enumerate(names)],
        is_bigendian=False, point_step=step, row_step=step * len(xyz),
        data=data.view(np.uint8).reshape(-1), is_dense=True,
    )  # fmt: skip


def _cloud_rows(msg: Any) -> NDArray[np.uint8]:
    """``(N, point_step)`` bytes of a cloud's points (rows of ``row_step`` bytes may be padded)."""
    step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    row_step = int(msg.row_step) or step * width
    raw = _bytes_of(msg.data)
    if width * height == 0:
        return np.zeros((0, max(step, 1)), np.uint8)
    if step <= 0 or row_step < step * width or len(raw) < row_step * (height - 1) + step * width:
        raise MessageError(
            f"point cloud {width}x{height} with point_step {step}, row_step {row_step} does not fit its "
            f"{len(raw)} data bytes"
        )
    if row_step == step * width:
        return raw[: height * row_step].reshape(width * height, step)
    rows = np.lib.stride_tricks.as_strided(raw, (height, step * width), (row_step, 1), writeable=False)
    return np.ascontiguousarray(rows).reshape(width * height, step)


def _field(msg: Any, rows: NDArray[np.uint8], name: str) -> NDArray[Any]:
    found = [f for f in msg.fields if f.name == name]
    if not found:
        raise MessageError(f"point cloud has no {name!r} field (fields: {[f.name for f in msg.fields]})")
    f = found[0]
    if int(f.datatype) not in _FIELD_TYPES:
        raise MessageError(f"point cloud field {name!r} has unknown datatype {f.datatype}")
    dtype = np.dtype(_FIELD_TYPES[int(f.datatype)]).newbyteorder(">" if msg.is_bigendian else "<")
    offset = int(f.offset)
    if offset + dtype.itemsize > rows.shape[1]:
        raise MessageError(f"point cloud field {name!r} at offset {offset} lies outside point_step {rows.shape[1]}")
    return np.ascontiguousarray(rows[:, offset : offset + dtype.itemsize]).view(dtype)[:, 0]


def pointcloud2_xyz(msg: Any) -> NDArray[np.float32]:
    """``(N, 3)`` float32 x, y, z of a sensor_msgs/PointCloud2, every point (NaN ones included), whatever its
    point step, field offsets and types, row padding and byte order."""
    rows = _cloud_rows(msg)
    if len(rows) == 0:
        return np.zeros((0, 3), np.float32)
    return np.stack([_field(msg, rows, axis).astype(np.float32) for axis in "xyz"], axis=1)


def pointcloud2_rgb(msg: Any) -> NDArray[np.uint8]:
    """``(N, 3)`` uint8 RGB of a cloud's packed ``rgb`` (or ``rgba``) field, ``0x00RRGGBB`` in 4 bytes."""
    rows = _cloud_rows(msg)
    name = "rgb" if any(f.name == "rgb" for f in msg.fields) else "rgba"
    if len(rows) == 0:
        return np.zeros((0, 3), np.uint8)
    values = _field(msg, rows, name)
    if values.dtype.itemsize != 4:
        raise MessageError(f"point cloud field {name!r} is not 4 bytes wide")
    packed = values.view(values.dtype.str[0] + "u4").astype(np.uint32)
    return np.stack([(packed >> 16) & 0xFF, (packed >> 8) & 0xFF, packed & 0xFF], axis=1).astype(np.uint8)
