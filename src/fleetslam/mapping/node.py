"""The mapping node of one agent: keyframes and the optimised graph in, occupancy products out.

Subscribes ``keyframes`` (fleetslam_msgs/Keyframe: depth as 16-bit PNG in mm, intrinsics, pose T_map_camera)
and ``graph_updates`` (fleetslam_msgs/KeyframeGraph deltas: new and moved keyframe poses, numbered; decoded at the
next tick and kept in a :class:`~fleetslam.fusion.graph_exchange.GraphMirror`; a gap, as when the node starts after
SLAM, asks SLAM's ``graph/full`` for the whole graph). Publishes, at ``publish_rate`` when the map changed,
``map/occupied`` (PointCloud2 of occupied voxel centres), ``map/markers`` (MarkerArray, one CUBE_LIST per leaf size,
coloured by height), ``map/grid`` (OccupancyGrid over a height band) and ``map/octomap`` (octomap_msgs/Octomap,
binary) — as octomap_server, each only while someone subscribes to it (a subscriber that comes later gets the
current map at the next tick). Services: ``map/save`` (SaveMap), ``map/clear_bbx`` (ClearBbx), ``map/reset``
(Trigger). The work is done by :class:`~fleetslam.mapping.keyframe_mapper.KeyframeMapper`, incrementally.

With ``follow_fleet`` it also subscribes its agent's ``fleet_path`` and ``/fleet/placements`` (the fleet back-end's
corrected keyframes and placement; the newest of each decoded at the next tick) and integrates each keyframe where
the back-end put it, expressed in the agent's own map frame (:mod:`fleetslam.fusion.fleet_correction`); keyframes
the back-end does not know yet follow the agent's own graph from the newest corrected one. Keyframes that moved
more than ``fleet_move_tolerance`` are integrated again as after the agent's own optimisation (at most every
``reintegrate_period``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from fleetslam import topics
from fleetslam._imports import require
from fleetslam.config import ConfigModel
from fleetslam.errors import MessageError, UnsafePathError, worth_logging
from fleetslam.fusion.fleet_correction import FleetCorrection, stamp_key
from fleetslam.fusion.graph_exchange import GraphMirror, graph_update_of
from fleetslam.fusion.graph_fetcher import GraphFetcher
from fleetslam.mapping.config import MappingConfig
from fleetslam.mapping.keyframe_mapper import KeyframeMapper, depth_to_points
from fleetslam.mapping.octomap_io import octomap_message_fields
from fleetslam.mapping.products import cube_list_markers, project_occupancy_grid
from fleetslam.middleware import Node, Publisher
from fleetslam.msg.conversions import pointcloud2_msg, pose_matrix
from fleetslam.msg.typesys import deserialize, get_type, header, message_from_dict, ns_from_stamp, serialize
from fleetslam.save_paths import save_path

log = logging.getLogger(__name__)

SLAM_GRAPH = "slam"
"""The one graph a mapping node fetches whole: its own SLAM's (``graph/full`` in its namespace)."""


class MappingNodeConfig(ConfigModel):
    """Parameters of the mapping node."""

    mapping: MappingConfig = Field(default_factory=MappingConfig)
    """Octree resolution and sensor model."""
    frame_id: str = "map"
    """Frame of the published map."""
    publish_rate: float = Field(default=1.0, gt=0)
    """How often changed maps are published (Hz)."""
    reintegrate_period: float = Field(default=5.0, ge=0)
    """Keyframes that the optimised graph moved are integrated again at most this often (s): loop closures in a row
    move the same keyframes again and again, and one pass serves them all (new keyframes go in at every tick)."""
    max_publish_load: float = Field(default=0.03, gt=0, le=1)
    """Largest share of one core that building the map products may take: a publication that took t s is followed
    by the next one no sooner than t / max_publish_load s later (a big map is published less often)."""
    pixel_stride: int = Field(default=4, ge=1)
    """Use every n-th pixel of a keyframe's depth image in each direction."""
    max_depth: float = Field(default=4.5, gt=0)
    """Depths beyond this (m) are not integrated (Kinect range)."""
    grid_z_min: float = 0.1
    """Lowest voxel centre projected into the 2D grid (m)."""
    grid_z_max: float = 1.8
    """Highest voxel centre projected into the 2D grid (m)."""
    maps_dir: str = "maps"
    """The only directory the map/save service writes to (created when needed; relative to the working
    directory). Requests name a plain file inside it, never a path."""
    save_path: str = "map.bt"
    """Default file name of the map/save service, inside ``maps_dir`` (``.bt`` binary or ``.ot`` full octree)."""
    follow_fleet: bool = False
    """Integrate the keyframes where the fleet back-end's joint optimisation put them (``fleet_path`` and
    ``/fleet/placements``, expressed in this agent's map frame; see :mod:`fleetslam.fusion.fleet_correction`)
    instead of where the agent's own graph has them, so that the fleet map, which lands this map by one rigid
    transform, has no doubled walls where the agent's own graph is bent. Keyframes the back-end has not corrected
    (newer, or the link to it cut) follow the agent's own graph from the newest corrected one; with no back-end
    nothing changes. Off by default: the map then no longer agrees with the agent's own localisation (near the robot
    it is shifted by the back-end's correction there), and subscribing makes the back-end send the agent its whole
    corrected path (~80 B per keyframe) whenever it changes."""
    fleet_move_tolerance: float = Field(default=0.05, ge=0)
    """With ``follow_fleet``: a keyframe is integrated again only when the back-end's corrections (or its own graph)
    moved its scan more than this (m, bound on any of its points) since it was integrated; one voxel by default,
    twice the mapper's own tolerance: every solve of the back-end nudges most keyframes by centimetres (a new
    closure bends the chains a little), and re-integrating for each nudge rebuilt the map every few seconds."""
    fleet_placement_tolerance: float = Field(default=0.05, gt=0)
    """With ``follow_fleet``: a placement of this agent by the back-end that moved less than this (m, and a tenth of
    it in radians) from the one followed is not taken (every keyframe would move with it); keep it equal to the
    fleet map's ``placement_tolerance``, which re-lands the map by the same rule."""


