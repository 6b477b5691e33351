"""The SLAM node of one agent: camera topics in, pose, keyframes and the keyframe graph out.

Subscribes ``camera/rgb/image_raw`` (rgb8/bgr8), ``camera/depth/image_raw`` (32FC1 m or 16UC1 mm) and
``camera/rgb/camera_info``; frames are paired by stamp and fed to :class:`~fleetslam.slam.pipeline.SlamPipeline`.
Publishes ``slam/odom`` (nav_msgs/Odometry, camera pose in ``map``), ``path`` (nav_msgs/Path of keyframes),
``liveframes`` (Keyframe without images, every frame), ``keyframes`` (Keyframe with JPEG colour, PNG depth in mm,
keypoints, 3D points and descriptors) and ``graph`` (KeyframeGraph: every keyframe pose and constraint; after a
loop closure all poses are re-sent, never points). Services: ``slam/save_map`` (SaveMap: map.db),
``slam/reset`` (Trigger), ``slam/pause`` (SetBool).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from fleetslam.config import ConfigModel
from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.geometry import pose_to_quat
from fleetslam.middleware import Node, QoSProfile
from fleetslam.middleware.typesys import get_type, header, message_from_dict, ns_from_stamp
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.pipeline import SlamPipeline, StepResult

log = logging.getLogger(__name__)


class SlamNodeConfig(ConfigModel):
    """Parameters of the SLAM node."""

    slam: SlamConfig = Field(default_factory=SlamConfig)
    """The SLAM pipeline."""
    map_frame: str = "map"
    """Frame of published poses."""
    camera_frame: str = "camera_optical_frame"
    """Child frame of slam/odom."""
    jpeg_quality: int = Field(default=85, ge=10, le=100)
    """Quality of keyframe colour images."""
    max_pending: int = Field(default=4, ge=1)
    """Unpaired colour images kept while waiting for their depth."""
    map_db: str = "map.db"
    """Default file of the save_map service."""
    peers: list[str] = Field(default_factory=list)
    """Other agents whose `graph` and `keyframes` this agent subscribes to (the distributed framework's
    cross-agent subscription; kept in ``peer_graphs`` / ``peer_keyframes`` for fusion and inter-agent loops)."""


def image_to_array(msg: Any) -> np.ndarray:
    """RGB uint8 (H, W, 3) or depth float32 metres (H, W) of a sensor_msgs/Image."""
    h, w, enc = int(msg.height), int(msg.width), msg.encoding
    raw = np.frombuffer(bytes(msg.data), np.uint8)
    if enc == "rgb8":
        return raw[: h * w * 3].reshape(h, w, 3)
    if enc == "bgr8":
        return raw[: h * w * 3].reshape(h, w, 3)[:, :, ::-1]
    if enc == "32FC1":
        depth = raw[: h * w * 4].view("<f4").reshape(h, w).copy()
        depth[~np.isfinite(depth)] = 0.0
        return depth
    if enc == "16UC1":
        return raw[: h * w * 2].view("<u2").reshape(h, w).astype(np.float32) / 1000.0
    raise ValueError(f"unsupported image encoding {enc!r}")


def _pose_dict(pose: np.ndarray) -> dict[str, Any]:
    t, q = pose_to_quat(pose)
    return {
        "position": dict(zip("xyz", t.tolist(), strict=True)),
        "orientation": dict(zip("xyzw", q.tolist(), strict=True)),
    }


class SlamNode:
    """Adapter between the middleware and a :class:`SlamPipeline`."""

    def __init__(self, node: Node, config: SlamNodeConfig | None = None) -> None:
        self.node = node
        self.config = config or SlamNodeConfig()
        self.pipeline: SlamPipeline | None = None
        self.camera_info: Any = None
        self.paused = False
        self.frames = 0
        self._pending: dict[int, Any] = {}
        self._depth: dict[int, Any] = {}
        self.agent = node.namespace.strip("/")
        qos = QoSProfile(depth=5)
        self.odom_pub = node.create_publisher("nav_msgs/msg/Odometry", "slam/odom", qos)
        self.path_pub = node.create_publisher("nav_msgs/msg/Path", "path", QoSProfile(depth=1))
        self.live_pub = node.create_publisher("fleetslam_msgs/msg/Keyframe", "liveframes", qos)
        self.keyframe_pub = node.create_publisher("fleetslam_msgs/msg/Keyframe", "keyframes", QoSProfile(depth=50))
        self.graph_pub = node.create_publisher(
            "fleetslam_msgs/msg/KeyframeGraph", "graph", QoSProfile(durability="transient_local", depth=1)
        )
        images = QoSProfile(depth=2)
        node.create_subscription("sensor_msgs/msg/Image", "camera/rgb/image_raw", self.on_rgb, images)
        node.create_subscription("sensor_msgs/msg/Image", "camera/depth/image_raw", self.on_depth, images)
        node.create_subscription("sensor_msgs/msg/CameraInfo", "camera/rgb/camera_info", self.on_camera_info, qos)
        self.peer_graphs: dict[str, Any] = {}
        self.peer_keyframes: dict[str, int] = {}
        for peer in self.config.peers:
            node.create_subscription(
                "fleetslam_msgs/msg/KeyframeGraph", f"/{peer}/graph", self.on_peer_graph,
                QoSProfile(durability="transient_local", depth=1),
            )  # fmt: skip
            node.create_subscription(
                "fleetslam_msgs/msg/Keyframe", f"/{peer}/keyframes", self.on_peer_keyframe, QoSProfile(depth=50)
            )
        node.create_service("fleetslam_msgs/srv/SaveMap", "slam/save_map", self.on_save_map)
        node.create_service("std_srvs/srv/Trigger", "slam/reset", self.on_reset)
        node.create_service("std_srvs/srv/SetBool", "slam/pause", self.on_pause)

    # -- inputs -------------------------------------------------------------------------------------------------
    def on_camera_info(self, msg: Any) -> None:
        if self.pipeline is None:
            k = msg.k
            intrinsics = Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(msg.width), int(msg.height))
            self.pipeline = SlamPipeline(self.config.slam, intrinsics=intrinsics)
            log.info("%s: SLAM started with fx=%.1f at %dx%d", self.agent, intrinsics.fx, msg.width, msg.height)
        self.camera_info = msg

    def on_rgb(self, msg: Any) -> None:
        self._pair(ns_from_stamp(msg.header.stamp), rgb=msg)

    def on_depth(self, msg: Any) -> None:
        self._pair(ns_from_stamp(msg.header.stamp), depth=msg)

    def _pair(self, stamp: int, rgb: Any = None, depth: Any = None) -> None:
        if rgb is not None:
            self._pending[stamp] = rgb
        if depth is not None:
            self._depth[stamp] = depth
        if stamp in self._pending and stamp in self._depth:
            rgb_msg, depth_msg = self._pending.pop(stamp), self._depth.pop(stamp)
            for old in [s for s in self._pending if s < stamp]:
                del self._pending[old]
            for old in [s for s in self._depth if s < stamp]:
                del self._depth[old]
            self.process(stamp, rgb_msg, depth_msg)
        for queue in (self._pending, self._depth):
            while len(queue) > self.config.max_pending:
                del queue[min(queue)]

    def on_peer_graph(self, msg: Any) -> None:
        self.peer_graphs[msg.agent] = msg

    def on_peer_keyframe(self, msg: Any) -> None:
        self.peer_keyframes[msg.agent] = self.peer_keyframes.get(msg.agent, 0) + 1

    # -- work ---------------------------------------------------------------------------------------------------
    def process(self, stamp_ns: int, rgb_msg: Any, depth_msg: Any) -> StepResult | None:
        if self.pipeline is None or self.paused:
            return None
        frame = RGBDFrame(self.frames, stamp_ns / 1e9, image_to_array(rgb_msg), image_to_array(depth_msg))
        self.frames += 1
        step = self.pipeline.step(frame)
        self.publish_pose(stamp_ns, step)
        if step.keyframe_id is not None:
            self.publish_keyframe(stamp_ns, step, frame)
            self.publish_graph(stamp_ns, optimized=step.loop_closed)
        return step

    def publish_pose(self, stamp_ns: int, step: StepResult) -> None:
        odom = message_from_dict(
            "nav_msgs/msg/Odometry",
            {"child_frame_id": self.config.camera_frame, "pose": {"pose": _pose_dict(step.pose)}},
        )
        odom.header = header(self.config.map_frame, stamp_ns)
        self.odom_pub.publish(odom)
        live = message_from_dict(
            "fleetslam_msgs/msg/Keyframe", {"agent": self.agent, "id": self.frames, "pose": _pose_dict(step.pose)}
        )
        live.header = odom.header
        self.live_pub.publish(live)

    def publish_keyframe(self, stamp_ns: int, step: StepResult, frame: RGBDFrame) -> None:
        import cv2

        ok_rgb, jpeg = cv2.imencode(
            ".jpg", np.ascontiguousarray(frame.rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, self.config.jpeg_quality]
        )
        depth_mm = np.clip(np.nan_to_num(frame.depth) * 1000.0, 0, 65535).astype(np.uint16)
        ok_depth, png = cv2.imencode(".png", depth_mm)
        result = step.odometry
        descriptors = np.asarray(result.descriptors)
        binary = descriptors.ndim == 2 and descriptors.dtype == np.uint8
        keyframe_id = int(step.keyframe_id or 0)
        pose = self.pipeline.keyframe_poses()[keyframe_id] if self.pipeline is not None else step.pose
        keyframe_type = get_type("fleetslam_msgs/msg/Keyframe")
        msg = keyframe_type(
            header=header(self.config.map_frame, stamp_ns), agent=self.agent, id=keyframe_id,
            pose=message_from_dict("geometry_msgs/msg/Pose", _pose_dict(pose)), camera_info=self.camera_info,
            rgb_format="jpeg" if ok_rgb else "", rgb=jpeg.reshape(-1) if ok_rgb else np.zeros(0, np.uint8),
            depth_format="png16_mm" if ok_depth else "", depth=png.reshape(-1) if ok_depth else np.zeros(0, np.uint8),
            keypoints=np.asarray(result.keypoints, np.float32).reshape(-1),
            points=np.asarray(result.points3d, np.float32).reshape(-1),
            descriptor_length=int(descriptors.shape[1]) if binary else 0,
            descriptors=descriptors.reshape(-1) if binary else np.zeros(0, np.uint8),
            word_ids=np.zeros(0, np.uint32), word_weights=np.zeros(0, np.float32),
        )  # fmt: skip
        self.keyframe_pub.publish(msg)

    def publish_graph(self, stamp_ns: int, *, optimized: bool) -> None:
        if self.pipeline is None:
            return
        poses = self.pipeline.keyframe_poses()
        ids = sorted(poses)
        constraints = []
        for c in self.pipeline.graph.constraints():
            constraints.append(
                {"from_id": int(c.a), "to_id": int(c.b), "from_agent": self.agent, "to_agent": self.agent,
                 "kind": 1 if c.kind == "loop" else 0, "relative": _pose_dict(c.transform),
                 "information": np.asarray(c.information, np.float64).reshape(-1).tolist()}
            )  # fmt: skip
        graph = message_from_dict(
            "fleetslam_msgs/msg/KeyframeGraph",
            {"agent": self.agent, "keyframe_ids": ids, "poses": [_pose_dict(poses[i]) for i in ids],
             "constraints": constraints, "optimized": optimized},
        )  # fmt: skip
        graph.header = header(self.config.map_frame, stamp_ns)
        graph.stamps = [
            message_from_dict(
                "builtin_interfaces/msg/Time", {"sec": int(self.pipeline.keyframe_stamps[i]), "nanosec": 0}
            )
            for i in ids
        ]
        self.graph_pub.publish(graph)
        path = message_from_dict("nav_msgs/msg/Path", {"poses": [{"pose": _pose_dict(poses[i])} for i in ids]})
        path.header = graph.header
        for pose_stamped in path.poses:
            pose_stamped.header = graph.header
        self.path_pub.publish(path)

    # -- services -----------------------------------------------------------------------------------------------
    def on_save_map(self, request: Any) -> Any:
        response = get_type("fleetslam_msgs/srv/SaveMap_Response")
        path = Path(request.path or self.config.map_db)
        if self.pipeline is None or self.pipeline.detector is None:
            return response(success=False, message="nothing to save yet (no camera frames)", path=str(path))
        from fleetslam.slam.database import MapDatabase

        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            path.unlink()
        with MapDatabase(path) as db:
            self.pipeline.detector.memory.save(db)
        return response(success=True, message=f"{len(self.pipeline.keyframe_stamps)} keyframes", path=str(path))

    def on_reset(self, request: Any) -> Any:
        self.pipeline = None
        self.frames = 0
        if self.camera_info is not None:
            self.on_camera_info(self.camera_info)
        return get_type("std_srvs/srv/Trigger_Response")(success=True, message="SLAM reset")

    def on_pause(self, request: Any) -> Any:
        self.paused = bool(request.data)
        return get_type("std_srvs/srv/SetBool_Response")(success=True, message="paused" if self.paused else "running")
