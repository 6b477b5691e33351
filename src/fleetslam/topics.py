"""Topic contracts: each topic's name, message type and QoS, declared once and used by publishers and subscribers.

A contract's ``name`` is relative (resolved in the node's namespace, ``/<agent>/...``) or absolute (``/...``, a
fleet-level topic). Its QoS is what the publisher offers; a subscriber takes :meth:`Topic.qos` with its own queue
depth and gets the same durability, so a late subscriber of a latched (transient-local) topic receives the last
message. ``docs/architecture.md``'s topic tables are rendered from :data:`AGENT_TOPICS` and :data:`FLEET_TOPICS`
by :func:`markdown_table` (``tests/test_topics.py`` fails when they differ; run it with
``FLEETSLAM_UPDATE_DOCS=1`` to rewrite them).

Importing this module does not import the middleware (``Topic.qos`` does, on first use).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from fleetslam.middleware import QoSProfile

__all__ = [
    "AGENT_TOPICS",
    "CAMERA_INFO",
    "CLOCK",
    "CMD_VEL",
    "CMD_VEL_STAMPED",
    "DEPTH_CAMERA_INFO",
    "DEPTH_IMAGE",
    "FINDINGS",
    "FLEET_BACKEND_DIAGNOSTICS",
    "FLEET_MAP_OCCUPIED",
    "FLEET_MAP_OCTOMAP",
    "FLEET_PATH",
    "FLEET_PLACEMENTS",
    "FLEET_POSE",
    "FLEET_TOPICS",
    "FLEET_TRANSFORM",
    "GRAPH",
    "GRAPH_UPDATES",
    "GROUND_TRUTH_ODOM",
    "JOINT_STATES",
    "KEYFRAMES",
    "KEYFRAME_SUMMARIES",
    "LIVEFRAMES",
    "MAP_GRID",
    "MAP_MARKERS",
    "MAP_OCCUPIED",
    "MAP_OCTOMAP",
    "ODOM",
    "PATH",
    "RGB_IMAGE",
    "SLAM_DIAGNOSTICS",
    "SLAM_ODOM",
    "STATISTICS",
    "TF",
    "TF_STATIC",
    "Topic",
    "markdown_table",
]


@dataclass(frozen=True)
class Topic:
    """One topic's contract."""

    name: str
    """Relative to the node's namespace, or absolute (``/statistics``)."""
    type: str
    """ROS 2 message type, ``pkg/msg/Name``."""
    depth: int
    """The publisher's KEEP_LAST depth (for a latched topic: how many messages a late subscriber gets)."""
    durability: Literal["volatile", "transient_local"] = "volatile"
    """``transient_local``: latched, a late subscriber gets the last ``depth`` messages."""
    reliability: Literal["reliable", "best_effort"] = "reliable"
    """What the publisher offers; a subscriber may ask for best effort (never for more)."""
    content: str = ""
    """What the messages hold, for the docs."""
    flow: str = ""
    """Who publishes → who subscribes, for the docs."""

    def qos(self, *, depth: int | None = None, best_effort: bool = False) -> QoSProfile:
        """The QoS to publish or subscribe with: the contract's, with a subscriber's own queue ``depth`` and,
        where it prefers dropping to queueing (a preview), ``best_effort``."""
        from fleetslam.middleware import QoSProfile

        return QoSProfile(
            reliability="best_effort" if best_effort else self.reliability,
            durability=self.durability,
            depth=self.depth if depth is None else depth,
        )

    def of(self, agent: str) -> str:
        """The absolute name of an agent's topic (``/c3po/graph``), for a node outside that namespace."""
        if self.name.startswith("/"):
            return self.name
        return f"/{agent.strip('/')}/{self.name}"


# -- one agent's topics (namespace /<agent>) -----------------------------------------------------------------
CMD_VEL = Topic("cmd_vel", "geometry_msgs/msg/Twist", 1, flow="teleop / station / autopilot → base controller")
CMD_VEL_STAMPED = Topic(
    "cmd_vel", "geometry_msgs/msg/TwistStamped", 1, content="the same command, stamped", flow="teleop → base controller"
)
ODOM = Topic("odom", "nav_msgs/msg/Odometry", 10, content="wheel odometry, base_link in odom",
             flow="base controller → slam (prior), autopilot, station")  # fmt: skip
