"""The fleet map node: every agent's `map/octomap` in, the fused map in the fleet frame out.

Agents are found in the graph (any `/<agent>/map/octomap` publisher) or listed in the parameters. An agent's map
frame is placed in the fleet frame by its known start pose (``start_poses``, optional), else by the fleet back-end's
joint optimisation when one runs (``/fleet/placements``, latched, see :mod:`fleetslam.fusion.fleet_graph_node`),
else by the transform its SLAM publishes once its closures with the fleet agree (``slam/fleet_transform``, latched:
``fleet`` → ``<agent>/map``, see :mod:`fleetslam.fusion.collaboration`); an agent placed by none stays out of the
fused map (with ``require_placement``) rather than land at the origin on top of the others. At ``publish_rate`` it
takes each agent's latest map (the maps that came in between are skipped), fuses what changed into the fleet map, and
publishes ``/fleet/map/occupied`` (PointCloud2) and ``/fleet/map/octomap`` if the fleet map changed — each only
while someone subscribes to it. Service ``/fleet/map/save`` (SaveMap) writes the fused `.bt`.
"""

from __future__ import annotations

import logging
import threading
from functools import partial
from typing import Any

import numpy as np
from pydantic import Field

from fleetslam import topics
from fleetslam.config import ConfigModel
from fleetslam.errors import UnsafePathError
from fleetslam.fusion.fleet_map import FleetMap
from fleetslam.geometry import invert, pose_from_xyz_rpy, rotation_angle
from fleetslam.mapping.node import PublishPacer
from fleetslam.mapping.octomap_io import leaves_from_octomap_message, octomap_message_fields
from fleetslam.middleware import Node
from fleetslam.msg.conversions import pointcloud2_msg, transform_matrix
from fleetslam.msg.typesys import deserialize, get_type, header, message_from_dict
from fleetslam.save_paths import save_path

log = logging.getLogger(__name__)


class FleetMapConfig(ConfigModel):
    """Parameters of the fleet map node."""

    resolution: float = Field(default=0.05, gt=0)
    """Resolution of the agents' maps and of the fused map (m)."""
    start_poses: dict[str, list[float]] = Field(default_factory=dict)
    """Per agent, its map frame in the fleet frame as [x, y, z, roll, pitch, yaw] (m, rad), when known; agents not
    listed are placed by the fleet back-end when one runs, else by the transform their SLAM publishes once aligned
    with the fleet."""
    require_placement: bool = True
    """Leave an agent out of the fused map until it has a start pose or has published its place in the fleet frame
    (False: fuse it at the fleet origin meanwhile)."""
    placement_tolerance: float = Field(default=0.05, gt=0)
    """A published placement that moved less than this (m, and a tenth of it in radians: that much at 10 m) is not
    applied again: applying one re-lands the agent's whole map, and the placements are refined by millimetres with
    every closure and solve; by default one voxel of the fused map, which a smaller move barely changes."""
    agents: list[str] = Field(default_factory=list)
    """Agents to fuse; empty: every agent publishing `map/octomap`."""
    publish_rate: float = Field(default=0.5, gt=0)
    """How often a changed fused map is published (Hz)."""
    max_publish_load: float = Field(default=0.03, gt=0, le=1)
    """Largest share of one core that building the published messages may take: a publication that took t s is
    followed by the next one no sooner than t / max_publish_load s later."""
    frame_id: str = "fleet"
    """Frame of the fused map."""
    maps_dir: str = "maps"
    """The only directory the save service writes to (created when needed; relative to the working directory).
    Requests name a plain file inside it, never a path."""
    save_path: str = "fleet.bt"
    """Default file name of the save service, inside ``maps_dir``."""


