"""RGB-D sequences as scans for the octree: each depth image back-projected at its camera pose.

A sequence is a TUM RGB-D folder, a simulator export or an MCAP recording of camera topics (the loaders of
:mod:`fleetslam.datasets`); the poses come from a TUM trajectory of camera poses ``T_world_camera`` (optical
frame: x right, y down, z forward), e.g. ``fleetslam slam run``'s ``trajectory.txt`` or a ground truth,
matched to each frame by the nearest stamp within ``max_difference`` (TUM's 0.02 s). Scans are produced
lazily, one frame at a time, so a long sequence never sits in memory.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from fleetslam.datasets.base import RGBDSource
from fleetslam.errors import DatasetError
from fleetslam.mapping.keyframe_mapper import depth_to_points
from fleetslam.mapping.scan_io import ScanNode
from fleetslam.trajectory import Trajectory


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
    """Frames without a trajectory pose within ``max_difference``."""


def rgbd_scans(
    source: RGBDSource,
    trajectory: Trajectory,
    *,
    max_difference: float = 0.02,
    every: int = 1,
    pixel_step: int = 4,
    min_depth: float = 0.3,
    max_depth: float = 6.0,
    counts: RgbdScanCounts | None = None,
) -> Iterator[ScanNode]:
    """One :class:`ScanNode` (camera-frame points, pose world ← camera) per used frame of ``source``."""
    if every < 1 or pixel_step < 1:
        raise DatasetError(f"every ({every}) and pixel_step ({pixel_step}) must be at least 1")
    if len(trajectory) == 0:
        raise DatasetError(f"{source.name}: the trajectory has no poses")
    stats = counts if counts is not None else RgbdScanCounts()
    k = source.intrinsics
    order = np.argsort(trajectory.stamps)
    stamps = trajectory.stamps[order]
    for frame in source:
        stats.frames += 1
        if (stats.frames - 1) % every:
            stats.skipped_every += 1
            continue
        index = int(np.searchsorted(stamps, frame.stamp))
        candidates = [i for i in (index - 1, index) if 0 <= i < len(stamps)]
        nearest = min(candidates, key=lambda i: abs(stamps[i] - frame.stamp))
        if abs(stamps[nearest] - frame.stamp) > max_difference:
            stats.unmatched += 1
            continue
        points = depth_to_points(
            frame.depth, k.fx, k.fy, k.cx, k.cy, stride=pixel_step, min_depth=min_depth, max_depth=max_depth
        )
        stats.used += 1
        yield ScanNode(frame.index, np.asarray(trajectory.poses[order[nearest]], np.float64), points)
