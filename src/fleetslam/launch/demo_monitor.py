"""The demo's monitor: its own node, which keeps the network statistics, the robots' trajectories (SLAM and ground
truth) and latest SLAM diagnostics, and records the key topics."""

from __future__ import annotations

import logging
import struct
import threading
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import quat_to_matrix
from fleetslam.middleware import Context, Node
from fleetslam.middleware.recording import BagWriter
from fleetslam.middleware.stats_table import StatsTable
from fleetslam.topics import (
    FLEET_TRANSFORM,
    GRAPH_UPDATES,
    ODOM,
    SLAM_DIAGNOSTICS,
    SLAM_ODOM,
    STATISTICS,
    Topic,
)

log = logging.getLogger(__name__)

_STAMP = struct.Struct("<iI")
_LENGTH = struct.Struct("<I")
_POSE = struct.Struct("<7d")


def odometry_stamp_pose(data: bytes) -> tuple[float, NDArray[np.float64]]:
    """Stamp (s) and pose (x, y, z, qx, qy, qz, qw) of a nav_msgs/Odometry in CDR, read where CDR puts them.

    The monitor keeps the ground truth at the physics rate; a full decode (every covariance, every nested message)
    costs some 70 µs, this about 2. Little-endian CDR (what every node sends) is read directly, anything else
    decoded in full. Offsets count from the end of the 4-byte encapsulation header, aligned to each field's size.
    """
    if len(data) < 16 or data[1] != 1:
        return decoded_stamp_pose(data)
    sec, nanosec = _STAMP.unpack_from(data, 4)
    offset = 8  # header.frame_id: length (with its NUL), characters
    offset += 4 + _LENGTH.unpack_from(data, 4 + offset)[0]
    offset = (offset + 3) & ~3  # child_frame_id
    offset += 4 + _LENGTH.unpack_from(data, 4 + offset)[0]
    offset = (offset + 7) & ~7  # pose.pose: position, orientation (float64)
    if 4 + offset + _POSE.size > len(data):
        return decoded_stamp_pose(data)
    return sec + nanosec * 1e-9, np.array(_POSE.unpack_from(data, 4 + offset))


def decoded_stamp_pose(data: bytes) -> tuple[float, NDArray[np.float64]]:
    from fleetslam.msg.typesys import deserialize, ns_from_stamp

    msg = deserialize(data, "nav_msgs/msg/Odometry")
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return ns_from_stamp(msg.header.stamp) / 1e9, np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w])


