"""The console's part in findings: the operator picks a pixel of the live camera image, the console turns it into a
finding anchored to a keyframe and records it with the fleet's findings service (:mod:`fleetslam.inspection.node`).

The bridge feeds :class:`FindingsDesk` what it already receives (each camera's recent raw frames, the SLAM poses
of the camera, the keyframe poses of the ``path``, the camera's intrinsics); nothing is decoded until a pixel is
picked. A pick freezes that frame (photo, depth, pose lookup) while the operator fills in the form, so the finding
is what the operator saw, not what the camera sees a minute later.

Browser messages (see :mod:`fleetslam.station.protocol`): ``finding_pick`` {agent, stamp, u, v} → ``finding_pick``
{ok, message, pick, point, crop}; ``finding_create`` {pick, title, severity, note} → ``finding_created`` {ok,
message, id}; ``finding_update`` {id, title?, severity?, status?, note?} → ``finding_updated`` {ok, message, id};
``finding_photo`` {id} → ``finding_photo`` {id, photo, crop}; every change of ``/fleet/findings`` → ``findings``
{findings: [...]} (no images: the browser asks for a photo when it shows one).
"""

from __future__ import annotations

import base64
import bisect
import itertools
import logging
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam import topics
from fleetslam.errors import FindingError, MessageError, ServiceError
from fleetslam.geometry import interpolate_pose, invert
from fleetslam.inspection.findings import Finding, anchor_to_keyframe, crop_around, pick_point
from fleetslam.inspection.node import (
    CREATE_SERVICE,
    CREATE_TYPE,
    UPDATE_SERVICE,
    UPDATE_TYPE,
    finding_from_msg,
    finding_msg,
)
from fleetslam.intrinsics import Intrinsics
from fleetslam.middleware import Node
from fleetslam.msg.conversions import depth_from_image, intrinsics_from_camera_info, pose_matrix, rgb_from_image
from fleetslam.msg.typesys import deserialize, get_type, message_from_dict, ns_from_stamp

log = logging.getLogger(__name__)

Emit = Any  # the bridge's emit(message, agent_filter)

FRAMES_KEPT = 12
"""Raw frames kept per camera (1.2 s at 10 Hz): the one the browser shows is among them."""
POSES_KEPT = 600
"""SLAM poses kept per agent (a minute at 10 Hz)."""
POSE_WAIT_S = 5.0
"""How long a new finding waits for SLAM to have tracked the picked frame (it runs behind on a loaded machine)."""
MAX_POSE_GAP_NS = 500_000_000
"""Without odometry, the frame's pose is interpolated between SLAM poses at most this far apart."""
ODOM_KEPT = 1500
"""Wheel odometry poses kept per agent (30 s at 50 Hz)."""
MAX_ODOM_GAP_NS = 200_000_000
"""Odometry is interpolated between samples at most this far apart (it comes at 50 Hz; a busy station drops some)."""
MAX_BRIDGE_NS = 2_000_000_000
"""The odometry bridges at most this long from the nearest SLAM pose to the picked frame (its drift: millimetres)."""
PICKS_KEPT = 20


