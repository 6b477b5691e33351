"""What a peer agent needs of a keyframe to recognise a shared place and verify it, in a few kilobytes.

A full keyframe carries its colour and depth images (~80 kB on the wire); inter-agent place recognition needs
only the features: where each keypoint is in the image, how far it is (its 3D point follows from the pixel, the
depth and the intrinsics) and its descriptor. A summary keeps the features that have a depth, at most
``max_features`` of them spread over the image, with pixels quantised to 1/8 px (``uint16``) and depth to the
millimetre (``uint16``): 4 + 2 + 32 = 38 bytes per ORB feature, ~15 kB for 400 features, against 60 bytes per
feature as float32 in the full keyframe.

Bag-of-words vectors are deliberately not sent: each agent grows its own vocabulary (word ids mean nothing to
another agent), so the receiver quantises the peer's descriptors with its own vocabulary.

The functions here are pure; :func:`summary_from_message` validates a received message field by field (a
hostile or corrupt one raises :class:`~fleetslam.errors.MessageError` naming the field and value).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics
from fleetslam.errors import MessageError
from fleetslam.intrinsics import pinhole_problem

KEYPOINT_SUBPIXELS = 8
"""Keypoints are sent in 1/8 pixel: the rounding error (≤ 1/16 px) is far below a keypoint's own noise."""
MAX_DEPTH_MM = 65_535
"""Largest depth a summary can carry (``uint16`` millimetres)."""
MAX_SUMMARY_FEATURES = 4096
"""A received summary with more features is refused (a sender keeps far fewer; a hostile one could send millions)."""
MAX_IMAGE_SIDE = 8191
"""Largest image side a summary can carry (``uint16`` keypoints in 1/8 px)."""


@dataclass(frozen=True)
class KeyframeSummary:
    """One keyframe of one agent, as exchanged between agents."""

    agent: str
    keyframe_id: int
    stamp_ns: int
    pose: NDArray[np.float64]
    """``T_map_camera`` in the sending agent's map frame when the keyframe was made."""
    intrinsics: Intrinsics
    keypoints: NDArray[np.float32]
    """``(N, 2)`` pixel coordinates (u, v)."""
    depth: NDArray[np.float32]
    """``(N,)`` depth along the optical axis (m); every feature has one."""
    descriptors: NDArray[np.uint8]
    """``(N, D)`` binary descriptors."""
    epoch: int = 0
    """The sending SLAM run (its graph's epoch): a new one means the agent restarted with a new map frame."""

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])

    @property
    def points3d(self) -> NDArray[np.float32]:
        """``(N, 3)`` feature points in the camera optical frame."""
        k = self.intrinsics
        x = (self.keypoints[:, 0] - k.cx) / k.fx * self.depth
        y = (self.keypoints[:, 1] - k.cy) / k.fy * self.depth
        return np.column_stack([x, y, self.depth]).astype(np.float32)


def spread_selection(keypoints: NDArray[np.floating], count: int, width: int, height: int) -> NDArray[np.intp]:
    """Indices of at most ``count`` keypoints spread over the image: a 8×6 grid of cells is visited round-robin,
    taking each cell's features in their given order (extractors list stronger ones first). Deterministic."""
    n = keypoints.shape[0]
    if n <= count:
        return np.arange(n, dtype=np.intp)
    cols, rows = 8, 6
    u = np.clip((keypoints[:, 0] * cols / max(width, 1)).astype(np.int64), 0, cols - 1)
    v = np.clip((keypoints[:, 1] * rows / max(height, 1)).astype(np.int64), 0, rows - 1)
    cell = v * cols + u
    # Rank of each feature within its cell (0 for the first listed), then take ranks 0, 1, 2... across cells.
    order = np.argsort(cell, kind="stable")
    sorted_cells = cell[order]
    starts = np.searchsorted(sorted_cells, sorted_cells, side="left")
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n) - starts
    chosen = np.lexsort((np.arange(n), rank))[:count]
    return np.sort(chosen).astype(np.intp)


def summarize(
    agent: str,
    keyframe_id: int,
    stamp_ns: int,
    pose: NDArray[np.float64],
    intrinsics: Intrinsics,
    keypoints: NDArray[np.floating],
    points3d: NDArray[np.floating],
    descriptors: NDArray[np.uint8],
    *,
    max_features: int = 400,
    epoch: int = 0,
) -> KeyframeSummary:
    """The summary of a keyframe: its features with a depth the summary can carry, at most ``max_features``
    spread over the image, quantised as they will be on the wire (so sender and receiver see the same values)."""
    if descriptors.dtype != np.uint8:
        raise ValueError(f"summaries carry binary descriptors (uint8), got {descriptors.dtype}")
    keypoints = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    points3d = np.asarray(points3d, dtype=np.float64).reshape(-1, 3)
    depth = points3d[:, 2]
    inside = (
        (keypoints[:, 0] >= 0) & (keypoints[:, 1] >= 0)
        & (keypoints[:, 0] < MAX_IMAGE_SIDE) & (keypoints[:, 1] < MAX_IMAGE_SIDE)
    )  # fmt: skip
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(depth) & (depth >= 0.001) & (depth * 1000.0 <= MAX_DEPTH_MM) & inside
    index = np.flatnonzero(usable)
    index = index[spread_selection(keypoints[index], max_features, intrinsics.width, intrinsics.height)]
    quantised_uv = np.round(keypoints[index] * KEYPOINT_SUBPIXELS) / KEYPOINT_SUBPIXELS
    quantised_depth = np.round(depth[index] * 1000.0) / 1000.0
    return KeyframeSummary(
        agent=agent,
        keyframe_id=int(keyframe_id),
        stamp_ns=int(stamp_ns),
        pose=np.asarray(pose, dtype=np.float64).copy(),
        intrinsics=intrinsics,
        keypoints=quantised_uv.astype(np.float32),
        depth=quantised_depth.astype(np.float32),
        descriptors=np.ascontiguousarray(descriptors[index]),
        epoch=int(epoch),
    )


