"""The mapping node of one agent: keyframes and the optimised graph in, occupancy products out.

Subscribes ``keyframes`` (fleetslam_msgs/Keyframe: depth as 16-bit PNG in mm, intrinsics, pose T_map_camera)
and ``graph`` (fleetslam_msgs/KeyframeGraph: optimised poses). Publishes, at ``publish_rate`` when the map
changed, ``map/occupied`` (PointCloud2 of occupied voxel centres), ``map/markers`` (MarkerArray, one CUBE_LIST
per leaf size, coloured by height), ``map/grid`` (OccupancyGrid over a height band) and ``map/octomap``
(octomap_msgs/Octomap, binary). Services: ``map/save`` (SaveMap), ``map/clear_bbx`` (ClearBbx), ``map/reset``
(Trigger). The work is done by :class:`~fleetslam.mapping.keyframe_mapper.KeyframeMapper`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from fleetslam.config import ConfigModel
from fleetslam.mapping.config import MappingConfig
from fleetslam.mapping.keyframe_mapper import KeyframeMapper, depth_to_points
from fleetslam.mapping.octomap_io import octomap_message_fields
from fleetslam.mapping.products import cube_list_markers, pointcloud2_fields_and_data, project_occupancy_grid
from fleetslam.middleware import Node, QoSProfile
from fleetslam.middleware.conversions import pose_matrix
from fleetslam.middleware.typesys import get_type, header, message_from_dict

log = logging.getLogger(__name__)


class MappingNodeConfig(ConfigModel):
    """Parameters of the mapping node."""

    mapping: MappingConfig = Field(default_factory=MappingConfig)
    """Octree resolution and sensor model."""
    frame_id: str = "map"
    """Frame of the published map."""
    publish_rate: float = Field(default=1.0, gt=0)
    """How often changed maps are published (Hz)."""
    pixel_stride: int = Field(default=4, ge=1)
    """Use every n-th pixel of a keyframe's depth image in each direction."""
    max_depth: float = Field(default=4.5, gt=0)
    """Depths beyond this (m) are not integrated (Kinect range)."""
    grid_z_min: float = 0.1
    """Lowest voxel centre projected into the 2D grid (m)."""
    grid_z_max: float = 1.8
    """Highest voxel centre projected into the 2D grid (m)."""
    save_path: str = "map.bt"
    """Default file of the map/save service."""


