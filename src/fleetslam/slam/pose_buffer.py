"""A time-ordered buffer of poses with interpolation (wheel odometry looked up at camera stamps)."""

from __future__ import annotations

import bisect

import numpy as np
from numpy.typing import NDArray

from fleetslam.trajectory import interpolated_pose_at


class PoseBuffer:
    """Poses by stamp (seconds), the last ``horizon`` seconds of them."""

    def __init__(self, horizon: float = 5.0, tolerance: float = 0.1) -> None:
        """``tolerance``: how far past the newest (or before the oldest) pose a lookup may be and still get it."""
        self.horizon = horizon
        self.tolerance = tolerance
        self._stamps: list[float] = []
        self._poses: list[NDArray[np.float64]] = []

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_stamp(self) -> float | None:
        """Stamp of the newest pose, or None when empty."""
        return self._stamps[-1] if self._stamps else None

    def clear(self) -> None:
        self._stamps.clear()
        self._poses.clear()

    def add(self, stamp: float, pose: NDArray[np.float64]) -> None:
        """Add a pose; out-of-order stamps are inserted in place, old ones beyond the horizon dropped."""
        index = bisect.bisect_right(self._stamps, stamp)
        self._stamps.insert(index, stamp)
        self._poses.insert(index, np.asarray(pose, np.float64))
        cut = bisect.bisect_left(self._stamps, self._stamps[-1] - self.horizon)
        if cut > 0:
            del self._stamps[:cut]
            del self._poses[:cut]

    def at(self, stamp: float) -> NDArray[np.float64] | None:
        """The pose at ``stamp`` (interpolated between neighbours), or None when outside the buffer."""
        return interpolated_pose_at(self._stamps, self._poses, stamp, self.tolerance)
