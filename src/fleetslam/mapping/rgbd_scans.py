"""RGB-D sequences as scans for the octree: each depth image back-projected at its camera pose.

A sequence is a TUM RGB-D folder, a simulator export or an MCAP recording of camera topics (the loaders of
:mod:`fleetslam.datasets`). The poses are camera poses ``T_world_camera`` of the camera's optical frame (x right,
y down, z forward), the convention of ``fleetslam slam run``'s ``trajectory.txt``, of TUM's and the simulator's
``groundtruth.txt``: either a TUM trajectory matched to each frame by the nearest stamp within
``max_difference`` (TUM's 0.02 s), or, without one, the poses the frames carry themselves (ground truth, else the
wheel-odometry prior ``T_odom_camera``). The sensor origin of each scan is the camera centre. Scans are produced
lazily, one frame at a time, so a long sequence never sits in memory.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import RGBDFrame, RGBDSource, open_source
from fleetslam.errors import ConfigError, DatasetError
from fleetslam.mapping.keyframe_mapper import depth_to_points
from fleetslam.mapping.scan_io import ScanNode
from fleetslam.trajectory import NearestPose, Trajectory, read_tum

log = logging.getLogger(__name__)

#: where a frame's own pose may come from, in order of preference (fields of :class:`RGBDFrame`).
FRAME_POSE_FIELDS = ("groundtruth", "prior")


@dataclass
class RgbdScanCounts:
    """What :func:`rgbd_scans` used and skipped (filled while iterating)."""

    frames: int = 0
    """Frames read from the source."""
    used: int = 0
    """Frames turned into scans."""
    skipped_every: int = 0
    """Frames left out by ``every``."""
    unmatched: int = 0
    """Frames without a pose (none within ``max_difference`` in the trajectory, or none of their own)."""
    points: int = 0
    """Points of the scans produced."""
    frame_pose_field: str | None = None
    """Without a trajectory: the frame field the poses came from (``groundtruth`` or ``prior``)."""


def _check_options(every: int, pixel_step: int, max_difference: float, min_depth: float, max_depth: float) -> None:
    if every < 1:
        raise ConfigError(f"every: must be at least 1, got {every}")
    if pixel_step < 1:
        raise ConfigError(f"pixel_step: must be at least 1, got {pixel_step}")
    if not max_difference >= 0:
        raise ConfigError(f"max_difference: must be >= 0 s, got {max_difference}")
    if not 0 <= min_depth < max_depth:
        raise ConfigError(f"min_depth/max_depth: need 0 <= min_depth < max_depth, got {min_depth} and {max_depth}")


def _frame_pose(frame: RGBDFrame, counts: RgbdScanCounts, source_name: str) -> NDArray[np.float64] | None:
    # One field for the whole sequence: ground truth and odometry live in different frames and must not mix.
    if counts.frame_pose_field is None:
        counts.frame_pose_field = next((f for f in FRAME_POSE_FIELDS if getattr(frame, f) is not None), None)
        if counts.frame_pose_field is None:
            raise ConfigError(
                f"{source_name}: no trajectory given, the sequence has no ground truth and its frames carry no "
                f"pose ({' or '.join(FRAME_POSE_FIELDS)}); give the camera poses with --trajectory"
            )
        if counts.frame_pose_field == "prior":
            log.warning(
                "%s: using the frames' wheel-odometry poses (T_odom_camera): the map is in the odometry frame and "
                "drifts with it; give --trajectory for better poses",
                source_name,
            )
    pose = getattr(frame, counts.frame_pose_field)
    return None if pose is None else np.asarray(pose, np.float64)


def rgbd_scans(
    source: RGBDSource,
    trajectory: Trajectory | None,
    *,
    max_difference: float = 0.02,
    every: int = 1,
    pixel_step: int = 4,
    min_depth: float = 0.3,
    max_depth: float = 6.0,
    counts: RgbdScanCounts | None = None,
    name: str | None = None,
) -> Iterator[ScanNode]:
    """One :class:`ScanNode` (camera-frame points, pose ``T_world_camera``) per used frame of ``source``.

    Args:
        source: the frames (read lazily).
        trajectory: camera poses ``T_world_camera`` (optical frame), each frame taking the pose of the nearest
            stamp within ``max_difference`` seconds; ``None``: each frame's own ground truth, else its prior.
        every: use every ``every``-th frame (the first one included).
        pixel_step: back-project every ``pixel_step``-th pixel of every ``pixel_step``-th row.
        min_depth, max_depth: depths (m) outside this range are dropped.
        counts: filled while iterating (frames used and skipped).
        name: the sequence in error messages (default ``source.name``).

    Raises:
        ConfigError: an option out of range; no trajectory and the first frame carries no pose of its own.
        DatasetError: the trajectory is empty.
    """
    _check_options(every, pixel_step, max_difference, min_depth, max_depth)
    stats = counts if counts is not None else RgbdScanCounts()
    name = name or source.name
    lookup: NearestPose | None = None
    if trajectory is not None:
        if len(trajectory) == 0:
            raise DatasetError(f"{name}: the trajectory has no poses")
        lookup = NearestPose(trajectory, max_difference)
    k = source.intrinsics
    for frame in source.frames(every):  # the frames in between are not even read
        stats.skipped_every += frame.index - stats.frames
        stats.frames = frame.index + 1
        pose = lookup(frame.stamp) if lookup is not None else _frame_pose(frame, stats, name)
        if pose is None:
            stats.unmatched += 1
            continue
        points = depth_to_points(
            frame.depth, k.fx, k.fy, k.cx, k.cy, stride=pixel_step, min_depth=min_depth, max_depth=max_depth
        )
        stats.used += 1
        stats.points += len(points)
        yield ScanNode(frame.index, pose, points)
    stats.skipped_every += max(0, len(source) - stats.frames)
    stats.frames = max(stats.frames, len(source))


@dataclass
class RgbdSequenceScans:
    """The scans of an opened RGB-D sequence; iterate once. ``len()`` is the number of frames of the source.

    Iteration raises :class:`DatasetError` at the end when no frame got a pose, naming where the poses came from.
    """

    source: RGBDSource
    trajectory: Trajectory | None
    poses_from: str
    """Where the poses come from, for messages (a file, or the sequence's ground truth or own poses)."""
    name: str
    """The sequence in messages (its path)."""
    max_difference: float = 0.02
    every: int = 1
    pixel_step: int = 4
    min_depth: float = 0.3
    max_depth: float = 6.0
    counts: RgbdScanCounts = field(default_factory=RgbdScanCounts)

    def __len__(self) -> int:
        return len(self.source)

    def __iter__(self) -> Iterator[ScanNode]:
        yield from rgbd_scans(
            self.source,
            self.trajectory,
            max_difference=self.max_difference,
            every=self.every,
            pixel_step=self.pixel_step,
            min_depth=self.min_depth,
            max_depth=self.max_depth,
            counts=self.counts,
            name=self.name,
        )
        if self.counts.used == 0:
            tolerance = f" within {self.max_difference} s" if self.trajectory is not None else ""
            hint = " (do the stamps use the same clock?)" if self.trajectory is not None else ""
            raise DatasetError(
                f"{self.name}: none of its {self.counts.frames} frames has a pose{tolerance} in {self.poses_from}{hint}"
            )

    def skipped_summary(self) -> str | None:
        """One line on the frames skipped for want of a pose, or None when every frame read had one."""
        if not self.counts.unmatched:
            return None
        where = f"within {self.max_difference} s in" if self.trajectory is not None else "in"
        return (
            f"{self.name}: {self.counts.unmatched} of {self.counts.frames} frames skipped, no pose {where} "
            f"{self.poses_from}"
        )


def open_rgbd_scans(
    path: str | Path,
    *,
    kind: str | None = None,
    trajectory: str | Path | None = None,
    max_difference: float = 0.02,
    every: int = 1,
    pixel_step: int = 4,
    min_depth: float = 0.3,
    max_depth: float = 6.0,
) -> RgbdSequenceScans:
    """Open an RGB-D sequence (``kind`` ``tum``/``sim``/``mcap``, or guessed from ``path``) as lazy scans.

    Poses: the TUM file ``trajectory`` when given, else the sequence's ground truth, else the frames' own poses
    (checked on the first frame).

    Raises:
        ConfigError: an option out of range.
        DatasetError: the sequence or trajectory file is missing or malformed.
    """
    _check_options(every, pixel_step, max_difference, min_depth, max_depth)
    source = open_source(path, kind=kind)
    poses: Trajectory | None
    if trajectory is not None:
        poses, poses_from = read_tum(trajectory), str(trajectory)
    else:
        poses = source.groundtruth()
        poses_from = f"the ground truth of {path}" if poses is not None else f"the frames of {path}"
    return RgbdSequenceScans(
        source,
        poses,
        poses_from,
        str(path),
        max_difference=max_difference,
        every=every,
        pixel_step=pixel_step,
        min_depth=min_depth,
        max_depth=max_depth,
    )
