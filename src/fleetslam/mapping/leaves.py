"""The leaves of an occupancy octree as arrays: the exchange format between the engine and file IO."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fleetslam.mapping.keys import morton


@dataclass(frozen=True)
class LeafArrays:
    """Leaves sorted in pre-order (Morton order of their min corner).

    Attributes:
        keys: ``(N, 3)`` uint16, finest-level key of each leaf's min corner.
        depths: ``(N,)`` uint8, 16 for a finest voxel, less for a pruned (coarser) leaf.
        log_odds: ``(N,)`` float32.
    """

    keys: NDArray[np.uint16]
    depths: NDArray[np.uint8]
    log_odds: NDArray[np.float32]

    def __len__(self) -> int:
        return int(self.depths.shape[0])

    @classmethod
    def empty(cls) -> LeafArrays:
        return cls(np.zeros((0, 3), np.uint16), np.zeros(0, np.uint8), np.zeros(0, np.float32))

    @classmethod
    def sorted(
        cls, keys: NDArray[np.integer], depths: NDArray[np.integer], log_odds: NDArray[np.floating]
    ) -> LeafArrays:
        """Leaves in pre-order, whatever order they came in."""
        keys = np.asarray(keys, dtype=np.uint16).reshape(-1, 3)
        order = np.argsort(morton(keys), kind="stable")
        return cls(
            np.ascontiguousarray(keys[order]),
            np.asarray(depths, dtype=np.uint8)[order],
            np.asarray(log_odds, dtype=np.float32)[order],
        )