def summary_fields(summary: KeyframeSummary) -> dict[str, Any]:
    """The message fields of ``fleetslam_msgs/KeyframeSummary`` but ``header`` and ``pose`` (which the node
    builds with the middleware's helpers)."""
    k = summary.intrinsics
    uv = np.round(summary.keypoints.astype(np.float64) * KEYPOINT_SUBPIXELS)
    return {
        "agent": summary.agent,
        "id": summary.keyframe_id,
        "intrinsics": np.array([k.fx, k.fy, k.cx, k.cy], dtype=np.float64),
        "width": int(k.width),
        "height": int(k.height),
        "keypoints": np.clip(uv, 0, 65_535).astype(np.uint16).reshape(-1),
        "depth_mm": np.clip(np.round(summary.depth.astype(np.float64) * 1000.0), 0, MAX_DEPTH_MM).astype(np.uint16),
        "descriptor_length": int(summary.descriptors.shape[1]) if summary.descriptors.ndim == 2 else 0,
        "descriptors": np.ascontiguousarray(summary.descriptors, dtype=np.uint8).reshape(-1),
        "epoch": int(summary.epoch),
    }


def summary_from_message(msg: Any, pose: NDArray[np.float64], stamp_ns: int) -> KeyframeSummary:
    """A summary from a received ``fleetslam_msgs/KeyframeSummary`` (``pose`` and ``stamp_ns`` already
    converted by the caller). Every field is checked; a bad one raises :class:`MessageError` naming it."""
    agent = str(msg.agent)
    where = f"KeyframeSummary from {agent!r} (keyframe {int(msg.id)})"
    intrinsics_values = np.asarray(msg.intrinsics, dtype=np.float64).reshape(-1)
    if intrinsics_values.shape != (4,):
        raise MessageError(f"{where}: intrinsics must be four numbers, got {intrinsics_values.tolist()}")
    fx, fy, cx, cy = (float(v) for v in intrinsics_values)
    if problem := pinhole_problem(fx, fy, cx, cy):
        raise MessageError(f"{where}: intrinsics: {problem}")
    width, height = int(msg.width), int(msg.height)
    if not (0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE):
        raise MessageError(f"{where}: image size {width}x{height} is not in 1..{MAX_IMAGE_SIDE}")
    if not np.isfinite(pose).all():
        raise MessageError(f"{where}: pose is not finite")
    keypoints = np.asarray(msg.keypoints, dtype=np.uint16).reshape(-1)
    depth_mm = np.asarray(msg.depth_mm, dtype=np.uint16).reshape(-1)
    descriptors = np.asarray(msg.descriptors, dtype=np.uint8).reshape(-1)
    length = int(msg.descriptor_length)
    count = depth_mm.shape[0]
    if count > MAX_SUMMARY_FEATURES:
        raise MessageError(f"{where}: {count} features, more than {MAX_SUMMARY_FEATURES}")
    if keypoints.shape[0] != 2 * count:
        raise MessageError(f"{where}: {keypoints.shape[0]} keypoint values for {count} depths (need {2 * count})")
    if count and not 1 <= length <= 256:
        raise MessageError(f"{where}: descriptor_length {length} is not in 1..256")
    if descriptors.shape[0] != count * length:
        raise MessageError(f"{where}: {descriptors.shape[0]} descriptor bytes for {count} features of {length} bytes")
    if np.any(depth_mm == 0):
        raise MessageError(f"{where}: a feature has depth 0 (every feature in a summary has a depth)")
    return KeyframeSummary(
        agent=agent,
        keyframe_id=int(msg.id),
        stamp_ns=int(stamp_ns),
        pose=np.asarray(pose, dtype=np.float64),
        intrinsics=Intrinsics(fx, fy, cx, cy, width, height),
        keypoints=(keypoints.reshape(count, 2).astype(np.float32) / np.float32(KEYPOINT_SUBPIXELS)).astype(np.float32),
        depth=depth_mm.astype(np.float32) / 1000.0,
        descriptors=descriptors.reshape(count, length if count else 0).copy(),
        epoch=int(msg.epoch),
    )