def cdr_image_stamp(payload: bytes | memoryview) -> int:
    """The header stamp (ns) of a CDR sensor_msgs/Image without decoding the pixels (its first fields)."""
    sec, nanosec = struct.unpack_from("<iI", payload, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


@dataclass
class Pick:
    """A frozen pick: what the operator saw at a pixel, waiting for the form."""

    agent: str
    stamp_ns: int
    u: float
    v: float
    point_camera: NDArray[np.float64]
    photo: bytes
    crop: bytes


@dataclass
class _AgentFeed:
    rgb: deque[tuple[int, bytes]]
    depth: deque[tuple[int, bytes]]
    pose_stamps: list[int]
    poses: list[NDArray[np.float64]]
    keyframes: list[NDArray[np.float64]]
    odom_stamps: list[int] = field(default_factory=list)
    odom: list[NDArray[np.float64]] = field(default_factory=list)
    """Wheel odometry: ``T_odom_base``."""
    mounting: NDArray[np.float64] | None = None
    """``T_base_camera`` (the camera's mounting, from ``tf_static``)."""
    intrinsics: Intrinsics | None = None


class FindingsDesk:
    """Picks, creates and updates findings for the console; relays the fleet's findings to the browsers."""

    def __init__(self, node: Node, emit: Emit) -> None:
        self.node = node
        self.emit = emit
        self._lock = threading.Lock()
        self._feeds: dict[str, _AgentFeed] = {}
        self._picks: dict[str, Pick] = {}
        self._pick_ids = itertools.count(1)
        self.findings: dict[str, Finding] = {}
        self._create = node.create_client(CREATE_TYPE, CREATE_SERVICE)
        self._update = node.create_client(UPDATE_TYPE, UPDATE_SERVICE)
        found = topics.FINDINGS
        node.create_subscription(found.type, found.name, self._on_findings, found.qos(depth=1))

    # -- what the bridge feeds ------------------------------------------------------------------------------------
    def _feed(self, agent: str) -> _AgentFeed:
        feed = self._feeds.get(agent)
        if feed is None:
            feed = _AgentFeed(deque(maxlen=FRAMES_KEPT), deque(maxlen=FRAMES_KEPT), [], [], [])
            self._feeds[agent] = feed
        return feed

    def watch(self, agent: str) -> None:
        """Subscribe to what only findings need of an agent (its camera's intrinsics, a few bytes a frame)."""
        info = topics.CAMERA_INFO
        self.node.create_subscription(
            info.type, info.of(agent), lambda m: self._on_camera_info(agent, m), info.qos(depth=1, best_effort=True)
        )

    def _on_camera_info(self, agent: str, msg: Any) -> None:
        try:
            intrinsics = intrinsics_from_camera_info(msg)
        except MessageError as err:
            log.warning("%s camera info: %s", agent, err)
            return
        with self._lock:
            self._feed(agent).intrinsics = intrinsics

    def record_frame(self, agent: str, kind: str, payload: bytes) -> None:
        """A raw camera frame (``rgb`` or ``depth``) as received; decoded only if picked."""
        try:
            stamp = cdr_image_stamp(payload)
        except struct.error:
            return
        with self._lock:
            feed = self._feed(agent)
            (feed.rgb if kind == "rgb" else feed.depth).append((stamp, bytes(payload)))

    def record_pose(self, agent: str, msg: Any) -> None:
        """SLAM's camera pose of a frame (``slam/odom``: camera in the agent's map)."""
        stamp, pose = ns_from_stamp(msg.header.stamp), pose_matrix(msg.pose.pose)
        with self._lock:
            feed = self._feed(agent)
            _insert(feed.pose_stamps, feed.poses, stamp, pose, POSES_KEPT)

    def record_odom(self, agent: str, msg: Any) -> None:
        """The wheel odometry (``odom``: base in the odom frame): it bridges a frame SLAM skipped to a SLAM pose."""
        stamp, pose = ns_from_stamp(msg.header.stamp), pose_matrix(msg.pose.pose)
        with self._lock:
            feed = self._feed(agent)
            _insert(feed.odom_stamps, feed.odom, stamp, pose, ODOM_KEPT)

    def record_mounting(self, agent: str, T_base_camera: NDArray[np.float64]) -> None:
        """The camera's mounting on the base (``tf_static``), through which the odometry moves the camera."""
        with self._lock:
            self._feed(agent).mounting = np.asarray(T_base_camera, dtype=np.float64).reshape(4, 4)

    def record_keyframes(self, agent: str, poses: list[Any]) -> None:
        """The agent's keyframe poses (its ``path``, in id order)."""
        matrices = [pose_matrix(p) for p in poses]
        with self._lock:
            self._feed(agent).keyframes = matrices

    # -- the operator's actions (server thread) ---------------------------------------------------------------------
    def pick(self, agent: str, stamp_ns: int, u: float, v: float) -> dict[str, Any]:
        """Freeze what the operator saw at pixel ``(u, v)`` of the frame stamped ``stamp_ns``."""
        try:
            pick = self._pick(agent, stamp_ns, u, v)
        except (FindingError, MessageError, ValueError) as err:
            return {"type": "finding_pick", "ok": False, "message": str(err)}
        with self._lock:
            pick_id = f"p{next(self._pick_ids)}"
            self._picks[pick_id] = pick
            for old in list(self._picks)[:-PICKS_KEPT]:
                del self._picks[old]
        return {
            "type": "finding_pick", "ok": True, "message": "", "pick": pick_id, "agent": agent,
            "point": np.round(pick.point_camera, 4).tolist(), "crop": base64.b64encode(pick.crop).decode(),
        }  # fmt: skip

    def _pick(self, agent: str, stamp_ns: int, u: float, v: float, *, photos: bool = True) -> Pick:
        with self._lock:
            feed = self._feeds.get(agent)
            if feed is None or not feed.rgb:
                raise FindingError(f"no camera frame of {agent!r} yet")
            rgb_stamp, rgb_payload = min(feed.rgb, key=lambda f: abs(f[0] - stamp_ns))
            if not feed.depth:
                raise FindingError(f"no depth frame of {agent!r} yet")
            depth_stamp, depth_payload = min(feed.depth, key=lambda f: abs(f[0] - rgb_stamp))
            intrinsics = feed.intrinsics
        if intrinsics is None:
            raise FindingError(f"the camera intrinsics of {agent!r} have not arrived yet")
        if abs(depth_stamp - rgb_stamp) > 60_000_000:
            raise FindingError(f"no depth frame of {agent!r} within 60 ms of its colour frame: try again")
        rgb = rgb_from_image(deserialize(rgb_payload, "sensor_msgs/msg/Image"))
        depth = depth_from_image(deserialize(depth_payload, "sensor_msgs/msg/Image"))
        # The depth camera is registered to the colour camera (same optical frame), possibly at its own resolution.
        scale_u, scale_v = depth.shape[1] / rgb.shape[1], depth.shape[0] / rgb.shape[0]
        in_depth = pick_point(depth, intrinsics.scaled(depth.shape[1], depth.shape[0]),
                              (u + 0.5) * scale_u - 0.5, (v + 0.5) * scale_v - 0.5)  # fmt: skip
        z = in_depth[2]
        colour = intrinsics.scaled(rgb.shape[1], rgb.shape[0])
        point = np.array([(u - colour.cx) / colour.fx * z, (v - colour.cy) / colour.fy * z, z])
        if not photos:
            return Pick(agent, rgb_stamp, u, v, point, b"", b"")
        return Pick(agent, rgb_stamp, u, v, point, _jpeg(rgb), _jpeg(crop_around(rgb, u, v)))

    def locate(self, agent: str, stamp_ns: int, u: float, v: float) -> dict[str, Any]:
        """Measuring: the point at pixel ``(u, v)`` of the frame stamped ``stamp_ns``, in the agent's map frame (where
        its keyframes are drawn), so that two picks on different frames can be measured between."""
        try:
            pick = self._pick(agent, stamp_ns, u, v, photos=False)
            T_map_camera = self._pose_at(agent, pick.stamp_ns)
        except (FindingError, MessageError, ValueError) as err:
            return {"type": "measure_point", "ok": False, "message": str(err)}
        in_map = T_map_camera[:3, :3] @ pick.point_camera + T_map_camera[:3, 3]
        return {"type": "measure_point", "ok": True, "message": "", "agent": agent, "stamp": str(pick.stamp_ns),
                "point": np.round(in_map, 4).tolist(), "range": round(float(pick.point_camera[2]), 4)}  # fmt: skip

    def create(self, pick_id: str, title: str, severity: str, note: str) -> dict[str, Any]:
        """Anchor a pick to its keyframe and record it with the findings service."""
        reply: dict[str, Any] = {"type": "finding_created", "ok": False, "id": ""}
        with self._lock:
            pick = self._picks.get(pick_id)
        if pick is None:
            return {**reply, "message": f"pick {pick_id!r} expired: click on the image again"}
        try:
            T_map_camera = self._pose_at(pick.agent, pick.stamp_ns)
            with self._lock:
                keyframes = list(self._feed(pick.agent).keyframes)
            keyframe, point = anchor_to_keyframe(pick.point_camera, T_map_camera, keyframes)
            draft = Finding(
                id="", title=title, severity=severity, status="open", note=note, agent=pick.agent,
                keyframe_id=keyframe, point=(float(point[0]), float(point[1]), float(point[2])),
                pixel=(pick.u, pick.v), stamp_ns=pick.stamp_ns, photo=pick.photo, crop=pick.crop,
            ).validated()  # fmt: skip
            request = get_type(f"{CREATE_TYPE}_Request")(finding=finding_msg(draft))
            response = self._create.call(request, timeout=10.0)
        except (FindingError, ServiceError) as err:
            return {**reply, "message": str(err)}
        if response.success:
            with self._lock:
                self._picks.pop(pick_id, None)
        return {**reply, "ok": bool(response.success), "message": str(response.message), "id": str(response.id)}

    def _pose_at(self, agent: str, stamp_ns: int) -> NDArray[np.float64]:
        """SLAM's camera pose at ``stamp_ns``, waiting a while for SLAM to catch up.

        SLAM processes the newest frame when it is free, so it skips frames (half of them on a loaded machine).
        A skipped frame's pose is the nearest SLAM pose moved by the wheel odometry between the two stamps,
        through the camera's mounting: ``T_map_cam(t) = T_map_cam(s) · T_base_cam⁻¹ · T_odom_base(s)⁻¹ ·
        T_odom_base(t) · T_base_cam`` (over a fraction of a second odometry drifts by millimetres; it follows
        a turn that interpolating between SLAM poses cuts). Without odometry around both stamps, it is
        interpolated between SLAM poses at most ``MAX_POSE_GAP_NS`` apart.
        """
        deadline = time.monotonic() + POSE_WAIT_S
        while True:
            with self._lock:
                feed = self._feed(agent)
                stamps, poses = list(feed.pose_stamps), list(feed.poses)
                odom_stamps, odom, mounting = list(feed.odom_stamps), list(feed.odom), feed.mounting
            i = bisect.bisect_left(stamps, stamp_ns)
            if i < len(stamps) and stamps[i] == stamp_ns:
                return poses[i]
            # Until SLAM has gone past the frame it may still track it; then the frame was skipped.
            if i < len(stamps) or time.monotonic() > deadline:
                nearest = sorted(
                    (j for j in (i - 1, i) if 0 <= j < len(stamps)), key=lambda j: abs(stamps[j] - stamp_ns)
                )
                for j in nearest:
                    if mounting is None or abs(stamps[j] - stamp_ns) > MAX_BRIDGE_NS:
                        continue
                    odom_then, odom_now = _at(odom_stamps, odom, stamps[j]), _at(odom_stamps, odom, stamp_ns)
                    if odom_then is not None and odom_now is not None:
                        moved = invert(odom_then) @ odom_now  # the base's motion, in the base's frame then
                        return poses[j] @ invert(mounting) @ moved @ mounting
                if 0 < i < len(stamps) and stamps[i] - stamps[i - 1] <= MAX_POSE_GAP_NS:
                    fraction = (stamp_ns - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
                    return interpolate_pose(poses[i - 1], poses[i], fraction)
                raise FindingError(
                    f"SLAM of {agent!r} has no pose of the picked frame (it was not tracked, and no SLAM pose within "
                    f"{MAX_BRIDGE_NS / 1e9:.0f} s has wheel odometry to bridge the gap)"
                )
            time.sleep(0.05)

    def update(self, finding_id: str, changes: dict[str, str]) -> dict[str, Any]:
        """Change a finding's title, severity, status or note."""
        fields = {k: str(changes[k]) for k in ("title", "severity", "status", "note") if changes.get(k) is not None}
        reply: dict[str, Any] = {"type": "finding_updated", "ok": False, "id": finding_id}
        try:
            request = message_from_dict(f"{UPDATE_TYPE}_Request", {"id": finding_id, **fields})
            response = self._update.call(request, timeout=10.0)
        except (ServiceError, MessageError) as err:
            return {**reply, "message": str(err)}
        return {**reply, "ok": bool(response.success), "message": str(response.message)}

    def photo(self, finding_id: str) -> dict[str, Any]:
        finding = self.findings.get(finding_id)
        if finding is None:
            return {"type": "finding_photo", "id": finding_id, "photo": "", "crop": ""}
        encode = base64.b64encode
        return {"type": "finding_photo", "id": finding_id, "photo": encode(finding.photo).decode(),
                "crop": encode(finding.crop).decode()}  # fmt: skip

    # -- the fleet's findings -------------------------------------------------------------------------------------
    def _on_findings(self, msg: Any) -> None:
        self.findings = {f.id: f for f in (finding_from_msg(m) for m in msg.findings)}
        self.emit(self.message(), None)

    def message(self) -> dict[str, Any]:
        """The ``findings`` message: every finding, without its images."""
        return {"type": "findings", "findings": [finding_json(f) for f in self.findings.values()]}


def _insert(stamps: list[int], poses: list[NDArray[np.float64]], stamp: int, pose: NDArray[np.float64],
            kept: int) -> None:  # fmt: skip
    """Keep ``pose`` at ``stamp`` in stamp order (at the end, unless it came late), the newest ``kept``."""
    i = bisect.bisect_left(stamps, stamp)
    if i < len(stamps) and stamps[i] == stamp:
        poses[i] = pose
        return
    stamps.insert(i, stamp)
    poses.insert(i, pose)
    del stamps[:-kept], poses[:-kept]


def _at(stamps: list[int], poses: list[NDArray[np.float64]], stamp: int) -> NDArray[np.float64] | None:
    """The pose at ``stamp`` interpolated between samples at most ``MAX_ODOM_GAP_NS`` apart; None outside them."""
    i = bisect.bisect_left(stamps, stamp)
    if i < len(stamps) and stamps[i] == stamp:
        return poses[i]
    if 0 < i < len(stamps) and stamps[i] - stamps[i - 1] <= MAX_ODOM_GAP_NS:
        return interpolate_pose(poses[i - 1], poses[i], (stamp - stamps[i - 1]) / (stamps[i] - stamps[i - 1]))
    return None


def finding_json(finding: Finding) -> dict[str, Any]:
    """A finding for the browser (names and texts are inserted there as text)."""
    return {
        "id": finding.id, "title": finding.title, "severity": finding.severity, "status": finding.status,
        "note": finding.note, "agent": finding.agent, "keyframe_id": finding.keyframe_id,
        "point": list(finding.point), "pixel": list(finding.pixel), "stamp_ns": finding.stamp_ns,
        "has_photo": bool(finding.photo), "position": list(finding.position) if finding.position else None,
    }  # fmt: skip


def _jpeg(rgb: NDArray[np.uint8]) -> bytes:
    import cv2

    ok, buffer = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        raise FindingError("JPEG encoding of the photo failed")
    return bytes(buffer.tobytes())
