"""Trajectories as stamped poses, and their TUM file format (``timestamp tx ty tz qx qy qz qw``)."""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fleetslam.errors import DatasetError
from fleetslam.geometry import interpolate_pose, pose_from_quat, pose_to_quat


@dataclass(frozen=True)
class Trajectory:
    """Stamped poses: ``stamps (N,)`` seconds and ``poses (N, 4, 4)`` as ``T_world_frame``."""

    stamps: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __post_init__(self) -> None:
        if self.stamps.shape[0] != self.poses.shape[0] or self.poses.shape[1:] != (4, 4):
            raise ValueError(
                f"trajectory needs stamps (N,) and poses (N,4,4), got {self.stamps.shape} and {self.poses.shape}"
            )

    def __len__(self) -> int:
        return int(self.stamps.shape[0])

    @property
    def positions(self) -> NDArray[np.float64]:
        """``(N, 3)`` positions."""
        return self.poses[:, :3, 3]

    @classmethod
    def from_lists(cls, stamps: Sequence[float], poses: Iterable[NDArray[np.float64]]) -> Trajectory:
        pose_list = [np.asarray(p, dtype=np.float64) for p in poses]
        arr = np.stack(pose_list) if pose_list else np.zeros((0, 4, 4))
        return cls(np.asarray(stamps, dtype=np.float64), arr)


class NearestPose:
    """The pose of a trajectory nearest to a stamp, within ``max_difference`` seconds (stamps sorted once; an
    exact tie goes to the earlier stamp)."""

    def __init__(self, trajectory: Trajectory, max_difference: float) -> None:
        self._order = np.argsort(trajectory.stamps, kind="stable")
        self._stamps = trajectory.stamps[self._order]
        self._poses = trajectory.poses
        self._max_difference = max_difference

    def __call__(self, stamp: float) -> NDArray[np.float64] | None:
        index = int(np.searchsorted(self._stamps, stamp))
        candidates = [i for i in (index - 1, index) if 0 <= i < len(self._stamps)]
        if not candidates:
            return None
        nearest = min(candidates, key=lambda i: abs(self._stamps[i] - stamp))
        if abs(self._stamps[nearest] - stamp) > self._max_difference:
            return None
        return np.asarray(self._poses[self._order[nearest]], np.float64)


def interpolated_pose_at(
    stamps: Sequence[float] | NDArray[np.float64],
    poses: Sequence[NDArray[np.float64]] | NDArray[np.float64],
    stamp: float,
    tolerance: float,
    max_gap: float = math.inf,
) -> NDArray[np.float64] | None:
    """The pose at ``stamp`` of poses sorted by stamp, interpolated between its neighbours; None where they are
    more than ``max_gap`` seconds apart. Before the first or after the last pose: the end pose within
    ``tolerance`` seconds, else None."""
    n = len(stamps)
    if n == 0:
        return None
    index = bisect.bisect_left(stamps, stamp)
    if index == 0 or index == n:
        end = 0 if index == 0 else n - 1
        return np.array(poses[end], np.float64) if abs(stamps[end] - stamp) <= tolerance else None
    t0, t1 = float(stamps[index - 1]), float(stamps[index])
    if t1 - t0 > max_gap:
        return None
    fraction = 0.0 if t1 <= t0 else (stamp - t0) / (t1 - t0)
    return interpolate_pose(poses[index - 1], poses[index], fraction)


class InterpolatedPose:
    """:func:`interpolated_pose_at` over a trajectory (sorted once): for a trajectory sampled faster than it is
    looked up, such as odometry at camera stamps."""

    def __init__(self, trajectory: Trajectory, max_gap: float, tolerance: float) -> None:
        order = np.argsort(trajectory.stamps, kind="stable")
        self._stamps = trajectory.stamps[order]
        self._poses = trajectory.poses[order]
        self._max_gap = max_gap
        self._tolerance = tolerance

    def __call__(self, stamp: float) -> NDArray[np.float64] | None:
        return interpolated_pose_at(self._stamps, self._poses, stamp, self._tolerance, self._max_gap)


def tum_line(stamp: float, pose: NDArray[np.float64], digits: int = 6) -> str:
    """One TUM line, ``stamp tx ty tz qx qy qz qw`` and a newline; the stamp with 6 decimals (µs), the pose with
    ``digits``."""
    t, q = pose_to_quat(pose)
    return f"{stamp:.6f} {' '.join(f'{v:.{digits}f}' for v in (*t, *q))}\n"


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    """Write a trajectory in TUM format (one ``stamp tx ty tz qx qy qz qw`` line per pose)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", encoding="utf-8") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        f.writelines(tum_line(stamp, pose) for stamp, pose in zip(trajectory.stamps, trajectory.poses, strict=True))


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory; comment lines (``#``) and blank lines are skipped.

    Raises:
        DatasetError: naming the file and line when a line is not 8 numbers.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: trajectory file not found")
    stamps: list[float] = []
    poses: list[NDArray[np.float64]] = []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as err:
        byte = err.object[err.start]
        raise DatasetError(f"{path}: not UTF-8 text (byte 0x{byte:02x} at offset {err.start})") from err
    for lineno, line in enumerate(lines, start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        try:
            values = [float(v) for v in fields]
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: not a number in TUM line {line!r}") from err
        if len(values) != 8:
            raise DatasetError(f"{path}:{lineno}: expected 8 values (stamp tx ty tz qx qy qz qw), got {len(values)}")
        stamps.append(values[0])
        poses.append(pose_from_quat(values[1:4], values[4:8]))
    return Trajectory.from_lists(stamps, poses)
