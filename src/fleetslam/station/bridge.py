"""The console's node: discovers agents, subscribes to what the operator sees, publishes what the operator does.

Middleware callbacks run on the node's executor thread; every browser-bound message goes through ``emit``
(thread-safe, supplied by the server). Latest state per agent is kept so a browser that connects later gets a
snapshot at once.
"""

from __future__ import annotations

import base64
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from fleetslam import topics
from fleetslam.errors import MessageError
from fleetslam.geometry import invert, matrix_to_quat
from fleetslam.middleware import Context, Node
from fleetslam.middleware.stats_table import StatsTable
from fleetslam.msg.conversions import (
    depth_from_image,
    image_to_array,
    pointcloud2_xyz,
    pose_matrix,
    rgb_from_image,
    transform_matrix,
)
from fleetslam.msg.typesys import deserialize, get_type, ns_from_stamp
from fleetslam.station.findings import FindingsDesk
from fleetslam.station.protocol import TeleopGate, TeleopLimits, VoxelDiff, yaw_from_quaternion

log = logging.getLogger(__name__)

Emit = Callable[[dict[str, Any], str | None], None]
"""emit(message, agent_filter): send to every browser (or only those watching ``agent_filter``'s camera)."""

FLEET_AGENT = "fleet"


@dataclass
class AgentView:
    """What the console keeps about one agent."""

    name: str
    voxels: VoxelDiff
    poses: dict[str, dict[str, Any]] = field(default_factory=dict)
    paths: dict[str, list[list[float]]] = field(default_factory=dict)
    keyframes: list[list[float]] = field(default_factory=list)
    last_image: dict[str, float] = field(default_factory=dict)
    last_pose: dict[str, float] = field(default_factory=dict)
    """When each pose source was last sent to the browsers (monotonic s)."""
    image_seq: int = 0
    own_placement: list[float] | None = None
    """``T_fleet_map`` (row-major) as the agent's SLAM placed its map frame (``slam/fleet_transform``)."""
    fleet_placement: list[float] | None = None
    """``T_fleet_map`` (row-major) from the fleet back-end's joint optimisation (``/fleet/placements``)."""

    @property
    def placement(self) -> list[float] | None:
        """Where the agent's map frame is drawn: the back-end's placement, which the fleet map uses too, else the
        agent's own, else None (not merged yet)."""
        return self.fleet_placement if self.fleet_placement is not None else self.own_placement

    mounting: list[float] | None = None
    """``T_base_camera`` (row-major) from the agent's ``tf_static``: which way is up in its map frame."""