JOINT_STATES = Topic("joint_states", "sensor_msgs/msg/JointState", 10, flow="base controller → anyone")
RGB_IMAGE = Topic("camera/rgb/image_raw", "sensor_msgs/msg/Image", 2, content="rgb8", flow="camera/sim → slam, station")
DEPTH_IMAGE = Topic("camera/depth/image_raw", "sensor_msgs/msg/Image", 2, content="32FC1 m or 16UC1 mm",
                    flow="camera/sim → slam, station")  # fmt: skip
CAMERA_INFO = Topic("camera/rgb/camera_info", "sensor_msgs/msg/CameraInfo", 2, flow="camera/sim → slam")
DEPTH_CAMERA_INFO = Topic("camera/depth/camera_info", "sensor_msgs/msg/CameraInfo", 2, flow="camera/sim → anyone")
TF_STATIC = Topic("tf_static", "tf2_msgs/msg/TFMessage", 1, "transient_local", content="base_link → camera",
                  flow="camera/sim → slam, station")  # fmt: skip
GROUND_TRUTH_ODOM = Topic("ground_truth/odom", "nav_msgs/msg/Odometry", 10, content="base_link in world",
                          flow="sim only → evaluation, station")  # fmt: skip
SLAM_ODOM = Topic("slam/odom", "nav_msgs/msg/Odometry", 5, content="camera in map, every frame",
                  flow="slam → station")  # fmt: skip
PATH = Topic("path", "nav_msgs/msg/Path", 1, content="keyframe poses", flow="slam → station")
LIVEFRAMES = Topic("liveframes", "fleetslam_msgs/msg/Keyframe", 5, content="no images, every frame",
                   flow="slam → viewers")  # fmt: skip
KEYFRAMES = Topic("keyframes", "fleetslam_msgs/msg/Keyframe", 50, content="with images", flow="slam → mapping")
GRAPH = Topic("graph", "fleetslam_msgs/msg/KeyframeGraph", 1, "transient_local",
              content="the whole graph, poses + constraints only; after loop closures, else at most 1 Hz",
              flow="slam → mapping, station")  # fmt: skip
GRAPH_UPDATES = Topic("graph_updates", "fleetslam_msgs/msg/KeyframeGraph", 50,
                      content="deltas: new keyframes, moved poses, new constraints, numbered; the whole graph on "
                      "request (`graph/full`)", flow="slam → other agents")  # fmt: skip
KEYFRAME_SUMMARIES = Topic("keyframe_summaries", "fleetslam_msgs/msg/KeyframeSummary", 50,
                           content="every keyframe's features, quantised, no images (~15 kB)",
                           flow="slam → other agents")  # fmt: skip
FLEET_TRANSFORM = Topic(
    "slam/fleet_transform",
    "geometry_msgs/msg/TransformStamped",
    1,
    "transient_local",
    content="fleet → <agent>/map once placed, on change",
    flow="slam → other agents, fleet map, station",
)
FLEET_POSE = Topic("slam/fleet_pose", "geometry_msgs/msg/PoseStamped", 5,
                   content="camera in the fleet frame, every frame once the agent is placed in it",
                   flow="slam → station, other agents")  # fmt: skip
FLEET_PATH = Topic("fleet_path", "nav_msgs/msg/Path", 1, "transient_local",
                   content="keyframes corrected by the joint optimisation, in the fleet frame; while subscribed",
                   flow="fleet back-end → station, viewers, mapping and slam (follow_fleet)")  # fmt: skip
SLAM_DIAGNOSTICS = Topic(
    "slam/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", 5,
    content="frames received/processed/dropped, relocalisations, loop closures, timings; every processed frame",
    flow="slam → demo monitor, operators",
)  # fmt: skip
MAP_OCCUPIED = Topic("map/occupied", "sensor_msgs/msg/PointCloud2", 1, "transient_local",
                     content="occupied voxel centres", flow="mapping → station")  # fmt: skip
MAP_MARKERS = Topic("map/markers", "visualization_msgs/msg/MarkerArray", 1, "transient_local",
                    flow="mapping → viewers")  # fmt: skip
