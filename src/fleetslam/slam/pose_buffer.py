"""A time-ordered buffer of poses with interpolation (wheel odometry looked up at camera stamps).

Stamp-sane: a pose stamped more than ``horizon`` away from the buffered ones (one message stamped far in the
future, or a clock that jumped) is held aside instead of evicting every buffered pose. Only ``confirm``
consecutive poses that continue such a jump (each within ``horizon`` of the previous one) replace the buffer: a
restarted simulation's clock is followed after a few messages, one forged stamp changes nothing.
"""

from __future__ import annotations

import bisect

import numpy as np
from numpy.typing import NDArray

from fleetslam.trajectory import interpolated_pose_at


class PoseBuffer:
    """Poses by stamp (seconds), the last ``horizon`` seconds of them."""

    def __init__(self, horizon: float = 5.0, tolerance: float = 0.1, confirm: int = 3) -> None:
        """``tolerance``: how far past the newest (or before the oldest) pose a lookup may be and still get it;
        ``confirm``: poses in a row that a jump of the clock takes to be believed (see the module docstring)."""
        self.horizon = horizon
        self.tolerance = tolerance
        self.confirm = confirm
        self._stamps: list[float] = []
        self._poses: list[NDArray[np.float64]] = []
        self._jump: list[tuple[float, NDArray[np.float64]]] = []
        """Poses after a jump of the clock, waiting for confirmation."""
        self.jumps_ignored = 0
        """Poses held aside as a jump of the clock and never confirmed."""

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_stamp(self) -> float | None:
        """Stamp of the newest pose, or None when empty."""
        return self._stamps[-1] if self._stamps else None

    @property
    def oldest_stamp(self) -> float | None:
        """Stamp of the oldest pose held, or None when empty."""
        return self._stamps[0] if self._stamps else None

    def clear(self) -> None:
        self._stamps.clear()
        self._poses.clear()
        self._jump.clear()

    def add(self, stamp: float, pose: NDArray[np.float64]) -> None:
        """Add a pose; out-of-order stamps are inserted in place, old ones beyond the horizon dropped, and stamps
        far from the buffered ones held aside until confirmed (see the module docstring)."""
        pose = np.asarray(pose, np.float64)
        if self._stamps and not self._stamps[0] - self.horizon <= stamp <= self._stamps[-1] + self.horizon:
            if self._jump and abs(stamp - self._jump[-1][0]) > self.horizon:  # not the same jump: start again
                self.jumps_ignored += len(self._jump)
                self._jump.clear()
            self._jump.append((stamp, pose))
            if len(self._jump) < self.confirm:
                return
            jump, self._jump = self._jump, []
            self.clear()
            for jump_stamp, jump_pose in jump:
                self._insert(jump_stamp, jump_pose)
            return
        if self._jump:  # the clock went on where it was: what was held aside was no jump
            self.jumps_ignored += len(self._jump)
            self._jump.clear()
        self._insert(stamp, pose)

    def _insert(self, stamp: float, pose: NDArray[np.float64]) -> None:
        index = bisect.bisect_right(self._stamps, stamp)
        self._stamps.insert(index, stamp)
        self._poses.insert(index, pose)
        cut = bisect.bisect_left(self._stamps, self._stamps[-1] - self.horizon)
        if cut > 0:
            del self._stamps[:cut]
            del self._poses[:cut]

    def at(self, stamp: float) -> NDArray[np.float64] | None:
        """The pose at ``stamp`` (interpolated between neighbours), or None when outside the buffer."""
        return interpolated_pose_at(self._stamps, self._poses, stamp, self.tolerance)