class StationBridge:
    """Bridges the fleet and the browsers."""

    def __init__(
        self,
        context: Context,
        emit: Emit,
        *,
        limits: TeleopLimits | None = None,
        voxel_resolution: float = 0.05,
        image_rate_hz: float = 5.0,
        pose_rate_hz: float = 10.0,
        wanted_cameras: Callable[[], set[tuple[str, str]]] = lambda: set(),
    ) -> None:
        self.node = Node("station", context=context, namespace="/")
        self.emit = emit
        self.gate = TeleopGate(limits or TeleopLimits())
        self.voxel_resolution = voxel_resolution
        self.image_period = 1.0 / image_rate_hz
        # Odometry arrives at 50 Hz from three sources per robot; the view draws at most ten times a second.
        self.pose_period = 1.0 / pose_rate_hz
        self.wanted_cameras = wanted_cameras
        self.agents: dict[str, AgentView] = {}
        self.stats = StatsTable()
        self._lock = threading.Lock()
        self._cmd_publishers: dict[str, Any] = {}
        self._estop_clients: dict[str, Any] = {}
        self._twist = get_type("geometry_msgs/msg/Twist")
        self._vector = get_type("geometry_msgs/msg/Vector3")
        self.findings = FindingsDesk(self.node, emit)
        """Findings: picks on the camera image, the fleet's findings (fleetslam.station.findings)."""
        statistics = topics.STATISTICS
        self.node.create_subscription(statistics.type, statistics.name, self._on_statistics, statistics.qos(depth=1000))
        self._add_agent(FLEET_AGENT, fleet=True)
        self._fleet_placements: dict[str, list[float]] = {}
        """The back-end's latest placement per agent, also of agents not discovered yet."""
        placements = topics.FLEET_PLACEMENTS
        self.node.create_subscription(placements.type, placements.name, self._on_fleet_placements,
                                      placements.qos(depth=1))  # fmt: skip
        self.node.create_timer(1.0, self._discover)
        self.node.create_timer(1.0, self._send_stats)
        self.node.call_soon(self._discover)

    # -- discovery ---------------------------------------------------------------------------------------------
    def _discover(self) -> None:
        graph = self.node.context.graph
        found: set[str] = set()
        for topic in graph.topic_names_and_types():
            parts = topic.strip("/").split("/")
            if len(parts) >= 2 and parts[0] != FLEET_AGENT and parts[1] in ("cmd_vel", "odom", "camera", "map"):
                found.add(parts[0])
        new = sorted(found - self.agents.keys())
        for name in new:
            self._add_agent(name)
        if new:
            self.emit({"type": "agents", "agents": self.agent_names()}, None)

    def agent_names(self) -> list[str]:
        return sorted(a for a in self.agents if a != FLEET_AGENT)

    def _add_agent(self, name: str, fleet: bool = False) -> None:
        view = AgentView(name, VoxelDiff(self.voxel_resolution))
        self.agents[name] = view
        sub = self.node.create_subscription
        # The agent's map and graph are latched: a console started later gets them at once.
        cloud = topics.FLEET_MAP_OCCUPIED if fleet else topics.MAP_OCCUPIED
        sub(cloud.type, cloud.of(name), lambda m: self._on_cloud(view, m), cloud.qos(depth=1))
        if fleet:
            return
        view.fleet_placement = self._fleet_placements.get(name)
        self.findings.watch(name)
        # SLAM's poses are all kept (depth 20): a finding picked on a frame needs the poses around it, and a busy
        # station dropped them with depth 1 (the pick then failed as "not tracked"); so is the wheel odometry (depth
        # 25, half a second at 50 Hz), which bridges a frame SLAM skipped to its nearest SLAM pose.
        for source, odom, depth in (("odom", topics.ODOM, 25), ("slam", topics.SLAM_ODOM, 20),
                                    ("truth", topics.GROUND_TRUTH_ODOM, 1)):  # fmt: skip
            sub(odom.type, odom.of(name), self._odom_callback(view, source), odom.qos(depth=depth))
        # The keyframe poses come with the path (the same poses): the whole graph, constraints and all, grows to
        # hundreds of kB and would cost the station that much every second for nothing it shows.
        path = topics.PATH
        sub(path.type, path.of(name), lambda m: self._on_path(view, "slam", m), path.qos(depth=1))
        for kind, image in (("rgb", topics.RGB_IMAGE), ("depth", topics.DEPTH_IMAGE)):
            # Raw: an image is decoded only when a console shows that camera and its period is due (the
            # station otherwise deserialised every frame of every camera, ~8 MB/s in the demo, for nothing).
            sub(image.type, image.of(name), self._image_callback(view, kind), image.qos(depth=1, best_effort=True),
                raw=True)  # fmt: skip
        self._follow_frames(view)
        # Depth 10, the middleware's default that the console has always published with.
        cmd_vel = topics.CMD_VEL
        self._cmd_publishers[name] = self.node.create_publisher(cmd_vel.type, cmd_vel.of(name), cmd_vel.qos(depth=10))
        self._estop_clients[name] = self.node.create_client("std_srvs/srv/SetBool", f"/{name}/e_stop")

    # -- subscriptions -----------------------------------------------------------------------------------------
    def _odom_callback(self, view: AgentView, source: str) -> Callable[[Any], None]:
        return lambda msg: self._on_odom(view, source, msg)

    def _image_callback(self, view: AgentView, kind: str) -> Callable[[bytes], None]:
        return lambda payload: self._on_image(view, kind, payload)

    def _on_cloud(self, view: AgentView, msg: Any) -> None:
        try:
            xyz = pointcloud2_xyz(msg)
        except MessageError as err:
            log.warning("%s point cloud: %s", view.name, err)
            return
        points = xyz[np.isfinite(xyz).all(axis=1)].astype(np.float64)
        added, removed = view.voxels.update(points)
        if len(added) or len(removed):
            self.emit(
                {"type": "voxels", "agent": view.name, "size": self.voxel_resolution, "add": added,
                 "remove": removed, "total": len(view.voxels)},
                None,
            )  # fmt: skip

    def _on_odom(self, view: AgentView, source: str, msg: Any) -> None:
        if source == "slam":
            self.findings.record_pose(view.name, msg)
        elif source == "odom":
            self.findings.record_odom(view.name, msg)
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        if source == "slam":  # the camera's pose: the robot's marker goes where its base is
            pose = robot_pose(pose_matrix(msg.pose.pose), view.mounting)
        else:
            pose = {"x": p.x, "y": p.y, "z": p.z, "yaw": yaw_from_quaternion(q.x, q.y, q.z, q.w),
                    "q": [q.x, q.y, q.z, q.w]}  # fmt: skip
        view.poses[source] = pose
        path = view.paths.setdefault(source, [])
        if not path or (path[-1][0] - p.x) ** 2 + (path[-1][1] - p.y) ** 2 > 0.0025:
            path.append([round(p.x, 3), round(p.y, 3), round(p.z, 3)])
            del path[:-5000]
        now = time.monotonic()
        if now - view.last_pose.get(source, -math.inf) >= self.pose_period:
            view.last_pose[source] = now
            self.emit({"type": "pose", "agent": view.name, "source": source, **pose}, None)

    def _on_path(self, view: AgentView, source: str, msg: Any) -> None:
        points = [[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in msg.poses]
        view.paths[source] = points
        self.emit({"type": "path", "agent": view.name, "source": source, "points": points}, None)
        if source == "slam":  # SLAM's path is its keyframes' poses
            self._on_keyframes(view, [s.pose for s in msg.poses])

    def _on_keyframes(self, view: AgentView, poses: list[Any]) -> None:
        view.keyframes = [
            [p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
             p.orientation.w]
            for p in poses
        ]  # fmt: skip
        self.findings.record_keyframes(view.name, poses)
        self.emit({"type": "keyframes", "agent": view.name, "poses": view.keyframes}, None)

    def _on_image(self, view: AgentView, kind: str, payload: bytes) -> None:
        self.findings.record_frame(view.name, kind, payload)
        if (view.name, kind) not in self.wanted_cameras():
            return
        now = time.monotonic()
        if now - view.last_image.get(kind, 0.0) < self.image_period:
            return
        view.last_image[kind] = now
        try:
            msg = deserialize(payload, "sensor_msgs/msg/Image")
            mime, data = encode_image(msg, kind)
        except (ValueError, MessageError) as err:
            log.warning("%s %s image: %s", view.name, kind, err)
            return
        view.image_seq += 1
        self.emit(
            {"type": "image", "agent": view.name, "kind": kind, "mime": mime, "seq": view.image_seq,
             "stamp": str(ns_from_stamp(msg.header.stamp)), "data": base64.b64encode(data).decode()},
            view.name,
        )  # fmt: skip

    # -- frames: where each agent's map frame lies in the fleet frame, and which way is up in it -------------
    def _follow_frames(self, view: AgentView) -> None:
        """The agent's ``slam/fleet_transform`` and its camera's mounting (``tf_static``), both latched: a console
        started later gets them at once."""
        for topic, callback in ((topics.FLEET_TRANSFORM, self._on_placement), (topics.TF_STATIC, self._on_mounting)):
            self.node.create_subscription(topic.type, topic.of(view.name), partial(callback, view), topic.qos(depth=1))

    def _on_placement(self, view: AgentView, msg: Any) -> None:
        """``fleet → <agent>/map``: the page draws the agent's map, path and marker through it."""
        matrix = _finite_matrix(view.name, "fleet transform", msg.transform)
        if matrix is not None:
            view.own_placement = matrix
            self.emit(frame_message(view), None)

    def _on_fleet_placements(self, msg: Any) -> None:
        """The back-end's ``fleet → <agent>/map`` of every agent it placed: preferred over the agents' own."""
        for transform in msg.transforms:
            agent, _, frame = transform.child_frame_id.strip("/").rpartition("/")
            if frame != "map" or not agent or agent == FLEET_AGENT:
                continue
            matrix = _finite_matrix(agent, "fleet placement", transform.transform)
            if matrix is None:
                continue
            if len(self._fleet_placements) < 1024 or agent in self._fleet_placements:  # forged names: bounded
                self._fleet_placements[agent] = matrix
            view = self.agents.get(agent)
            if view is not None and view.fleet_placement != matrix:
                view.fleet_placement = matrix
                self.emit(frame_message(view), None)

    def _on_mounting(self, view: AgentView, msg: Any) -> None:
        """``base_link → *optical_frame``: the agent's map frame is its camera's at start, upright through this."""
        for transform in msg.transforms:
            parent, child = transform.header.frame_id.split("/")[-1], transform.child_frame_id
            if parent == "base_link" and child.endswith("optical_frame"):
                matrix = _finite_matrix(view.name, "camera mounting", transform.transform)
                if matrix is not None:
                    view.mounting = matrix
                    self.findings.record_mounting(view.name, np.reshape(matrix, (4, 4)))
                    self.emit(frame_message(view), None)

    def _on_statistics(self, msg: Any) -> None:
        with self._lock:
            self.stats.update(msg)

    def _send_stats(self) -> None:
        with self._lock:
            rows = [r.as_dict() for r in self.stats.rows(now_ns=time.time_ns())]
        self.emit({"type": "stats", "rows": rows}, None)

    # -- operator actions (from the server's thread) -------------------------------------------------------
    def tick_teleop(self, now: float) -> dict[str, tuple[float, float]]:
        """Publish the commands the gate releases now."""
        commands = self.gate.tick(now)
        for agent, (v, w) in commands.items():
            publisher = self._cmd_publishers.get(agent)
            if publisher is not None:
                publisher.publish(
                    self._twist(linear=self._vector(x=v, y=0.0, z=0.0), angular=self._vector(x=0.0, y=0.0, z=w))
                )
        return commands

    def estop(self, agent: str, engage: bool, timeout_s: float = 3.0) -> tuple[bool, str]:
        """Engage or release an agent's latched e-stop through its `e_stop` service."""
        client = self._estop_clients.get(agent)
        if client is None:
            return False, f"unknown agent {agent}"
        request = get_type("std_srvs/srv/SetBool_Request")(data=engage)
        try:
            response = client.call(request, timeout=timeout_s)
        except Exception as err:
            return False, str(err)
        return bool(response.success), str(response.message)

    def snapshot(self) -> list[dict[str, Any]]:
        """Messages that bring a new browser up to date."""
        out: list[dict[str, Any]] = [{"type": "agents", "agents": self.agent_names()}]
        for view in list(self.agents.values()):
            keys = view.voxels.keys()
            if len(keys):
                out.append(
                    {"type": "voxels", "agent": view.name, "size": self.voxel_resolution, "add": keys,
                     "remove": keys[:0], "total": len(keys), "reset": True}
                )  # fmt: skip
            for source, pose in view.poses.items():
                out.append({"type": "pose", "agent": view.name, "source": source, **pose})
            for source, points in view.paths.items():
                out.append({"type": "path", "agent": view.name, "source": source, "points": points})
            if view.keyframes:
                out.append({"type": "keyframes", "agent": view.name, "poses": view.keyframes})
            if view.placement is not None or view.mounting is not None:
                out.append(frame_message(view))
        if self.findings.findings:
            out.append(self.findings.message())
        return out

    def close(self) -> None:
        self.node.destroy()


def encode_image(msg: Any, kind: str) -> tuple[str, bytes]:
    """JPEG of an rgb8/bgr8/rgba8/bgra8/mono8 image, or a colour-mapped JPEG of a 32FC1 (m) / 16UC1 (mm) depth
    image (rows decoded with their ``step`` and byte order)."""
    import cv2

    image: Any
    if msg.encoding in ("32FC1", "16UC1", "mono16"):
        depth = depth_from_image(msg)
        valid = depth > 0
        scaled = np.zeros(depth.shape, dtype=np.uint8)
        scaled[valid] = np.clip(255.0 * (1.0 - np.clip(depth[valid], 0.0, 5.0) / 5.0), 1, 255).astype(np.uint8)
        image = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
        image[~valid] = 0
    elif msg.encoding == "mono8":
        image = image_to_array(msg)
    else:
        image = rgb_from_image(msg)[:, :, ::-1]  # OpenCV writes BGR
    ok, buffer = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, 80])
    if not ok:
        raise ValueError("JPEG encoding failed")
    del kind
    return "image/jpeg", buffer.tobytes()


