"""An agent's keyframe poses as the fleet back-end corrected them, in the agent's own map frame.

The fleet back-end (:mod:`fleetslam.fusion.fleet_graph_node`) optimises every agent's keyframes jointly and publishes,
per agent, its corrected keyframes in the fleet frame (``<agent>/fleet_path``, each pose stamped with its keyframe's
stamp) and one rigid ``T_fleet_map`` (``/fleet/placements``: the fit of the corrected keyframes to the agent's own),
by which the fleet map lands the agent's map. A map integrated at the agent's own poses lands bent where the agent's
own graph is bent (two passes along one wall, drifted apart: a doubled wall); integrated at

    T_map_kf = T_fleet_map⁻¹ · T_fleet_kf

(the correction expressed in the agent's own map frame) it lands, by the same rigid transform, where the back-end put
every keyframe. A keyframe the back-end does not know yet (newer than its last solve, or the link to it is cut)
follows its own graph, chained from the nearest corrected keyframe before it: ``T_map_c · own_c⁻¹ · own_kf``, so the
newest part of the map continues where the corrected part ends.

Pure: no middleware (the messages' fields are read, as decoded by any node). Keyframes are matched to the path's
poses by their stamps (the path carries no ids), both rounded to integer nanoseconds as the messages carry them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import invert, quat_to_matrix, rotation_angle
from fleetslam.msg.conversions import transform_matrix
from fleetslam.msg.typesys import ns_from_stamp

Pose = NDArray[np.float64]


def stamp_key(stamp: float) -> int:
    """A keyframe stamp (s) as the integer nanoseconds a message header carries."""
    return round(stamp * 1e9)


def corrected_poses(
    own: Mapping[int, Pose],
    stamps: Mapping[int, float],
    corrected: Mapping[int, Pose],
    T_fleet_map: Pose,
) -> tuple[dict[int, Pose], Pose]:
    """Every keyframe's pose in the agent's map frame, following the back-end where it corrected the keyframe.

    Args:
        own: keyframe id -> ``T_map_kf`` of the agent's own graph.
        stamps: keyframe id -> stamp (s) of the keyframes in ``own``.
        corrected: stamp (integer ns, :func:`stamp_key`) -> ``T_fleet_kf`` corrected by the back-end.
        T_fleet_map: the back-end's placement of the agent's map frame.

    Returns:
        The poses (``T_fleet_map⁻¹ · T_fleet_kf`` for a corrected keyframe; for another, its own pose moved as the
        nearest corrected keyframe before it was, or after it when none is before; its own pose when none is
        corrected), and the ``chain``, ``T_map_c · own_c⁻¹`` of the newest corrected keyframe (identity when none),
        which places a keyframe newer than ``own``: ``chain · own_kf``.
    """
    ids = sorted(own)
    keys = [stamp_key(stamps[i]) if i in stamps else -1 for i in ids]
    hit = np.array([key in corrected for key in keys], dtype=bool)
    if not hit.any():
        return {i: np.array(own[i], dtype=np.float64) for i in ids}, np.eye(4)
    own_stack = np.stack([np.asarray(own[i], dtype=np.float64) for i in ids])
    index = np.flatnonzero(hit)
    fixed = invert(T_fleet_map) @ np.stack([np.asarray(corrected[keys[k]], np.float64) for k in index])
    moves = fixed @ invert(own_stack[index])
    # Each keyframe follows the nearest corrected keyframe at or before it (the first corrected one when none is).
    before = np.maximum.accumulate(np.where(hit, np.arange(len(ids)), -1))
    anchor = np.searchsorted(index, np.where(before >= 0, before, index[0]))
    poses = moves[anchor] @ own_stack
    poses[index] = fixed
    return dict(zip(ids, poses, strict=True)), moves[-1].copy()


@dataclass
class FleetCorrection:
    """The back-end's latest word on one agent: its placement and its corrected keyframes (see the module)."""

    T_fleet_map: Pose | None = None
    """The agent's map frame in the fleet frame (``/fleet/placements``); None until the back-end placed it."""
    frame_id: str = ""
    """The fleet frame the placement is given in (the path must be in it)."""
    corrected: dict[int, Pose] = field(default_factory=dict)
    """Stamp (ns) -> ``T_fleet_kf`` of the keyframes in the latest ``fleet_path``."""
    placement_tolerance: float = 0.0
    """A placement that moved less than this (m, and a tenth of it in radians) from the one held is not taken, as
    the fleet map does (its ``placement_tolerance``): the back-end's fit wobbles by millimetres with every solve, and
    taking each wobble would move every keyframe of the map, while the fleet map keeps landing it where it did."""

    @property
    def active(self) -> bool:
        """Whether there is something to follow: a placement and a path."""
        return self.T_fleet_map is not None and bool(self.corrected)

    def set_placement(self, T_fleet_map: Pose, frame_id: str) -> bool:
        """The agent's placement; whether it was taken (it moved at least ``placement_tolerance``, or is the first,
        or is in another fleet frame: that drops the path, which is in the old one)."""
        pose = np.asarray(T_fleet_map, dtype=np.float64)
        if pose.shape != (4, 4) or not np.isfinite(pose).all():
            raise ValueError("placement is not a finite 4×4 transform")
        if frame_id != self.frame_id:
            self.corrected = {}
        elif self.T_fleet_map is not None:
            moved = invert(self.T_fleet_map) @ pose
            tolerance = self.placement_tolerance
            if np.linalg.norm(moved[:3, 3]) < tolerance and rotation_angle(moved) < tolerance / 10:
                return False
        self.T_fleet_map, self.frame_id = pose, frame_id
        return True

    def set_path(self, stamps_ns: NDArray[np.int64], poses: NDArray[np.float64], frame_id: str) -> None:
        """The agent's corrected keyframes (``T_fleet_kf`` stacked, stamps in ns): they replace the previous ones.
        A path in another frame than the placement's is refused (ValueError)."""
        poses = np.asarray(poses, dtype=np.float64)
        if self.T_fleet_map is not None and frame_id != self.frame_id:
            raise ValueError(f"path is in frame {frame_id!r}, the placement in {self.frame_id!r}")
        if poses.shape != (len(stamps_ns), 4, 4) or not np.isfinite(poses).all():
            raise ValueError("path poses are not finite 4×4 transforms, one per stamp")
        self.frame_id = frame_id
        self.corrected = dict(zip(np.asarray(stamps_ns, np.int64).tolist(), poses, strict=True))

    def poses(self, own: Mapping[int, Pose], stamps: Mapping[int, float]) -> tuple[dict[int, Pose], Pose]:
        """:func:`corrected_poses` of the agent's own graph (its own poses and an identity chain while inactive)."""
        if self.T_fleet_map is None or not self.corrected:
            return {i: np.asarray(p, dtype=np.float64) for i, p in own.items()}, np.eye(4)
        return corrected_poses(own, stamps, self.corrected, self.T_fleet_map)

    def take_placements(self, msg: Any, child_frame: str) -> bool:
        """The placement of ``child_frame`` (``<agent>/map``) from the back-end's ``/fleet/placements``
        (``tf2_msgs/TFMessage``); whether one was taken (see :meth:`set_placement`). An agent the back-end no longer
        places keeps its last placement. A malformed one raises ValueError and changes nothing."""
        taken = False
        for transform in msg.transforms:
            if str(transform.child_frame_id) == child_frame:
                taken |= self.set_placement(transform_matrix(transform.transform), str(transform.header.frame_id))
        return taken

    def take_path(self, msg: Any) -> None:
        """The agent's corrected keyframes from its ``fleet_path`` (``nav_msgs/Path``). A malformed one raises
        ValueError and changes nothing."""
        poses = msg.poses
        values = np.array([(p.pose.position.x, p.pose.position.y, p.pose.position.z, p.pose.orientation.x,
                            p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w) for p in poses],
                          dtype=np.float64).reshape(-1, 7)  # fmt: skip
        if not np.isfinite(values).all() or (np.linalg.norm(values[:, 3:], axis=1) < 1e-6).any():
            raise ValueError("a pose is not finite, or its quaternion is zero")
        matrices = np.broadcast_to(np.eye(4), (len(values), 4, 4)).copy()
        if len(values):
            matrices[:, :3, :3] = quat_to_matrix(values[:, 3:])
            matrices[:, :3, 3] = values[:, :3]
        stamps = np.array([ns_from_stamp(p.header.stamp) for p in poses], dtype=np.int64)
        self.set_path(stamps, matrices, str(msg.header.frame_id))

    def chain(self, own: Mapping[int, Pose], stamps: Mapping[int, float]) -> Pose | None:
        """``T_fleet_map · T_map_c · own_c⁻¹`` of the newest keyframe ``c`` of ``own`` the back-end corrected: what
        takes a pose of the agent's own map frame (a keyframe newer than the path, the camera now) into the fleet
        frame as the back-end's correction of that keyframe moved it. None while inactive or when no keyframe of
        ``own`` is corrected (a path of another run of the agent)."""
        if self.T_fleet_map is None or not self.corrected:
            return None
        for i in sorted(own, reverse=True):
            corrected = self.corrected.get(stamp_key(stamps[i])) if i in stamps else None
            if corrected is not None:
                return np.asarray(corrected, dtype=np.float64) @ invert(np.asarray(own[i], dtype=np.float64))
        return None
