"""The SLAM node of one agent: camera topics in, pose, keyframes and the keyframe graph out.

Subscribes ``camera/rgb/image_raw`` (rgb8/bgr8), ``camera/depth/image_raw`` (32FC1 m or 16UC1 mm) and
``camera/rgb/camera_info``; frames are paired by stamp and fed to :class:`~fleetslam.slam.pipeline.SlamPipeline` by
a worker thread that always takes the newest complete pair: a node that cannot keep up with the camera drops the
stale pairs (counted) instead of falling behind, and the wheel odometry bridges the gap.
With wheel odometry (``odom``, nav_msgs/Odometry of ``base_link`` in ``odom``, and ``tf_static`` giving
``base_link`` → camera), each frame gets the wheel pose at its stamp as prior: the visual odometry predicts
with it and follows it when tracking is lost (a blank wall), so the map does not break.
Publishes ``slam/odom`` (nav_msgs/Odometry, camera pose in ``map``), ``tf`` (``map`` → ``odom``: the correction
that puts the wheel odometry, or without it the visual odometry, on the optimised map), ``path``
(nav_msgs/Path of keyframes), ``liveframes`` (Keyframe without images, every frame), ``keyframes`` (Keyframe
with JPEG colour, PNG depth in mm, keypoints, 3D points, descriptors and the bag-of-words vector: visual word
ids with TF-IDF weights) and ``graph`` (KeyframeGraph: every keyframe pose and constraint; after a loop
closure all poses are re-sent, never points). After every processed frame, ``slam/diagnostics``
(diagnostic_msgs/DiagnosticArray, one status named ``slam``): frames received, processed and dropped,
relocalisations, loop closures, lost and coasting frames, keyframes, and the frame's timings (odometry, steps,
latency from the pair's arrival to its pose). Services: ``slam/save_map`` (SaveMap: map.db), ``slam/reset``
(Trigger), ``slam/trajectory`` (GetTrajectory: every processed frame on its keyframe after a full optimisation,
as an offline run ends), ``slam/pause`` (SetBool), ``graph/full`` (GetGraph) and ``keyframe_summaries/catch_up``
(GetKeyframeSummaries: the summaries of this agent's newest keyframes, for a peer that missed them; a thread asks
the peers for theirs the same way, see :mod:`fleetslam.fusion.summary_catchup`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any

import numpy as np
from pydantic import Field

from fleetslam import topics
from fleetslam._imports import require
from fleetslam.config import ConfigModel
from fleetslam.datasets.base import RGBDFrame
from fleetslam.errors import MessageError, ServiceError, UnsafePathError, worth_logging
from fleetslam.fusion.collaboration import CollaborationConfig, InterAgentLinker, SharedClosure
from fleetslam.fusion.fleet_correction import FleetCorrection
from fleetslam.fusion.graph_exchange import GraphDeltaWriter, GraphUpdate, graph_update_of
from fleetslam.fusion.graph_fetcher import GraphFetcher
from fleetslam.fusion.keyframe_summary import KeyframeSummary, summarize, summary_fields, summary_from_message
from fleetslam.fusion.summary_catchup import MAX_REQUEST_IDS, SummaryStore
from fleetslam.geometry import invert, rotation_angle
from fleetslam.middleware import Node
from fleetslam.msg.conversions import (
    depth_from_image,
    intrinsics_from_camera_info,
    odometry_msg,
    pose_matrix,
    pose_msg,
    pose_msgs,
    rgb_from_image,
    transform_matrix,
    transform_msg,
)
from fleetslam.msg.typesys import get_type, header, message_from_dict, ns_from_stamp, stamp_from_ns
from fleetslam.save_paths import save_path
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.frame_queue import FramePair, FrameQueue
from fleetslam.slam.peer_recognition import PeerMatch, closure_information
from fleetslam.slam.pipeline import SlamPipeline, StepResult
from fleetslam.slam.pose_buffer import PoseBuffer

log = logging.getLogger(__name__)

CATCH_UP_SERVICE = "keyframe_summaries/catch_up"
"""The service that answers a peer's catch-up requests (in the agent's namespace)."""
CATCH_UP_TYPE = "fleetslam_msgs/srv/GetKeyframeSummaries"
TRAJECTORY_TYPE = "fleetslam_msgs/srv/GetTrajectory"
"""``slam/trajectory``: the whole trajectory as a run ends."""


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
    """Unpaired colour (and depth) images kept while waiting for their partner."""
    graph_period: float = Field(default=1.0, ge=0.0)
    """Between loop closures, ``graph`` and ``path`` are published at most this often (s); 0: every keyframe."""
    odom_wait: float = Field(default=0.5, ge=0.0)
    """How long (s) a frame may wait for the wheel odometry to reach its stamp before it is processed without
    the newest wheel pose (odometry and images travel separately)."""
    maps_dir: str = "maps"
    """The only directory the save_map service writes to (created when needed; relative to the working
    directory). Requests name a plain file inside it, never a path."""
    map_db: str = "map.db"
    """Default file name of the save_map service, inside ``maps_dir``."""
    use_wheel_odometry: bool = True
    """Subscribe ``odom`` and ``tf_static`` and give every frame the wheel pose at its stamp as prior."""
    odom_frame: str = "odom"
    """Child frame of the published ``map`` → ``odom`` transform."""
    base_frame: str = "base_link"
    """Robot frame of the wheel odometry; ``tf_static`` must give base_frame → camera_frame."""
    wheels_gone_after: float = Field(default=2.0, gt=0.0)
    """A frame whose wheel pose has not arrived after ``odom_wait`` is skipped (counted as ``late_wheel_frames``) while
    the newest wheel pose is less than this (s) older than the frame: the wheels are late, not gone, and a frame
    without its prior could lose a ground robot in a blank view that the wheels would have carried it through.
    Older than this, the wheels are taken as gone and frames are processed without them. At the start, while a
    publisher of ``odom`` is known but its first pose (or the camera's extrinsic) has not arrived, frames wait as
    long (``wheels_starting``)."""
    odom_tolerance: float = Field(default=0.1, gt=0.0)
    """How far (s) a camera stamp may lie outside the buffered wheel poses and still get a prior."""
    peers: list[str] = Field(default_factory=list)
    """Other agents this agent maps with (the distributed framework's cross-agent subscription): their
    ``keyframe_summaries`` are recognised in this agent's memory, their ``graph_updates`` mirrored, and their
    ``fleet → <peer>/map`` read from their ``tf``, so that this agent places itself in the fleet frame."""
    collaboration: CollaborationConfig = Field(default_factory=CollaborationConfig)
    """Inter-agent place recognition and alignment with the peers."""
    fleet_reference: str = ""
    """The agent whose map frame is the fleet frame; empty: the alphabetically first of this agent and its peers."""
    fleet_frame: str = "fleet"
    """Parent frame of the published ``fleet → <agent>/map`` transform and of ``slam/fleet_pose``."""
    fleet_transform_change: float = Field(default=0.02, gt=0.0)
    """``slam/fleet_transform`` is published again when the placement moved more than this (m; a tenth of it in
    radians): each publication makes the fleet map re-land this agent's whole map."""
    follow_fleet: bool = False
    """Take the fleet back-end's word (``fleetslam fleet backend``, the joint optimisation of every agent's graph)
    for where this agent is in the fleet frame, once it has placed the agent: ``fleet → <agent>/map`` (``tf``,
    ``slam/fleet_transform``) is the back-end's placement (``/fleet/placements``), and ``slam/fleet_pose`` the camera
    moved as the back-end corrected the agent's newest corrected keyframe (``fleet_path``; followed once keyframes of
    the current run are corrected), so the agent sits where the fleet map and its own map (the mapping node's
    ``follow_fleet``) put what it sees. The agent's graph, its
    localisation (``slam/odom``, ``map → odom``) and its map frame stay its own: cut off from the back-end it goes on
    from the last correction, and a back-end that never places it changes nothing (its own placement is used)."""


def _valid_pose(convert: Callable[[], np.ndarray]) -> np.ndarray | None:
    """The converted pose, or None when the message's is not finite or its quaternion is zero."""
    try:
        pose = convert()
    except ValueError:
        return None
    return pose if np.isfinite(pose).all() else None


class SlamNode:
    """Adapter between the middleware and a :class:`SlamPipeline`."""

    def __init__(self, node: Node, config: SlamNodeConfig | None = None) -> None:
        self.node = node
        self.config = config or SlamNodeConfig()
        self.pipeline: SlamPipeline | None = None
        self.camera_info: Any = None
        self.paused = False
        self.frames = 0
        """Frames processed."""
        self.queue = FrameQueue(self.config.max_pending)
        self._first_frame_at: float | None = None
        """When the first frame reached process() (monotonic s): the wheels' start is waited for from there."""
        self._odom_topic = ""
        self.counts = {"relocalisations": 0, "loop_closures": 0, "loops_retracted": 0, "lost_frames": 0,
                       "coasting_frames": 0, "keyframes": 0, "failed_frames": 0, "late_wheel_frames": 0,
                       "stale_frames": 0, "peer_keyframes": 0, "peer_closures": 0, "bad_peer_messages": 0,
                       "graph_requests": 0, "caught_up_summaries": 0, "catch_up_failures": 0}  # fmt: skip
        self._odometry_ms: list[float] = []
        self._latency_ms: list[float] = []
        self._wheel_wait_ms: list[float] = []
        self._lock = threading.Lock()
        """Held while the pipeline is used (the worker's frames, the services)."""
        self._graph_published = 0.0
        self._graph_changed = False
        self.agent = node.namespace.strip("/")
        self.wheel_poses = PoseBuffer(horizon=5.0, tolerance=self.config.odom_tolerance)
        self.base_camera: np.ndarray | None = None
        """``T_base_camera`` from tf_static, once received."""
        self.priors_used = 0
        self.bad_inputs = 0
        """Odometry / tf_static messages ignored because their pose was not finite or not a rotation."""

        def publisher(topic: topics.Topic) -> Any:
            return node.create_publisher(topic.type, topic.name, topic.qos())

        def subscribe(topic: topics.Topic, callback: Callable[[Any], None], depth: int, name: str | None = None) -> Any:
            return node.create_subscription(topic.type, name or topic.name, callback, topic.qos(depth=depth))

        self.odom_pub = publisher(topics.SLAM_ODOM)
        self.path_pub = publisher(topics.PATH)
        self.tf_pub = publisher(topics.TF)
        self.live_pub = publisher(topics.LIVEFRAMES)
        self.keyframe_pub = publisher(topics.KEYFRAMES)
        self.graph_pub = publisher(topics.GRAPH)
        self.graph_updates_pub = publisher(topics.GRAPH_UPDATES)
        self.summary_pub = publisher(topics.KEYFRAME_SUMMARIES)
        self.fleet_pose_pub = publisher(topics.FLEET_POSE)
        self.fleet_transform_pub = publisher(topics.FLEET_TRANSFORM)
        self.diagnostics_pub = publisher(topics.SLAM_DIAGNOSTICS)
        # The frame queue drops stale frames itself (and counts them); the subscriptions only bridge a busy moment.
        pending = self.config.max_pending
        self._image_subscriptions = [
            subscribe(topics.RGB_IMAGE, self.on_rgb, pending),
            subscribe(topics.DEPTH_IMAGE, self.on_depth, pending),
        ]
        subscribe(topics.CAMERA_INFO, self.on_camera_info, 5)
        if self.config.use_wheel_odometry:
            # Deep enough for several seconds of 50 Hz odometry: a starved process must not lose the wheel poses
            # it needs as priors for the frames it is still working through.
            self._odom_topic = subscribe(topics.ODOM, self.on_odom, 500).topic
            subscribe(topics.TF_STATIC, self.on_tf_static, 1)
        self.graph_writer: GraphDeltaWriter[Any] = GraphDeltaWriter()
        """What this agent's ``graph_updates`` have sent."""
        self.linker = InterAgentLinker(self.agent, self.config.collaboration)
        self._recognizer: Any = None
        """The pipeline's peer recognizer (made on the first peer keyframe, again after a reset)."""
        self.peers_in_fleet: dict[str, np.ndarray] = {}
        """``T_fleet_peermap`` of the peers that published theirs."""
        self.fleet_transform: np.ndarray | None = None
        """``T_fleet_map`` of this agent, once placed."""
        self._fleet_published = (0.0, np.zeros((4, 4)))
        self._followed_backend = False
        """Whether the fleet back-end's placement has been followed yet (``follow_fleet``; logged once)."""
        self._constraints: list[Any] = []
        """What the graph messages carry, append-only: the pipeline's constraints and the inter-agent closures this
        agent verified (shared with the peers, which use them too), in the order they came."""
        self._pipeline_constraints = 0
        self._inter_agent: list[tuple[PeerMatch, int]] = []
        """Closures verified with peers, with the peer's run (epoch) they refer to."""
        self._inter_agent_sent = 0
        self._graph_fetcher = GraphFetcher(node.create_client, self._on_peer_full_graph, name=node.fq_name)
        self.fleet_correction = FleetCorrection()
        """The fleet back-end's placement and corrected keyframes of this agent (with ``follow_fleet``)."""
        self._fleet_lock = threading.Lock()
        """Guards ``fleet_correction``: the executor takes the back-end's messages, the worker reads them."""
        if self.config.follow_fleet:
            subscribe(topics.FLEET_PLACEMENTS, partial(self.on_fleet, "placements"), 1)
            subscribe(topics.FLEET_PATH, partial(self.on_fleet, "path"), 1)
        for peer in self.config.peers:
            if peer == self.agent:
                continue
            subscribe(topics.KEYFRAME_SUMMARIES, partial(self.on_peer_summary, peer), 50,
                      topics.KEYFRAME_SUMMARIES.of(peer))  # fmt: skip
            subscribe(topics.GRAPH_UPDATES, partial(self.on_peer_graph_update, peer), 50, topics.GRAPH_UPDATES.of(peer))
            subscribe(topics.FLEET_TRANSFORM, partial(self.on_peer_fleet_transform, peer), 1,
                      topics.FLEET_TRANSFORM.of(peer))  # fmt: skip
            self._graph_fetcher.add(peer)
        node.create_service("fleetslam_msgs/srv/GetGraph", "graph/full", self.on_full_graph)
        self.summary_store = SummaryStore(self.config.collaboration.summary_store,
                                          max_per_call=self.config.collaboration.catch_up_batch)  # fmt: skip
        """This agent's newest keyframe summaries, for peers that missed them (``keyframe_summaries/catch_up``)."""
        node.create_service(CATCH_UP_TYPE, CATCH_UP_SERVICE, self.on_summaries_request)
        self._summary_clients = {peer: node.create_client(CATCH_UP_TYPE, f"/{peer}/{CATCH_UP_SERVICE}")
                                 for peer in self.config.peers if peer != self.agent}  # fmt: skip
        node.create_service("fleetslam_msgs/srv/SaveMap", "slam/save_map", self.on_save_map)
        node.create_service(TRAJECTORY_TYPE, "slam/trajectory", self.on_trajectory)
        node.create_service("std_srvs/srv/Trigger", "slam/reset", self.on_reset)
        node.create_service("std_srvs/srv/SetBool", "slam/pause", self.on_pause)
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._work, name=f"{node.fq_name}/slam", daemon=True)
        self._worker.start()
        self._catch_up_thread: threading.Thread | None = None
        if self._summary_clients and self.config.collaboration.catch_up:
            self._catch_up_thread = threading.Thread(
                target=self._catch_up, name=f"{node.fq_name}/catch-up", daemon=True
            )
            self._catch_up_thread.start()
        node.add_on_destroy(self.close)

    def close(self) -> None:
        """Stop the worker (it finishes the frame it is on)."""
        self._stop.set()
        self.queue.close()
        if self._worker is not threading.current_thread():
            self._worker.join(10.0)
        if self._catch_up_thread is not None and self._catch_up_thread is not threading.current_thread():
            self._catch_up_thread.join(self.config.collaboration.catch_up_timeout + 1.0)

    # -- inputs -------------------------------------------------------------------------------------------------
    def on_camera_info(self, msg: Any) -> None:
        try:
            with self._lock:
                self._start_pipeline(msg)
        except MessageError as err:  # the pipeline starts with the first camera_info that is a camera
            self.bad_inputs += 1
            if worth_logging(self.bad_inputs):
                log.warning("%s: %s (%d bad inputs ignored)", self.agent, err, self.bad_inputs)

    def _start_pipeline(self, msg: Any) -> None:
        # Every camera_info is checked, not only the first: the newest is the one the keyframes carry.
        intrinsics = intrinsics_from_camera_info(msg)
        if self.pipeline is None:
            self.pipeline = SlamPipeline(self.config.slam, intrinsics=intrinsics, base_camera=self.base_camera)
            log.info("%s: SLAM started with fx=%.1f at %dx%d", self.agent, intrinsics.fx, msg.width, msg.height)
        self.camera_info = msg

    def on_odom(self, msg: Any) -> None:
        pose = _valid_pose(lambda: pose_matrix(msg.pose.pose))
        if pose is None:
            self.bad_inputs += 1
            if worth_logging(self.bad_inputs):
                log.warning("%s: odom pose is not finite or not a rotation (%d such messages ignored)",
                            self.agent, self.bad_inputs)  # fmt: skip
            return
        self.wheel_poses.add(ns_from_stamp(msg.header.stamp) / 1e9, pose)

    def on_tf_static(self, msg: Any) -> None:
        for transform in msg.transforms:
            parent = transform.header.frame_id.split("/")[-1]
            child = transform.child_frame_id.split("/")[-1]
            if parent == self.config.base_frame and child == self.config.camera_frame:
                extrinsic = _valid_pose(partial(transform_matrix, transform.transform))
                if extrinsic is not None:
                    self.base_camera = extrinsic
                    with self._lock:
                        if self.pipeline is not None:
                            self.pipeline.set_mounting(extrinsic)
                else:
                    self.bad_inputs += 1
                    log.warning("%s: tf_static %s -> %s is not a valid transform; ignored", self.agent, parent, child)

    def wheel_prior(self, stamp: float) -> np.ndarray | None:
        """``T_odom_camera`` at ``stamp`` from the wheel odometry, when both it and the extrinsic are known."""
        if self.base_camera is None:
            return None
        base = self.wheel_poses.at(stamp)
        return None if base is None else base @ self.base_camera

    def wheels_behind(self, stamp: float) -> bool:
        """The wheel odometry is running but has not reached ``stamp`` (see ``wheels_gone_after``)."""
        if not self.config.use_wheel_odometry or self.base_camera is None:
            return False
        newest = self.wheel_poses.newest_stamp
        return newest is not None and 0.0 < stamp - newest < self.config.wheels_gone_after

    def wheels_starting(self) -> bool:
        """Wheel odometry is published (the graph knows a publisher of this agent's ``odom``) but neither its first
        pose nor the camera's extrinsic has arrived, within ``wheels_gone_after`` of the node's first frame: frames
        wait for it. Tracked without the wheels, the first frame starts the map in a frame the next one (with them)
        cannot predict from: a demo's robot lost it and kept its first pose 39 cm off. A camera without wheels
        (no publisher) does not wait."""
        if not self.config.use_wheel_odometry:
            return False
        if self.base_camera is not None and self.wheel_poses.newest_stamp is not None:
            return False
        now = time.monotonic()
        if self._first_frame_at is None:
            self._first_frame_at = now
        if now - self._first_frame_at >= self.config.wheels_gone_after:
            return False
        return bool(self.node.context.graph.publishers_info(self._odom_topic))

    def before_wheels(self, stamp: float) -> bool:
        """The wheel odometry runs but holds no pose as old as ``stamp``: a frame from before the wheels' first pose,
        or one that arrives later than the buffer reaches back (a late sample from the sensor's start)."""
        if not self.config.use_wheel_odometry or self.base_camera is None:
            return False
        oldest = self.wheel_poses.oldest_stamp
        return oldest is not None and stamp < oldest - self.wheel_poses.tolerance

    def on_rgb(self, msg: Any) -> None:
        self.queue.put_rgb(ns_from_stamp(msg.header.stamp), msg)

    def on_depth(self, msg: Any) -> None:
        self.queue.put_depth(ns_from_stamp(msg.header.stamp), msg)

    def _bad_peer_message(self, peer: str, what: str, err: Exception | str) -> None:
        self.counts["bad_peer_messages"] += 1
        n = self.counts["bad_peer_messages"]
        if worth_logging(n):
            log.warning("%s: %s from %s ignored (%d so far): %s", self.agent, what, peer, n, err)

    def on_peer_summary(self, peer: str, msg: Any) -> None:
        """A peer's keyframe: queued for recognition in this agent's memory (the worker does it between frames)."""
        summary = self._summary_of(peer, msg)
        if summary is not None:
            self.linker.queue_summary(summary)

    def _summary_of(self, peer: str, msg: Any) -> KeyframeSummary | None:
        """A peer's ``KeyframeSummary`` message checked and converted; None (counted) when it is malformed."""
        if str(msg.agent) != peer:
            self._bad_peer_message(peer, "keyframe summary", f"it names agent {str(msg.agent)!r}")
            return None
        pose = _valid_pose(lambda: pose_matrix(msg.pose))
        try:
            if pose is None:
                raise MessageError("pose is not finite or not a rotation")
            return summary_from_message(msg, pose, ns_from_stamp(msg.header.stamp))
        except (MessageError, ValueError, TypeError) as err:
            self._bad_peer_message(peer, "keyframe summary", err)
            return None

    def on_peer_graph_update(self, peer: str, msg: Any) -> None:
        """A peer's graph update, applied to its mirror; a gap asks the peer for its whole graph."""
        if str(msg.agent) != peer:
            self._bad_peer_message(peer, "graph update", f"it names agent {str(msg.agent)!r}")
            return
        try:
            update = graph_update_of(msg)
        except (MessageError, ValueError, TypeError) as err:
            self._bad_peer_message(peer, "graph update", err)
            return
        if not self.linker.apply_graph(peer, update):
            self._request_graph(peer)
        self._receive_shared(peer, update)

    def _receive_shared(self, peer: str, update: GraphUpdate[Any]) -> None:
        """The closures ``peer`` verified with this agent's current run, from its graph, to the linker."""
        for c in update.constraints:
            if (int(c.kind) == 2 and c.from_agent == peer and c.to_agent == self.agent
                    and int(c.to_epoch) == self.graph_writer.epoch):  # fmt: skip
                relative = _valid_pose(partial(pose_matrix, c.relative))
                if relative is None:
                    self._bad_peer_message(peer, "inter-agent constraint", "relative pose not finite or not a rotation")
                    continue
                self.linker.receive_shared(SharedClosure(peer, int(c.from_id), int(c.to_id), relative, update.epoch))

    def _request_graph(self, peer: str) -> None:
        """Ask ``peer`` for its whole graph (off the middleware's thread, one request per peer at a time)."""
        if self._graph_fetcher.request(peer):
            self.counts["graph_requests"] += 1

    def _on_peer_full_graph(self, peer: str, graph: Any) -> None:
        if str(graph.agent) == peer:
            update = graph_update_of(graph)
            self.linker.apply_graph(peer, update)
            self._receive_shared(peer, update)

    def on_fleet(self, kind: str, msg: Any) -> None:
        """The fleet back-end's placements (``tf2_msgs/TFMessage``) or this agent's corrected keyframes
        (``nav_msgs/Path``), with ``follow_fleet``; a malformed one is counted and changes nothing."""
        try:
            with self._fleet_lock:
                if kind == "placements":
                    self.fleet_correction.take_placements(msg, f"{self.agent}/{self.config.map_frame}")
                else:
                    self.fleet_correction.take_path(msg)
        except (ValueError, TypeError, AttributeError) as err:
            self._bad_peer_message("the fleet back-end", f"fleet {kind}", err)

    def _fleet_placement(self) -> tuple[np.ndarray, np.ndarray] | None:
        """With ``follow_fleet``, once the back-end placed this agent and corrected keyframes of its current run (a
        placement or path left from a run before a reset matches none): its ``T_fleet_map``, and what takes a pose
        of this agent's map frame into the fleet frame as the back-end corrected the newest corrected keyframe."""
        if not self.config.follow_fleet or self.pipeline is None:
            return None
        with self._fleet_lock:
            placement = self.fleet_correction.T_fleet_map
            if placement is None or self.fleet_correction.frame_id != self.config.fleet_frame:
                return None
            chain = self.fleet_correction.chain(self.pipeline.keyframe_poses(), self.pipeline.keyframe_stamps)
        return None if chain is None else (placement, chain)

    def on_peer_fleet_transform(self, peer: str, msg: Any) -> None:
        """A peer's ``fleet → <peer>/map`` (latched ``slam/fleet_transform``), once it is placed in the fleet frame."""
        if msg.header.frame_id != self.config.fleet_frame or msg.child_frame_id != f"{peer}/{self.config.map_frame}":
            self._bad_peer_message(peer, "fleet transform", f"{msg.header.frame_id} -> {msg.child_frame_id}")
            return
        pose = _valid_pose(partial(transform_matrix, msg.transform))
        if pose is None:
            self._bad_peer_message(peer, "fleet transform", "not finite or not a rotation")
        else:
            self.peers_in_fleet[peer] = pose

    # -- work ---------------------------------------------------------------------------------------------------
    def _work(self) -> None:
        """The worker: the newest pair, processed; a frame that fails is counted and logged, never fatal."""
        while not self._stop.is_set():
            pair = self.queue.take(timeout_s=0.5)
            if pair is None:
                if self.linker.queue:  # no camera frames (a robot standing still): peers' keyframes still count
                    with self._lock:
                        self.collaborate(self.node.now_ns(), None)
                continue
            waited = time.monotonic()
            self._wait_for_wheels(pair.stamp_ns / 1e9)
            self._wheel_wait_ms.append((time.monotonic() - waited) * 1e3)
            del self._wheel_wait_ms[:-1000]
            try:
                with self._lock:
                    self.process(pair)
            except Exception as err:  # one bad frame (malformed image, numeric failure) must not stop SLAM
                self.counts["failed_frames"] += 1
                if worth_logging(self.counts["failed_frames"]):
                    log.warning("%s: frame at %d ns failed (%d so far): %s", self.agent, pair.stamp_ns,
                                self.counts["failed_frames"], err)  # fmt: skip

    def _wait_for_wheels(self, stamp: float) -> None:
        """Give the wheel odometry up to ``odom_wait`` to reach the frame's stamp (it may travel behind it)."""
        if not self.config.use_wheel_odometry or self.base_camera is None:
            return
        deadline = time.monotonic() + self.config.odom_wait
        while time.monotonic() < deadline and not self._stop.is_set():
            newest = self.wheel_poses.newest_stamp
            if newest is None or newest >= stamp:
                return
            time.sleep(0.005)

    def process(self, pair: FramePair) -> StepResult | None:
        """Track one frame and publish what it produced (the caller holds the pipeline lock)."""
        if self.pipeline is None or self.paused:
            return None
        stamp_ns = pair.stamp_ns
        prior = self.wheel_prior(stamp_ns / 1e9)
        if prior is None and (self.wheels_behind(stamp_ns / 1e9) or self.wheels_starting()):
            self.counts["late_wheel_frames"] += 1
            return None
        if prior is None and self.before_wheels(stamp_ns / 1e9):
            # Tracked without the wheels, it would start the map in a frame the next frame (with them) cannot
            # reach: a demo's robot that had driven 4.5 m since kept that first pose 4.5 m off in its trajectory.
            self.counts["stale_frames"] += 1
            return None
        rgb, depth = rgb_from_image(pair.rgb), depth_from_image(pair.depth)
        if depth.shape != rgb.shape[:2]:
            raise ValueError(f"colour {rgb.shape[:2]} and depth {depth.shape} images differ in size")
        self.priors_used += prior is not None
        frame = RGBDFrame(self.frames, stamp_ns / 1e9, rgb, depth, prior=prior)
        self.frames += 1
        t0 = time.perf_counter()
        # The pose goes out as soon as it is tracked; local mapping and the graph follow (ORB-SLAM's order).
        tracked = self.pipeline.track(frame)
        self.publish_pose(stamp_ns, tracked.pose)
        step = self.pipeline.finish(tracked)
        step_ms = (time.perf_counter() - t0) * 1e3
        self.publish_map_to_odom(stamp_ns, step, prior)
        if step.keyframe_id is not None:
            self.publish_keyframe(stamp_ns, step, frame)
            self._graph_changed = True
        if self._graph_changed:
            self.publish_graph(stamp_ns, optimized=step.loop_closed)
        self.collaborate(stamp_ns, step)
        self._count(step)
        self.publish_diagnostics(stamp_ns, step, step_ms, (time.monotonic() - pair.completed) * 1e3)
        return step

    def collaborate(self, stamp_ns: int, step: StepResult | None) -> None:
        """Recognise queued peer keyframes within the budget, and publish this agent's place in the fleet frame
        once its closures with a placed peer agree (the reference agent's map frame is the fleet frame); with this
        frame's ``step``, also its camera pose in the fleet frame."""
        if self.pipeline is None:
            return
        if (self.linker.queue or self.linker.shared) and self.pipeline.loop_closure:
            if self._recognizer is None:
                self._recognizer = self.pipeline.peer_recognizer(
                    max_verifications=self.config.collaboration.max_verifications,
                    min_off_plane=self.config.collaboration.min_off_plane_inliers,
                    quality=self.config.collaboration.closure_quality(),
                )
            before = sum(state.recognised for state in self.linker.peers.values())
            matches = self.linker.step(self._recognizer, self.pipeline.keyframe_poses())
            self.counts["peer_keyframes"] += sum(state.recognised for state in self.linker.peers.values()) - before
            self.counts["peer_closures"] += len(matches)
            if matches:
                self._inter_agent += [(m, self.linker.peer(m.peer_agent).epoch) for m in matches]
                self._graph_changed = True
                if step is None:  # idle: no frame will publish the graph soon
                    self.publish_graph(stamp_ns, optimized=False)
        if not self.config.peers and not self.config.fleet_reference and not self.config.follow_fleet:
            return  # alone: no fleet to be placed in
        reference = self.config.fleet_reference or min([self.agent, *self.config.peers])
        transform = self.linker.fleet_transform(reference, self.peers_in_fleet)
        to_fleet = transform
        backend = self._fleet_placement()
        if backend is not None:
            if not self._followed_backend:
                log.info("%s: placed in the fleet frame by the fleet back-end", self.agent)
            self._followed_backend = True
            transform, to_fleet = backend
        if transform is None or to_fleet is None:
            return
        if self.fleet_transform is None and backend is None:
            log.info("%s: placed in the fleet frame (reference %s)", self.agent, reference)
        self.fleet_transform = transform
        if step is not None:
            fleet_pose = get_type("geometry_msgs/msg/PoseStamped")(
                header=header(self.config.fleet_frame, stamp_ns), pose=pose_msg(to_fleet @ step.pose)
            )
            self.fleet_pose_pub.publish(fleet_pose)
        # The placement is refined with every closure by millimetres: it goes out when it moved by more than
        # ``fleet_transform_change`` (the fleet map re-lands the agent's whole map on each), on tf once a second.
        now = time.monotonic()
        last, sent = self._fleet_published
        child = f"{self.agent}/{self.config.map_frame}"
        moved = invert(sent) @ transform if np.isfinite(sent).all() and sent[3, 3] == 1.0 else None
        change = self.config.fleet_transform_change
        if moved is None or np.linalg.norm(moved[:3, 3]) > change or rotation_angle(moved) > change / 10.0:
            tf = transform_msg(transform, self.config.fleet_frame, child, stamp_ns)
            self.fleet_transform_pub.publish(tf.transforms[0])
            self._fleet_published = (last, transform)
            sent = transform
        if now - last >= 1.0:
            self._fleet_published = (now, sent)
            self.tf_pub.publish(transform_msg(sent, self.config.fleet_frame, child, stamp_ns))

    def _count(self, step: StepResult) -> None:
        odometry = step.odometry
        self.counts["keyframes"] += step.keyframe_id is not None
        self.counts["loop_closures"] += step.loop_closed
        if self.pipeline is not None:
            self.counts["loops_retracted"] = self.pipeline.loops_retracted
        self.counts["relocalisations"] += step.relocalized
        self.counts["lost_frames"] += bool(odometry.lost)
        self.counts["coasting_frames"] += bool(odometry.coasting)

    def publish_diagnostics(self, stamp_ns: int, step: StepResult, step_ms: float, latency_ms: float) -> None:
        """``slam/diagnostics``: counts since start and this frame's timings (see the module docstring)."""
        timings = dict(step.odometry.timings)
        self._odometry_ms.append(float(timings.get("total", 0.0)))
        self._latency_ms.append(latency_ms)
        del self._odometry_ms[:-1000], self._latency_ms[:-1000]  # the means are over the last 1000 frames
        values = {
            "frames_received": self.queue.received,
            "frames_processed": self.frames,
            "frames_dropped": self.queue.dropped,
            "frames_pending": self.queue.pending,
            # Images the subscriptions overwrote before the node's callbacks saw them (a starved process).
            "images_overwritten": sum(sub.queue_overflows for sub in self._image_subscriptions),
            **self.counts,
            **peer_closure_counts(self.linker),
            "odometry_ms": round(float(timings.get("total", 0.0)), 2),
            "odometry_ms_mean": round(float(np.mean(self._odometry_ms)), 2),
            "step_ms": round(step_ms, 2),
            "latency_ms": round(latency_ms, 2),
            "latency_ms_mean": round(float(np.mean(self._latency_ms)), 2),
            # How long frames waited for the wheel odometry to reach their stamp (part of the latency).
            "wheel_wait_ms_mean": round(float(np.mean(self._wheel_wait_ms)), 2) if self._wheel_wait_ms else 0.0,
            **{f"{name}_ms": round(float(ms), 2) for name, ms in timings.items() if name != "total"},
        }
        odometry = step.odometry
        status_type = get_type("diagnostic_msgs/msg/DiagnosticStatus")
        level = status_type.WARN if odometry.lost or odometry.coasting else status_type.OK
        state = "lost" if odometry.lost else "coasting on wheel odometry" if level else "tracking"
        status = status_type(
            level=level, name="slam", hardware_id=self.agent,
            message=f"{state}; {self.frames} frames processed, {self.queue.dropped} dropped",
            values=[get_type("diagnostic_msgs/msg/KeyValue")(key=k, value=str(v)) for k, v in values.items()],
        )  # fmt: skip
        array = get_type("diagnostic_msgs/msg/DiagnosticArray")(header=header(self.config.map_frame, stamp_ns),
                                                                status=[status])  # fmt: skip
        self.diagnostics_pub.publish(array)

    def publish_pose(self, stamp_ns: int, pose: np.ndarray) -> None:
        odom = odometry_msg(
            pose_msg(pose), frame_id=self.config.map_frame, child_frame_id=self.config.camera_frame, stamp_ns=stamp_ns
        )
        self.odom_pub.publish(odom)
        live = message_from_dict("fleetslam_msgs/msg/Keyframe", {"agent": self.agent, "id": self.frames})
        live.header, live.pose = odom.header, odom.pose.pose
        self.live_pub.publish(live)

    def publish_map_to_odom(self, stamp_ns: int, step: StepResult, prior: np.ndarray | None) -> None:
        """``T_map_odom``: the optimised camera pose composed with the inverse of the odometry's camera pose
        (the wheel odometry's when there is one, so that map → odom → base_link is one tf tree)."""
        odometry_camera = prior if prior is not None else step.odometry.pose
        self.tf_pub.publish(
            transform_msg(step.pose @ invert(odometry_camera), self.config.map_frame, self.config.odom_frame, stamp_ns)
        )

    def bag_of_words(self, keyframe_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Word ids and TF-IDF weights of a keyframe's location (empty without the loop-closure side)."""
        if self.pipeline is None:
            return np.zeros(0, np.uint32), np.zeros(0, np.float32)
        words, weights = self.pipeline.bag_of_words(keyframe_id)
        return words.astype(np.uint32), weights.astype(np.float32)

    def publish_keyframe(self, stamp_ns: int, step: StepResult, frame: RGBDFrame) -> None:
        cv2 = require("cv2", "slam")
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
        word_ids, word_weights = self.bag_of_words(keyframe_id)
        keyframe_type = get_type("fleetslam_msgs/msg/Keyframe")
        msg = keyframe_type(
            header=header(self.config.map_frame, stamp_ns), agent=self.agent, id=keyframe_id,
            pose=pose_msg(pose), camera_info=self.camera_info,
            rgb_format="jpeg" if ok_rgb else "", rgb=jpeg.reshape(-1) if ok_rgb else np.zeros(0, np.uint8),
            depth_format="png16_mm" if ok_depth else "", depth=png.reshape(-1) if ok_depth else np.zeros(0, np.uint8),
            keypoints=np.asarray(result.keypoints, np.float32).reshape(-1),
            points=np.asarray(result.points3d, np.float32).reshape(-1),
            descriptor_length=int(descriptors.shape[1]) if binary else 0,
            descriptors=descriptors.reshape(-1) if binary else np.zeros(0, np.uint8),
            word_ids=word_ids, word_weights=word_weights,
        )  # fmt: skip
        self.keyframe_pub.publish(msg)
        if self.pipeline is not None and self.camera_info is not None and binary:
            summary = summarize(
                self.agent, keyframe_id, stamp_ns, pose, self.pipeline.intrinsics, result.keypoints, result.points3d,
                descriptors, max_features=self.config.collaboration.summary_features, epoch=self.graph_writer.epoch,
            )  # fmt: skip
            fields = summary_fields(summary)
            summary_msg = message_from_dict("fleetslam_msgs/msg/KeyframeSummary", fields)
            summary_msg.header, summary_msg.pose = msg.header, msg.pose
            self.summary_pub.publish(summary_msg)
            self.summary_store.add(summary)

    def publish_graph(self, stamp_ns: int, *, optimized: bool) -> None:
        """The whole keyframe graph on ``graph``, what changed on ``graph_updates`` and the keyframe path on
        ``path``: after a loop closure (every pose moved), else at most every ``graph_period`` (new keyframes reach
        their readers on ``keyframes`` at once; a graph of hundreds of keyframes is not worth resending three times
        a second)."""
        if self.pipeline is None:
            return
        now = time.monotonic()
        if not optimized and now - self._graph_published < self.config.graph_period:
            return  # published by a later frame (the change is remembered)
        self._graph_published = now
        self._graph_changed = False
        poses = self.pipeline.keyframe_poses()
        stamps = self.pipeline.keyframe_stamps
        constraints, rebuilt = self._graph_constraints()
        update = self.graph_writer.update(poses, stamps, constraints, full=rebuilt)
        # The whole graph grows with the run (hundreds of kB): built only while someone reads it.
        if self.graph_pub.matched_subscriptions:
            self.graph_pub.publish(
                self._graph_message(
                    stamp_ns,
                    poses,
                    stamps,
                    constraints,
                    sequence=self.graph_writer.sequence,
                    full=True,
                    optimized=optimized,
                )
            )
        if update is not None:
            self.graph_updates_pub.publish(
                self._graph_message(
                    stamp_ns,
                    update.poses,
                    update.stamps,
                    update.constraints,
                    sequence=update.sequence,
                    full=update.full,
                    optimized=optimized,
                )
            )
        if self.path_pub.matched_subscriptions:
            stamp = header(self.config.map_frame, stamp_ns)
            pose_stamped = get_type("geometry_msgs/msg/PoseStamped")
            stamped = [pose_stamped(header=stamp, pose=p) for p in pose_msgs([poses[i] for i in sorted(poses)])]
            self.path_pub.publish(get_type("nav_msgs/msg/Path")(header=stamp, poses=stamped))

    def _graph_constraints(self) -> tuple[list[Any], bool]:
        """The constraints the graph carries (append-only, see ``_constraints``), and whether the list was rebuilt
        (the back-end retracted a loop: readers get the whole graph)."""
        assert self.pipeline is not None
        pipeline = self.pipeline.constraints()
        rebuilt = len(pipeline) < self._pipeline_constraints
        if rebuilt:
            self._constraints, self._pipeline_constraints, self._inter_agent_sent = [], 0, 0
        self._constraints += pipeline[self._pipeline_constraints :]
        self._pipeline_constraints = len(pipeline)
        self._constraints += self._inter_agent[self._inter_agent_sent :]
        self._inter_agent_sent = len(self._inter_agent)
        return self._constraints, rebuilt

    def _graph_message(
        self, stamp_ns: int, poses: Mapping[int, np.ndarray], stamps: Mapping[int, float], constraints: Sequence[Any],
        *, sequence: int, full: bool, optimized: bool,
    ) -> Any:  # fmt: skip
        """A ``KeyframeGraph`` of these keyframes and constraints (all of them, or a delta)."""
        ids = sorted(poses)
        constraint_type = get_type("fleetslam_msgs/msg/GraphConstraint")

        def constraint(c: Any, relative: Any) -> Any:
            if isinstance(c, tuple):  # (PeerMatch, the peer's epoch): a closure shared with the peer
                match, epoch = c
                return constraint_type(
                    from_id=int(match.own_id), to_id=int(match.peer_id), from_agent=self.agent,
                    to_agent=match.peer_agent, kind=2, relative=relative, information=closure_information(match),
                    to_epoch=int(epoch),
                )  # fmt: skip
            return constraint_type(
                from_id=int(c.a), to_id=int(c.b), from_agent=self.agent, to_agent=self.agent,
                kind=1 if c.kind == "loop" else 0, relative=relative,
                information=np.asarray(c.information, np.float64).reshape(36), to_epoch=0,
            )  # fmt: skip

        relative_msgs = pose_msgs([c[0].relative if isinstance(c, tuple) else c.transform for c in constraints])
        return get_type("fleetslam_msgs/msg/KeyframeGraph")(
            header=header(self.config.map_frame, stamp_ns), agent=self.agent, keyframe_ids=np.asarray(ids, np.uint32),
            poses=pose_msgs([poses[i] for i in ids]), stamps=[stamp_from_ns(round(stamps[i] * 1e9)) for i in ids],
            constraints=[constraint(c, r) for c, r in zip(constraints, relative_msgs, strict=True)],
            optimized=optimized, sequence=sequence, full=full, epoch=self.graph_writer.epoch,
        )  # fmt: skip

    def on_full_graph(self, request: Any) -> Any:
        """``graph/full``: the whole graph as of the last ``graph_updates`` message (for a peer that missed one)."""
        response = get_type("fleetslam_msgs/srv/GetGraph_Response")
        with self._lock:
            if self.pipeline is None:
                full: GraphUpdate[Any] = GraphUpdate(max(self.graph_writer.sequence, 1), True, {}, {}, [])
            else:
                full = self.graph_writer.full(
                    self.pipeline.keyframe_poses(), self.pipeline.keyframe_stamps, self._constraints
                )
            graph = self._graph_message(self.node.now_ns(), full.poses, full.stamps, full.constraints,
                                        sequence=max(full.sequence, 1), full=True, optimized=False)  # fmt: skip
        return response(graph=graph)

    def on_summaries_request(self, request: Any) -> Any:
        """``keyframe_summaries/catch_up``: the summaries of the ids asked that this agent keeps (a few per call),
        and the ids it does not keep. Never waits for the SLAM thread (the store has its own lock)."""
        store, epoch = self.summary_store, self.graph_writer.epoch
        found, unknown = store.lookup(np.asarray(request.ids, dtype=np.int64).reshape(-1)[:MAX_REQUEST_IDS].tolist())
        messages = []
        for summary in found:
            msg = message_from_dict("fleetslam_msgs/msg/KeyframeSummary", summary_fields(summary))
            msg.header, msg.pose = header(self.config.map_frame, summary.stamp_ns), pose_msg(summary.pose)
            messages.append(msg)
        return get_type(f"{CATCH_UP_TYPE}_Response")(
            agent=self.agent, epoch=epoch, summaries=messages, unknown=np.asarray(unknown, dtype=np.uint32)
        )

    def _catch_up(self) -> None:
        """The catch-up thread: asks each peer for the summaries of keyframes its graph named but whose summaries
        never came (see :meth:`InterAgentLinker.catch_up_request`), one request at a time, each with a timeout (a
        dead link holds this thread, never the SLAM one, for at most ``catch_up_timeout``)."""
        config = self.config.collaboration
        request_type = get_type(f"{CATCH_UP_TYPE}_Request")
        while not self._stop.wait(min(0.25, config.catch_up_period)):
            for peer, client in self._summary_clients.items():
                linker = self.linker  # replaced by a reset
                _, ids = linker.catch_up_request(peer, time.monotonic())
                if not ids or self._stop.is_set():
                    continue
                try:
                    response = client.call(
                        request_type(ids=np.asarray(ids, np.uint32)), timeout=config.catch_up_timeout
                    )
                    if str(response.agent) != peer:
                        raise MessageError(f"the answer names agent {str(response.agent)!r}")
                    summaries = [self._summary_of(peer, msg) for msg in response.summaries[: 2 * len(ids)]]
                    unknown = np.asarray(response.unknown, dtype=np.int64).reshape(-1)[: len(ids)].tolist()
                except (ServiceError, MessageError, ValueError, TypeError) as err:
                    linker.catch_up_failed(peer, time.monotonic())
                    self.counts["catch_up_failures"] += 1
                    n = self.counts["catch_up_failures"]
                    if worth_logging(n):
                        log.info("%s: no keyframe summaries from %s (%d failed requests): %s", self.agent, peer, n, err)
                    continue
                good = [s for s in summaries if s is not None]
                self.counts["caught_up_summaries"] += linker.catch_up_answered(peer, good, unknown, time.monotonic())
                if len(good) < len(summaries):  # malformed ones: the peer is asked again, later
                    linker.catch_up_failed(peer, time.monotonic())
                    self.counts["catch_up_failures"] += 1

    # -- services -----------------------------------------------------------------------------------------------
    def on_save_map(self, request: Any) -> Any:
        with self._lock:
            return self._save_map(request)

    def _save_map(self, request: Any) -> Any:
        response = get_type("fleetslam_msgs/srv/SaveMap_Response")
        name = request.path or self.config.map_db
        try:
            path = save_path(self.config.maps_dir, name, suffixes=(".db",))
        except (UnsafePathError, OSError) as err:
            return response(success=False, message=str(err), path=name)
        if self.pipeline is None or not self.pipeline.save_map(path):
            return response(success=False, message="nothing to save yet (no camera frames)", path=str(path))
        return response(success=True, message=f"{len(self.pipeline.keyframe_stamps)} keyframes", path=str(path))

    def on_trajectory(self, request: Any) -> Any:
        """Every processed frame on its keyframe's pose after a full optimisation (what an offline run returns)."""
        with self._lock:
            if self.pipeline is None or not self.pipeline.keyframe_stamps:
                refusal = {"success": False, "message": "no trajectory yet (no camera frames)"}
                return message_from_dict(TRAJECTORY_TYPE + "_Response", refusal)
            result = self.pipeline.result()
        trajectory = result.trajectory
        pose_stamped = get_type("geometry_msgs/msg/PoseStamped")
        poses = [
            pose_stamped(header=header(self.config.map_frame, round(float(t) * 1e9)), pose=p)
            for t, p in zip(trajectory.stamps, pose_msgs(list(trajectory.poses)), strict=True)
        ]
        path = get_type("nav_msgs/msg/Path")(header=header(self.config.map_frame, time.time_ns()), poses=poses)
        keyframes = len(result.keyframes)
        return get_type(TRAJECTORY_TYPE + "_Response")(
            success=True, message=f"{len(poses)} frames on {keyframes} keyframes", trajectory=path, keyframes=keyframes
        )

    def on_reset(self, request: Any) -> Any:
        with self._lock:
            self.pipeline = None
            self.frames = 0
            # A new map frame: a new graph epoch (peers drop what they had of this agent), no closures, not placed.
            self.graph_writer = GraphDeltaWriter()
            self.summary_store = SummaryStore(self.config.collaboration.summary_store,
                                              max_per_call=self.config.collaboration.catch_up_batch)  # fmt: skip
            self._constraints, self._pipeline_constraints, self._inter_agent, self._inter_agent_sent = [], 0, [], 0
            self.linker = InterAgentLinker(self.agent, self.config.collaboration)
            self._recognizer = None
            self.fleet_transform = None
            self._fleet_published = (0.0, np.zeros((4, 4)))
            with self._fleet_lock:  # the back-end's word was on the old map frame
                self.fleet_correction, self._followed_backend = FleetCorrection(), False
            if self.camera_info is not None:
                self._start_pipeline(self.camera_info)
        return get_type("std_srvs/srv/Trigger_Response")(success=True, message="SLAM reset")

    def on_pause(self, request: Any) -> Any:
        self.paused = bool(request.data)
        return get_type("std_srvs/srv/SetBool_Response")(success=True, message="paused" if self.paused else "running")


def peer_closure_counts(linker: InterAgentLinker) -> dict[str, int]:
    """Per peer, for ``slam/diagnostics``: ``peer_closures_accepted.<peer>``, the closures its map frame is placed by
    (the largest consistent set, once accepted), and ``peer_closures_rejected.<peer>``, those held outside that set
    (inconsistent with it: repeated structure, a wrong match). Over the closures held (the latest 64 per peer)."""
    counts = {}
    for peer, state in sorted(linker.peers.items()):
        believed = len(state.decision.inliers) if state.decision is not None else 0
        placed = state.decision is not None and state.decision.alignment is not None
        counts[f"peer_closures_accepted.{peer}"] = believed if placed else 0
        counts[f"peer_closures_rejected.{peer}"] = len(state.closures.closures) - believed
    return counts