class OdometryTrack:
    """Stamps and poses of one nav_msgs/Odometry topic, as compact arrays."""

    def __init__(self) -> None:
        self._stamps: list[float] = []
        self._poses: list[NDArray[np.float64]] = []

    def add(self, data: bytes) -> None:
        stamp, pose = odometry_stamp_pose(data)
        self._stamps.append(stamp)
        self._poses.append(pose)

    def __len__(self) -> int:
        return len(self._stamps)

    def samples(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Stamps (s, arrival order) and 4×4 poses."""
        poses = np.tile(np.eye(4), (len(self._poses), 1, 1))
        if self._poses:
            xyzq = np.stack(self._poses)
            poses[:, :3, :3] = quat_to_matrix(xyzq[:, 3:])
            poses[:, :3, 3] = xyzq[:, :3]
        return np.array(self._stamps), poses


class Monitor:
    """The demo's own node: statistics, trajectories, each robot's latest SLAM diagnostics and the recording of
    the key topics.

    Built to stay light: one raw subscription per topic, handled on Zenoh's thread (no hand-off); the bytes are
    recorded as received, only the stamp and pose of the odometry are read (:func:`odometry_stamp_pose`), and only
    the latest diagnostics message is kept, decoded when asked for. The ground truth is not taken off the network
    (the simulator writes it to a file): at 50 Hz per robot it was a third of what the monitor received.
    """

    def __init__(self, ctx: Context, robots: list[str], recording: Path | None) -> None:
        self.node = Node("demo_monitor", context=ctx, statistics_period_s=0)
        self.table = StatsTable(stale_s=1e9)
        self.history: list[dict[str, Any]] = []
        self.tracks: dict[str, OdometryTrack] = {f"{r}/slam": OdometryTrack() for r in robots}
        """Each robot's SLAM camera poses (the ground truth is the simulator's to write: ``sim run --ground-truth``)."""
        self._diagnostics: dict[str, bytes] = {}
        self._started = time.monotonic()
        self._placements: dict[str, tuple[float, bytes]] = {}
        """Per robot: when (s after the monitor started) its SLAM first placed it in the fleet frame, and its latest
        ``slam/fleet_transform``."""
        self._placed_stamps: dict[str, bytes] = {}
        """Per robot, its first ``slam/fleet_transform`` (its stamp: the frame it was placed at)."""
        self.lock = threading.Lock()
        self.writer = BagWriter(recording) if recording is not None else None
        self.node.create_subscription(
            STATISTICS.type, STATISTICS.name, self._on_statistics, STATISTICS.qos(depth=1000), raw=True, inline=True
        )
        for robot in robots:
            followed: list[tuple[Topic, OdometryTrack | None]] = [(SLAM_ODOM, self.tracks[f"{robot}/slam"])]
            if self.writer is not None:  # recorded only
                followed += [(ODOM, None), (GRAPH_UPDATES, None)]
            for topic, track in followed:
                self.node.create_subscription(topic.type, topic.of(robot), partial(self._on_sample, track),
                                              topic.qos(depth=100), raw=True, inline=True)  # fmt: skip
            self.node.create_subscription(
                SLAM_DIAGNOSTICS.type, SLAM_DIAGNOSTICS.of(robot), partial(self._on_diagnostics, robot),
                SLAM_DIAGNOSTICS.qos(depth=1), raw=True, inline=True,
            )  # fmt: skip
            self.node.create_subscription(
                FLEET_TRANSFORM.type, FLEET_TRANSFORM.of(robot), partial(self._on_placement, robot),
                FLEET_TRANSFORM.qos(depth=1), raw=True, inline=True,
            )  # fmt: skip

    def _on_statistics(self, data: bytes, info: Any) -> None:
        from fleetslam.msg.typesys import deserialize

        msg = deserialize(data, info.type_name)
        with self.lock:
            row = self.table.update(msg)
            self.history.append({"t": time.time(), "agent": row.agent, "topic": row.topic,
                                 "subscriber": row.node_sub, "bandwidth_bps": row.bandwidth_bps,
                                 "bytes": int(msg.traffic), "delivered": row.delivered})  # fmt: skip
        if self.writer is not None:
            self.writer.write(info.topic, info.type_name, info.received_timestamp_ns, data)

    def _on_sample(self, track: OdometryTrack | None, data: bytes, info: Any) -> None:
        if self.writer is not None:
            self.writer.write(info.topic, info.type_name, info.received_timestamp_ns, data)
        if track is not None:
            with self.lock:
                track.add(data)

    def _on_diagnostics(self, robot: str, data: bytes, info: Any) -> None:
        with self.lock:
            self._diagnostics[robot] = data

    def _on_placement(self, robot: str, data: bytes, info: Any) -> None:
        with self.lock:
            first = self._placements.get(robot, (time.monotonic() - self._started, b""))[0]
            self._placements[robot] = (first, data)
            self._placed_stamps.setdefault(robot, data)

    def placements(self) -> dict[str, tuple[float, NDArray[np.float64]]]:
        """Per placed robot: seconds after the start when its SLAM placed it in the fleet frame, and its latest
        ``T_fleet_map``."""
        with self.lock:
            latest = dict(self._placements)
        return {robot: (first, decoded[1]) for robot, (first, data) in latest.items()
                if (decoded := _fleet_transform(robot, data)) is not None}  # fmt: skip

    def placement_stamps(self) -> dict[str, float]:
        """Per placed robot, the stamp (s) of its first ``slam/fleet_transform``: its poses stamped earlier were
        tracked before it was placed in the fleet frame."""
        with self.lock:
            first = dict(self._placed_stamps)
        return {robot: decoded[0] for robot, data in first.items()
                if (decoded := _fleet_transform(robot, data)) is not None}  # fmt: skip

    def trajectories(self) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """Stamps and 4×4 poses per ``<robot>/slam``."""
        with self.lock:
            return {key: track.samples() for key, track in self.tracks.items()}

    def slam_diagnostics(self) -> dict[str, dict[str, str]]:
        """The values of each robot's latest ``slam`` diagnostics status (robots that sent none are absent)."""
        from fleetslam.msg.typesys import deserialize

        with self.lock:
            latest = dict(self._diagnostics)
        out = {}
        for robot, data in latest.items():
            values = slam_values(deserialize(data, "diagnostic_msgs/msg/DiagnosticArray"))
            if values is not None:
                out[robot] = values
        return out

    def close(self) -> None:
        self.node.destroy()
        if self.writer is not None:
            self.writer.close()


def _fleet_transform(robot: str, data: bytes) -> tuple[float, NDArray[np.float64]] | None:
    """A robot's ``slam/fleet_transform``: its stamp (s) and ``T_fleet_map``; None (logged) when malformed: not fatal
    to the report."""
    from fleetslam.msg.conversions import transform_matrix
    from fleetslam.msg.typesys import deserialize, ns_from_stamp

    try:
        msg = deserialize(data, FLEET_TRANSFORM.type)
        return ns_from_stamp(msg.header.stamp) / 1e9, transform_matrix(msg.transform)
    except Exception as err:
        log.warning("%s: unreadable fleet transform: %s", robot, err)
        return None


def slam_values(msg: Any) -> dict[str, str] | None:
    """Key → value of the DiagnosticStatus named ``slam`` in a diagnostic_msgs/DiagnosticArray (None if absent)."""
    for status in msg.status:
        if status.name == "slam":
            return {kv.key: kv.value for kv in status.values}
    return None