def decode_depth(msg: Any) -> np.ndarray | None:
    """Depth in metres of a Keyframe's compressed depth image (None when omitted)."""
    if msg.depth_format != "png16_mm" or len(msg.depth) == 0:
        return None
    import cv2

    image = cv2.imdecode(np.frombuffer(bytes(msg.depth), np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint16:
        raise ValueError("depth is not a 16-bit PNG")
    depth = image.astype(np.float32) / 1000.0
    depth[image == 0] = np.nan
    return depth


def pointcloud2_msg(points: np.ndarray, stamp_header: Any) -> Any:
    """sensor_msgs/msg/PointCloud2 of ``(N, 3)`` points as float32 x, y, z."""
    fields, step, data = pointcloud2_fields_and_data(points)
    field_type = get_type("sensor_msgs/msg/PointField")
    return get_type("sensor_msgs/msg/PointCloud2")(
        header=stamp_header, height=1, width=len(points),
        fields=[field_type(name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields],
        is_bigendian=False, point_step=step, row_step=step * len(points),
        data=np.frombuffer(data, np.uint8), is_dense=True,
    )  # fmt: skip


class MappingNode:
    """Adapter between the middleware and a :class:`KeyframeMapper`."""

    def __init__(self, node: Node, config: MappingNodeConfig | None = None) -> None:
        self.node = node
        self.config = config or MappingNodeConfig()
        self.mapper = KeyframeMapper(self.config.mapping)
        self._dirty = False
        latched = QoSProfile(durability="transient_local", depth=1)
        self.cloud_pub = node.create_publisher("sensor_msgs/msg/PointCloud2", "map/occupied", latched)
        self.marker_pub = node.create_publisher("visualization_msgs/msg/MarkerArray", "map/markers", latched)
        self.grid_pub = node.create_publisher("nav_msgs/msg/OccupancyGrid", "map/grid", latched)
        self.octomap_pub = node.create_publisher("octomap_msgs/msg/Octomap", "map/octomap", latched)
        node.create_subscription("fleetslam_msgs/msg/Keyframe", "keyframes", self.on_keyframe, QoSProfile(depth=50))
        node.create_subscription("fleetslam_msgs/msg/KeyframeGraph", "graph", self.on_graph, QoSProfile(depth=5))
        node.create_service("fleetslam_msgs/srv/SaveMap", "map/save", self.on_save)
        node.create_service("fleetslam_msgs/srv/ClearBbx", "map/clear_bbx", self.on_clear_bbx)
        node.create_service("std_srvs/srv/Trigger", "map/reset", self.on_reset)
        node.create_timer(1.0 / self.config.publish_rate, self.on_timer)

    # -- inputs -------------------------------------------------------------------------------------------------
    def on_keyframe(self, msg: Any) -> None:
        depth = decode_depth(msg)
        if depth is None:
            return
        k = msg.camera_info.k
        points = depth_to_points(
            depth, float(k[0]), float(k[4]), float(k[2]), float(k[5]), stride=self.config.pixel_stride,
            max_depth=self.config.max_depth,
        )  # fmt: skip
        self.mapper.add_keyframe(int(msg.id), points, pose_matrix(msg.pose))
        self._dirty = True

    def on_graph(self, msg: Any) -> None:
        poses = {int(i): pose_matrix(p) for i, p in zip(msg.keyframe_ids, msg.poses, strict=False)}
        if self.mapper.update_poses(poses):
            self._dirty = True

    def on_timer(self) -> None:
        if not self._dirty:
            return
        self._dirty = False
        if self.mapper.integrate():
            self.publish()

    # -- outputs ------------------------------------------------------------------------------------------------
    def publish(self) -> None:
        tree = self.mapper.tree
        now = self.node.now_ns()
        stamp = header(self.config.frame_id, now)
        centres, sizes = tree.occupied_centers()
        self.cloud_pub.publish(pointcloud2_msg(centres, stamp))
        z_range = (float(centres[:, 2].min()), float(centres[:, 2].max())) if len(centres) else (0.0, 1.0)
        markers = []
        point, colour = get_type("geometry_msgs/msg/Point"), get_type("std_msgs/msg/ColorRGBA")
        for cubes in cube_list_markers(centres, sizes, tree.resolution, height_range=z_range):
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
        self.marker_pub.publish(get_type("visualization_msgs/msg/MarkerArray")(markers=markers))
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
        self.grid_pub.publish(occupancy)
        octomap = message_from_dict(
            "octomap_msgs/msg/Octomap",
            octomap_message_fields(
                tree.resolution, tree.leaves(), occupancy_threshold_log_odds=float(tree.threshold_log)
            ),
        )
        octomap.header = stamp
        self.octomap_pub.publish(octomap)

    # -- services -----------------------------------------------------------------------------------------------
    def on_save(self, request: Any) -> Any:
        response = get_type("fleetslam_msgs/srv/SaveMap_Response")
        path = Path(request.path or self.config.save_path)
        try:
            self.mapper.integrate()
            path.parent.mkdir(parents=True, exist_ok=True)
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
        cleared = self.mapper.tree.clear_bbox(lo, hi)
        self._dirty = True
        self.publish()
        return get_type("fleetslam_msgs/srv/ClearBbx_Response")(success=True, message=f"cleared {cleared} leaves")

    def on_reset(self, request: Any) -> Any:
        self.mapper.reset()
        self.publish()
        return get_type("std_srvs/srv/Trigger_Response")(success=True, message="map reset")