def decode_depth(msg: Any) -> np.ndarray | None:
    """Depth in metres of a Keyframe's compressed depth image (None when omitted)."""
    if msg.depth_format != "png16_mm" or len(msg.depth) == 0:
        return None
    cv2 = require("cv2", "mapping")
    image = cv2.imdecode(np.frombuffer(bytes(msg.depth), np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint16:
        raise ValueError("depth is not a 16-bit PNG")
    depth = image.astype(np.float32) / 1000.0
    depth[image == 0] = np.nan
    return depth


class PublishPacer:
    """Spaces out publications so that building them takes at most ``max_load`` of a core on average."""

    def __init__(self, max_load: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.max_load = max_load
        self._clock = clock
        self._next = -math.inf

    def due(self) -> bool:
        return self._clock() >= self._next

    def timed(self, work: Callable[[], bool]) -> bool:
        """Run ``work``; if it did something (returned True), the next publication waits for its time share."""
        start = self._clock()
        did = work()
        if did:
            self._next = start + (self._clock() - start) / self.max_load
        return did


class MappingNode:
    """Adapter between the middleware and a :class:`KeyframeMapper`."""

    def __init__(self, node: Node, config: MappingNodeConfig | None = None) -> None:
        self.node = node
        self.config = config or MappingNodeConfig()
        self.mapper = KeyframeMapper(self.config.mapping)
        self._graph_updates: list[bytes] = []
        """Graph updates received since the last tick, in order (decoded at the tick)."""
        self.graph = GraphMirror[Any]()
        self._graph_fetcher = GraphFetcher(node.create_client, self._on_full_graph, name=node.fq_name)
        self._graph_fetcher.add(SLAM_GRAPH, "graph/full")
        self._graph_lock = threading.Lock()
        """Guards ``_graph_updates``: the executor appends, the fetch of the whole graph puts it first."""
        self._version = 0
        """Incremented whenever the map changes; each product remembers the version it last published."""
        self._published = dict.fromkeys(("octomap", "occupied", "markers", "grid"), 0)  # nothing to say yet
        self._centres: tuple[int, NDArray[np.float64], NDArray[np.float64]] | None = None
        self._pacer = PublishPacer(self.config.max_publish_load)
        self._next_reintegration = -math.inf
        self.rejected = 0
        """Keyframes and graphs left out because they were malformed (non-finite or invalid poses)."""
        self._products: dict[str, tuple[Publisher, Callable[[Any], Any]]] = {
            name: (node.create_publisher(topic.type, topic.name, topic.qos()), build)
            for name, topic, build in (
                ("octomap", topics.MAP_OCTOMAP, self._octomap),
                ("occupied", topics.MAP_OCCUPIED, self._cloud),
                ("markers", topics.MAP_MARKERS, self._markers),
                ("grid", topics.MAP_GRID, self._grid),
            )
        }
        keyframes, graph = topics.KEYFRAMES, topics.GRAPH_UPDATES
        node.create_subscription(keyframes.type, keyframes.name, self.on_keyframe, keyframes.qos(depth=50))
        node.create_subscription(graph.type, graph.name, self.on_graph_data, graph.qos(depth=50), raw=True)
        self.fleet = FleetCorrection(placement_tolerance=self.config.fleet_placement_tolerance)
        """The fleet back-end's corrections of this agent's keyframes (followed with ``follow_fleet``)."""
        self._fleet_inbox: dict[str, bytes] = {}
        """The newest ``placements`` and ``path`` message received since the last tick (decoded at the tick)."""
        self._fleet_changed = False
        """The graph or the corrections changed since the mapper was last handed the corrected poses."""
        self._chain = np.eye(4)
        """Places a keyframe newer than the graph: ``chain · own pose`` (see :func:`corrected_poses`)."""
        self._handed: dict[int, NDArray[np.floating]] = {}
        """While following the fleet: the pose each keyframe was last handed to the mapper with."""
        self._handed_epoch = 0
        self._handed_any = False
        self._fleet_child = ""
        if self.config.follow_fleet:
            self._follow_fleet(node)
        node.create_service("fleetslam_msgs/srv/SaveMap", "map/save", self.on_save)
        node.create_service("fleetslam_msgs/srv/ClearBbx", "map/clear_bbx", self.on_clear_bbx)
        node.create_service("std_srvs/srv/Trigger", "map/reset", self.on_reset)
        node.create_timer(1.0 / self.config.publish_rate, self.on_timer)

    def _follow_fleet(self, node: Node) -> None:
        agent = node.namespace.strip("/")
        if not agent or "/" in agent:
            log.warning("follow_fleet: the node's namespace %r names no agent; the map follows its own graph",
                        node.namespace)  # fmt: skip
            return
        self._fleet_child = f"{agent}/{self.config.frame_id}"
        path, placements = topics.FLEET_PATH, topics.FLEET_PLACEMENTS
        node.create_subscription(path.type, path.name, partial(self._on_fleet_data, "path"), path.qos(depth=1),
                                 raw=True)  # fmt: skip
        node.create_subscription(placements.type, placements.name, partial(self._on_fleet_data, "placements"),
                                 placements.qos(depth=1), raw=True)  # fmt: skip

    # -- inputs -------------------------------------------------------------------------------------------------
    def on_keyframe(self, msg: Any) -> None:
        depth = decode_depth(msg)
        if depth is None:
            return
        k = msg.camera_info.k
        try:
            points = depth_to_points(
                depth, float(k[0]), float(k[4]), float(k[2]), float(k[5]), stride=self.config.pixel_stride,
                max_depth=self.config.max_depth,
            )  # fmt: skip
            # Following the fleet: a keyframe newer than the graph continues from the newest corrected one (its
            # graph pose, handed to the mapper before it came, wins as always).
            pose = pose_matrix(msg.pose)
            self.mapper.add_keyframe(int(msg.id), points, self._chain @ pose if self.fleet.active else pose)
        except ValueError as err:  # a NaN position, a zero quaternion, a zero focal length: this keyframe is left out
            self._reject(f"keyframe {msg.id} from {msg.agent!r}", err)

    def _reject(self, what: str, err: Exception) -> None:
        self.rejected += 1
        if worth_logging(self.rejected):
            log.warning("%s ignored (%d inputs ignored so far): %s", what, self.rejected, err)

    def on_graph_data(self, data: bytes) -> None:
        """Keep a graph update's bytes for the next tick (bounded: a flood keeps the newest)."""
        with self._graph_lock:
            self._graph_updates.append(data)
            del self._graph_updates[:-1000]

    def on_graph(self, msg: Any) -> None:
        """Apply a KeyframeGraph (a delta, or the whole graph) and hand the keyframe poses that changed to the
        mapper; a gap before it asks SLAM for the whole graph."""
        update = graph_update_of(msg)
        before = self.graph.sequence
        if not self.graph.apply(update):
            self._request_graph()
            return
        # In order: this update's poses; the whole graph, or deltas kept while waiting for it: every pose.
        in_order = not update.full and self.graph.sequence == update.sequence == before + 1
        changed = update.poses if in_order else self.graph.poses
        if self.fleet.active:
            self._fleet_changed = True  # every pose follows the corrections: handed over at the end of the tick
        elif changed:
            self.mapper.update_poses(dict(changed))

    def _on_fleet_data(self, kind: str, data: bytes) -> None:
        """Keep the back-end's newest placements or path for the next tick (older ones are superseded)."""
        with self._graph_lock:
            self._fleet_inbox[kind] = data

    def on_fleet(self, kind: str, msg: Any) -> None:
        """Take the back-end's placements (``tf2_msgs/TFMessage``) or this agent's corrected path
        (``nav_msgs/Path``); a malformed one raises ValueError and changes nothing."""
        if kind == "placements":
            self._fleet_changed |= self.fleet.take_placements(msg, self._fleet_child)
            return
        self.fleet.take_path(msg)
        self._fleet_changed = True

    def _hand_corrected_poses(self) -> None:
        """Hand the mapper the poses (following the corrections) that differ from those it was last handed."""
        self._fleet_changed = False
        if self.graph.epoch != self._handed_epoch:  # SLAM restarted: its keyframe ids mean other keyframes
            self._handed, self._handed_epoch = {}, self.graph.epoch
        if not self._handed_any:
            self._handed_any = True
            corrected = sum(stamp_key(t) in self.fleet.corrected for t in self.graph.stamps.values())
            log.info("following the fleet back-end: %d of %d keyframes corrected, the others follow from them",
                     corrected, len(self.graph.poses))  # fmt: skip
        poses, self._chain = self.fleet.poses(self.graph.poses, self.graph.stamps)
        known = [i for i in poses if i in self._handed]
        changed: dict[int, NDArray[np.floating]] = {i: pose for i, pose in poses.items() if i not in self._handed}
        if known:
            same = (np.stack([poses[i] for i in known]) == np.stack([self._handed[i] for i in known])).all(axis=(1, 2))
            changed.update({i: poses[i] for i, keep in zip(known, same.tolist(), strict=True) if not keep})
        if changed:
            self.mapper.update_poses(changed, tolerance=self.config.fleet_move_tolerance)
            self._handed.update(changed)

    def _request_graph(self) -> None:
        """SLAM's whole graph (``graph/full``), fetched off the executor; applied at a later tick."""
        self._graph_fetcher.request(SLAM_GRAPH)

    def _on_full_graph(self, _: str, graph: Any) -> None:
        data = serialize(graph, "fleetslam_msgs/msg/KeyframeGraph")
        with self._graph_lock:
            self._graph_updates.insert(0, data)

    def on_timer(self) -> None:
        with self._graph_lock:
            pending, self._graph_updates = self._graph_updates, []
            fleet, self._fleet_inbox = self._fleet_inbox, {}
        for data in pending:
            try:
                self.on_graph(deserialize(data, "fleetslam_msgs/msg/KeyframeGraph"))
            except (MessageError, ValueError, TypeError) as err:
                self._reject("graph update", err)
        for kind, type_name in (("placements", "tf2_msgs/msg/TFMessage"), ("path", "nav_msgs/msg/Path")):
            if kind not in fleet:  # (the placement first: the path must be in its frame)
                continue
            try:
                self.on_fleet(kind, deserialize(fleet[kind], type_name))
            except (MessageError, ValueError, TypeError) as err:
                self._reject(f"fleet {kind}", err)
        if self._fleet_changed and self.fleet.active:
            try:
                self._hand_corrected_poses()
            except ValueError as err:  # a correction outside the map: the keyframes keep their poses
                self._reject("fleet correction", err)
        if self.mapper.pending:
            self._integrate(moved=time.monotonic() >= self._next_reintegration)
        if self._pacer.due():
            self._pacer.timed(self.publish)

    def _integrate(self, *, moved: bool = True) -> None:
        mapper = self.mapper
        before = (mapper.rebuilds, mapper.reintegrated, mapper.replayed)
        if moved and mapper.moved:
            self._next_reintegration = time.monotonic() + self.config.reintegrate_period
        start = time.perf_counter()
        scans = mapper.integrate(moved=moved)
        if scans:
            self._version += 1
        seconds = time.perf_counter() - start
        if mapper.rebuilds != before[0]:
            log.info("map rebuilt from %d keyframes in %.2f s (most moved)", scans, seconds)
        elif mapper.reintegrated != before[1]:
            log.info("%d moved keyframes integrated again, %d scans replayed, in %.2f s",
                     mapper.reintegrated - before[1], mapper.replayed - before[2], seconds)  # fmt: skip

    # -- outputs ------------------------------------------------------------------------------------------------
    def publish(self) -> bool:
        """Publish each product that someone subscribes to if the map changed since; whether any was."""
        published = False
        for name, (publisher, build) in self._products.items():
            if self._published.get(name) == self._version or not publisher.matched_subscriptions:
                continue
            message = build(header(self.config.frame_id, self.node.now_ns()))
            publisher.publish(message)
            self._published[name] = self._version
            published = True
        return published

    def _occupied(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Centres and sizes of the occupied leaves, once per map version (the cloud, markers and grid share them)."""
        if self._centres is None or self._centres[0] != self._version:
            centres, sizes = self.mapper.tree.occupied_centers()
            self._centres = (self._version, centres, sizes)
        return self._centres[1], self._centres[2]

    def _cloud(self, stamp: Any) -> Any:
        return pointcloud2_msg(self._occupied()[0], frame_id=stamp.frame_id, stamp_ns=ns_from_stamp(stamp.stamp))

    def _markers(self, stamp: Any) -> Any:
        centres, sizes = self._occupied()
        z_range = (float(centres[:, 2].min()), float(centres[:, 2].max())) if len(centres) else (0.0, 1.0)
        markers = []
        point, colour = get_type("geometry_msgs/msg/Point"), get_type("std_msgs/msg/ColorRGBA")
        for cubes in cube_list_markers(centres, sizes, self.mapper.tree.resolution, height_range=z_range):
            marker = message_from_dict(
                "visualization_msgs/msg/Marker",
                {
                    "ns": "occupied_cells",
                    "id": cubes.depth,
                    "type": 6,
                    "action": 0,
                    "pose": {"orientation": {"w": 1.0}},
                    "scale": {"x": cubes.size, "y": cubes.size, "z": cubes.size},
                    "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0},
                },
            )
            # Tens of thousands of points: built directly, not through message_from_dict's per-field checks.
            marker.points = [point(x=x, y=y, z=z) for x, y, z in cubes.centres.tolist()]
            if cubes.colors is not None:
                marker.colors = [colour(r=r, g=g, b=b, a=a) for r, g, b, a in cubes.colors.tolist()]
            marker.header = stamp
            markers.append(marker)
        return get_type("visualization_msgs/msg/MarkerArray")(markers=markers)

    def _grid(self, stamp: Any) -> Any:
        tree = self.mapper.tree
        centres, sizes = self._occupied()
        free_centres, free_sizes = tree.free_centers()
        grid, origin = project_occupancy_grid(
            centres, sizes, free_centres, free_sizes, tree.resolution, self.config.grid_z_min, self.config.grid_z_max
        )
        occupancy = message_from_dict(
            "nav_msgs/msg/OccupancyGrid",
            {"info": {"resolution": tree.resolution, "width": int(grid.shape[1]) if grid.size else 0,
                      "height": int(grid.shape[0]) if grid.size else 0,
                      "origin": {"position": {"x": float(origin[0]), "y": float(origin[1])},
                                 "orientation": {"w": 1.0}}},
             "data": grid.reshape(-1).astype(np.int8)},
        )  # fmt: skip
        occupancy.header = stamp
        return occupancy

    def _octomap(self, stamp: Any) -> Any:
        tree = self.mapper.tree
        octomap = message_from_dict(
            "octomap_msgs/msg/Octomap",
            octomap_message_fields(
                tree.resolution, tree.leaves(), occupancy_threshold_log_odds=float(tree.threshold_log)
            ),
        )
        octomap.header = stamp
        return octomap

    # -- services -----------------------------------------------------------------------------------------------
    def on_save(self, request: Any) -> Any:
        response = get_type("fleetslam_msgs/srv/SaveMap_Response")
        name = request.path or self.config.save_path
        try:
            path = save_path(self.config.maps_dir, name, suffixes=(".bt", ".ot"))
        except (UnsafePathError, OSError) as err:
            return response(success=False, message=str(err), path=name)
        try:
            self._integrate()
            tree = self.mapper.tree
            written = tree.write(path) if path.suffix == ".ot" else tree.write_binary(path)
        except OSError as err:
            return response(success=False, message=f"{path}: {err.strerror}", path=str(path))
        # A .bt holds the max-likelihood tree, which prunes further than the live one: say both.
        return response(
            success=True, message=f"{written} nodes written (live tree: {tree.num_nodes()})", path=str(path)
        )

    def on_clear_bbx(self, request: Any) -> Any:
        lo = [request.min.x, request.min.y, request.min.z]
        hi = [request.max.x, request.max.y, request.max.z]
        if not np.isfinite([*lo, *hi]).all():
            return get_type("fleetslam_msgs/srv/ClearBbx_Response")(
                success=False, message=f"box corners must be finite, got min {lo} max {hi}"
            )
        cleared = self.mapper.tree.clear_bbox(lo, hi)
        self._version += 1
        self.publish()
        return get_type("fleetslam_msgs/srv/ClearBbx_Response")(success=True, message=f"cleared {cleared} leaves")

    def on_reset(self, request: Any) -> Any:
        self.mapper.reset()
        self.graph = GraphMirror[Any]()
        self._handed = {}
        self._version += 1
        self.publish()
        return get_type("std_srvs/srv/Trigger_Response")(success=True, message="map reset")