MAP_GRID = Topic("map/grid", "nav_msgs/msg/OccupancyGrid", 1, "transient_local", flow="mapping → viewers")
MAP_OCTOMAP = Topic("map/octomap", "octomap_msgs/msg/Octomap", 1, "transient_local", flow="mapping → fleet map")
TF = Topic("tf", "tf2_msgs/msg/TFMessage", 10, content="odom → base_link, map → odom, fleet → <agent>/map",
           flow="base controller, slam → anyone")  # fmt: skip

# -- fleet-level topics ------------------------------------------------------------------------------------
STATISTICS = Topic("/statistics", "fleetslam_msgs/msg/TopicStatistics", 100, content="from every subscription",
                   flow="every node → station, `fleetslam stats`, demo monitor")  # fmt: skip
FLEET_MAP_OCCUPIED = Topic("/fleet/map/occupied", "sensor_msgs/msg/PointCloud2", 1, "transient_local",
                           content="the fused map", flow="fleet map → station")  # fmt: skip
FLEET_MAP_OCTOMAP = Topic("/fleet/map/octomap", "octomap_msgs/msg/Octomap", 1, "transient_local",
                          content="the fused map", flow="fleet map → viewers")  # fmt: skip
FINDINGS = Topic("/fleet/findings", "fleetslam_msgs/msg/FindingArray", 1, "transient_local",
                 content="every inspection finding, latest state, photos included; on change",
                 flow="findings service → station, report")  # fmt: skip
FLEET_PLACEMENTS = Topic("/fleet/placements", "tf2_msgs/msg/TFMessage", 1, "transient_local",
                         content="fleet → <agent>/map of every agent the joint optimisation placed, after each solve",
                         flow="fleet back-end → fleet map, station, mapping and slam (follow_fleet)")  # fmt: skip
FLEET_BACKEND_DIAGNOSTICS = Topic(
    "/fleet/backend/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", 5,
    content="agents placed, closures kept/rejected, variables, solve time; after each solve",
    flow="fleet back-end → operators, benchmarks",
)  # fmt: skip
CLOCK = Topic("/clock", "rosgraph_msgs/msg/Clock", 1, content="sim time, when simulated", flow="sim → every node")

AGENT_TOPICS: tuple[Topic, ...] = (
    CMD_VEL, CMD_VEL_STAMPED, ODOM, JOINT_STATES, RGB_IMAGE, DEPTH_IMAGE, CAMERA_INFO, DEPTH_CAMERA_INFO, TF_STATIC,
    GROUND_TRUTH_ODOM, SLAM_ODOM, FLEET_POSE, FLEET_TRANSFORM, FLEET_PATH, PATH, LIVEFRAMES, KEYFRAMES,
    KEYFRAME_SUMMARIES, GRAPH, GRAPH_UPDATES, SLAM_DIAGNOSTICS, MAP_OCCUPIED, MAP_MARKERS, MAP_GRID, MAP_OCTOMAP, TF,
)  # fmt: skip
"""The topics of one agent, in its namespace."""
FLEET_TOPICS: tuple[Topic, ...] = (STATISTICS, FLEET_MAP_OCCUPIED, FLEET_MAP_OCTOMAP, FINDINGS, FLEET_PLACEMENTS,
                                   FLEET_BACKEND_DIAGNOSTICS, CLOCK)  # fmt: skip
"""The fleet-level topics (absolute names)."""


def _short_type(type_name: str) -> str:
    pkg, _, name = type_name.split("/")
    return f"{pkg}/{name}"


def markdown_table(topics: tuple[Topic, ...]) -> str:
    """The markdown table of ``topics`` (topic, type, QoS, from → to) as ``docs/architecture.md`` shows it."""
    lines = ["| topic | type | QoS | from → to |", "|---|---|---|---|"]
    for topic in topics:
        kind = _short_type(topic.type) + (f" ({topic.content})" if topic.content else "")
        qos = [topic.reliability.replace("_", " "), f"depth {topic.depth}"]
        if topic.durability == "transient_local":
            qos.insert(0, "latched")
        lines.append(f"| `{topic.name}` | {kind} | {', '.join(qos)} | {topic.flow} |")
    return "\n".join(lines) + "\n"