def frame_message(view: AgentView) -> dict[str, Any]:
    """The browsers' ``frame`` message of an agent: its placement and camera mounting (each None until known)."""
    return {"type": "frame", "agent": view.name, "placement": view.placement, "mounting": view.mounting}


def _finite_matrix(agent: str, what: str, transform: Any) -> list[float] | None:
    """A geometry_msgs/Transform as a row-major 4×4 list; None (logged) when it is not a finite rigid transform."""
    try:
        matrix = transform_matrix(transform)
    except (ValueError, MessageError) as err:
        log.warning("%s %s: %s", agent, what, err)
        return None
    if not np.isfinite(matrix).all():
        log.warning("%s %s is not finite: ignored", agent, what)
        return None
    return [float(v) for v in matrix.reshape(-1)]


#: ``T_base_camera`` of a level camera looking ahead (optical z ahead, x right, y down), for a robot whose camera
#: mounting is not known.
LEVEL_CAMERA = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def robot_pose(camera: np.ndarray, mounting: list[float] | None) -> dict[str, Any]:
    """The browsers' pose of a robot's base (``T_map_base``, marker and heading) from its camera's pose
    ``T_map_camera`` and the camera's mounting ``T_base_camera`` (row-major; a level camera when not known)."""
    base = camera @ invert(np.reshape(mounting, (4, 4)) if mounting is not None else LEVEL_CAMERA)
    x, y, z, w = matrix_to_quat(base[:3, :3])
    return {"x": float(base[0, 3]), "y": float(base[1, 3]), "z": float(base[2, 3]),
            "yaw": yaw_from_quaternion(x, y, z, w), "q": [float(x), float(y), float(z), float(w)]}  # fmt: skip