class FleetMapNode:
    """Adapter between the middleware and a :class:`FleetMap`."""

    def __init__(self, node: Node, config: FleetMapConfig | None = None) -> None:
        self.node = node
        self.config = config or FleetMapConfig()
        self.fleet = FleetMap(self.config.resolution)
        self.placed: dict[str, np.ndarray] = {}
        """Each placed agent's ``T_fleet_map``."""
        for agent, pose in self.config.start_poses.items():
            self.placed[agent] = pose_from_xyz_rpy(*pose)
            self.fleet.set_transform(agent, self.placed[agent])
        self._subscribed: set[str] = set()
        self._latest: dict[str, bytes] = {}
        """Per agent, the latest map message (CDR) not fused yet."""
        self._fuse_lock = threading.Lock()
        self._pending_placement: dict[str, np.ndarray] = {}
        """Per agent, the newest published placement not applied yet (applied at the next tick)."""
        self._own_placement: dict[str, np.ndarray] = {}
        """Per agent, the newest placement its own SLAM published (used while the back-end does not place it)."""
        self.backend_placed: set[str] = set()
        """Agents the fleet back-end places (their SLAM's own placement is then ignored)."""
        self._version = 0
        self._published = {"occupied": 0, "octomap": 0}
        self._pacer = PublishPacer(self.config.max_publish_load)
        cloud, octomap = topics.FLEET_MAP_OCCUPIED, topics.FLEET_MAP_OCTOMAP
        self.cloud_pub = node.create_publisher(cloud.type, cloud.name, cloud.qos())
        self.octomap_pub = node.create_publisher(octomap.type, octomap.name, octomap.qos())
        node.create_service("fleetslam_msgs/srv/SaveMap", "/fleet/map/save", self.on_save)
        for agent in self.config.agents:
            self._subscribe(agent)
        placements = topics.FLEET_PLACEMENTS
        node.create_subscription(placements.type, placements.name, self.on_backend_placements, placements.qos(depth=1))
        node.create_timer(1.0, self._discover)
        node.create_timer(1.0 / self.config.publish_rate, self.on_timer)

    def _subscribe(self, agent: str) -> None:
        if agent in self._subscribed:
            return
        self._subscribed.add(agent)
        octomap = topics.MAP_OCTOMAP
        self.node.create_subscription(
            octomap.type, octomap.of(agent), partial(self.on_agent_map, agent), octomap.qos(depth=1), raw=True
        )
        if agent not in self.config.start_poses:
            placement = topics.FLEET_TRANSFORM
            self.node.create_subscription(
                placement.type, placement.of(agent), partial(self.on_agent_placement, agent), placement.qos(depth=1)
            )

    def on_agent_placement(self, agent: str, msg: Any) -> None:
        """An agent's ``fleet → <agent>/map`` (``slam/fleet_transform``): its map frame placed by its SLAM."""
        if msg.header.frame_id != self.config.frame_id or msg.child_frame_id != f"{agent}/map":
            log.warning("%s: placement %s -> %s is not fleet -> %s/map; ignored", agent, msg.header.frame_id,
                        msg.child_frame_id, agent)  # fmt: skip
            return
        try:
            pose = transform_matrix(msg.transform)
        except ValueError:
            pose = np.full((4, 4), np.nan)
        if not np.isfinite(pose).all():
            log.warning("%s: placement is not finite; ignored", agent)
            return
        self._own_placement[agent] = pose
        if agent not in self.backend_placed:
            self._pending_placement[agent] = pose

    def on_backend_placements(self, msg: Any) -> None:
        """The fleet back-end's ``fleet → <agent>/map`` of every agent it places (``/fleet/placements``): preferred
        to the agents' own; an agent it no longer places (it restarted) falls back to its SLAM's own placement.
        Agents with a configured start pose keep it."""
        placed: dict[str, np.ndarray] = {}
        for transform in msg.transforms:
            agent, _, frame = str(transform.child_frame_id).rpartition("/")
            if transform.header.frame_id != self.config.frame_id or frame != "map" or not agent:
                continue
            try:
                pose = transform_matrix(transform.transform)
            except ValueError:
                continue
            if np.isfinite(pose).all() and agent not in self.config.start_poses:
                placed[agent] = pose
        for agent in self.backend_placed - set(placed):
            self._pending_placement.pop(agent, None)
            if agent in self._own_placement:
                self._pending_placement[agent] = self._own_placement[agent]
        self.backend_placed = set(placed)
        self._pending_placement.update(placed)

    def _discover(self) -> None:
        if self.config.agents:
            return
        for topic in self.node.context.graph.topic_names_and_types():
            parts = topic.strip("/").split("/")
            if len(parts) == 3 and parts[1:] == ["map", "octomap"] and parts[0] != "fleet":
                self._subscribe(parts[0])

    def on_agent_map(self, agent: str, data: bytes) -> None:
        """Keep an agent's latest map; it is decoded and fused at the next tick."""
        self._latest[agent] = data

    def _apply_placements(self) -> None:
        pending, self._pending_placement = self._pending_placement, {}
        tolerance = self.config.placement_tolerance
        for agent, pose in sorted(pending.items()):
            known = self.placed.get(agent)
            if known is not None:
                moved = invert(known) @ pose
                if np.linalg.norm(moved[:3, 3]) < tolerance and rotation_angle(moved) < tolerance / 10:
                    continue
            by = "the fleet back-end" if agent in self.backend_placed else "its SLAM"
            if known is None:
                log.info("%s: placed in the fleet frame by %s", agent, by)
            else:
                log.info("%s: map re-landed (placement by %s moved %.3f m, %.2f°)", agent, by,
                         float(np.linalg.norm(moved[:3, 3])), float(np.degrees(rotation_angle(moved))))  # fmt: skip
            self.placed[agent] = pose
            self.fleet.set_transform(agent, pose)
            self._version += 1

    def fuse_pending(self) -> None:
        """Apply new placements, then fuse the agents' latest maps into the fleet map (only what changed in them);
        the map of an agent not placed yet waits (with ``require_placement``). Callable from any thread (the tick,
        the save service, a test): one call fuses at a time, so a caller returns with what had arrived fused."""
        with self._fuse_lock:
            self._fuse_pending()

    def _fuse_pending(self) -> None:
        self._apply_placements()
        pending, self._latest = self._latest, {}
        if self.config.require_placement:
            for agent in [a for a in pending if a not in self.placed]:
                self._latest.setdefault(agent, pending.pop(agent))  # a newer map may have landed meanwhile
        template = self.fleet.fused()
        for agent, data in sorted(pending.items()):
            msg = deserialize(data, "octomap_msgs/msg/Octomap")
            if abs(msg.resolution - self.config.resolution) > 1e-9:
                log.warning("%s: map resolution %g differs from the fleet's %g; ignored", agent, msg.resolution,
                            self.config.resolution)  # fmt: skip
                continue
            leaves = leaves_from_octomap_message(
                bool(msg.binary), msg.id, np.asarray(msg.data),
                clamp_min_log_odds=float(template.clamp_min_log), clamp_max_log_odds=float(template.clamp_max_log),
            )  # fmt: skip
            if self.fleet.update_agent_leaves(agent, leaves):
                self._version += 1

    def on_timer(self) -> None:
        self.fuse_pending()
        if self._pacer.due():
            self._pacer.timed(self.publish)

    def publish(self) -> bool:
        """The fused map to whoever subscribes, if it changed since it was last published to them; whether it
        was published."""
        fused = self.fleet.fused()
        now_ns = self.node.now_ns()
        stamp = header(self.config.frame_id, now_ns)
        published = False
        if self._published["occupied"] != self._version and self.cloud_pub.matched_subscriptions:
            centres, _ = fused.occupied_centers()
            self.cloud_pub.publish(pointcloud2_msg(centres, frame_id=self.config.frame_id, stamp_ns=now_ns))
            self._published["occupied"] = self._version
            published = True
        if self._published["octomap"] != self._version and self.octomap_pub.matched_subscriptions:
            octomap = message_from_dict(
                "octomap_msgs/msg/Octomap", octomap_message_fields(fused.resolution, fused.leaves())
            )
            octomap.header = stamp
            self.octomap_pub.publish(octomap)
            self._published["octomap"] = self._version
            published = True
        return published

    def on_save(self, request: Any) -> Any:
        response = get_type("fleetslam_msgs/srv/SaveMap_Response")
        name = request.path or self.config.save_path
        try:
            path = save_path(self.config.maps_dir, name, suffixes=(".bt",))
        except (UnsafePathError, OSError) as err:
            return response(success=False, message=str(err), path=name)
        self.fuse_pending()
        try:
            written = self.fleet.fused().write_binary(path)
        except OSError as err:
            return response(success=False, message=f"{path}: {err.strerror}", path=str(path))
        return response(success=True, message=f"{written} nodes written, agents {self.fleet.agents()}", path=str(path))
