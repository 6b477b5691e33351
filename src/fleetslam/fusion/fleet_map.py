"""The fleet's global map: every agent's occupancy octree moved into the fleet frame and fused.

Each agent maps in its own `map` frame. Its transform into the fleet frame comes from its known start pose, or
from inter-agent loop closures (:mod:`fleetslam.fusion.alignment`). Fusion adds the agents' log-odds evidence voxel
by voxel (clamped), as if one robot had made all the observations; an agent's latest map replaces its previous
one, so re-optimised agent maps never leave doubled walls in the fleet map.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleetslam.mapping.octree import OccupancyOctree


@dataclass
class FleetMap:
    """Latest map and fleet transform per agent; fuses on demand."""

    resolution: float
    transforms: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    maps: dict[str, OccupancyOctree] = field(default_factory=dict)
    _fused: OccupancyOctree | None = None

    def set_transform(self, agent: str, t_fleet_map: NDArray[np.float64]) -> None:
        """Where the agent's map frame sits in the fleet frame (4×4)."""
        self.transforms[agent] = np.asarray(t_fleet_map, dtype=np.float64)
        self._fused = None

    def update_agent(self, agent: str, tree: OccupancyOctree) -> None:
        """Replace an agent's map with its latest version."""
        if abs(tree.resolution - self.resolution) > 1e-12:
            raise ValueError(
                f"agent {agent}: map resolution {tree.resolution} differs from the fleet's {self.resolution}"
            )
        self.maps[agent] = tree
        self._fused = None

    def agents(self) -> list[str]:
        return sorted(self.maps)

    def fused(self) -> OccupancyOctree:
        """The fleet map (cached until an agent's map or transform changes)."""
        if self._fused is None:
            fused = OccupancyOctree(self.resolution)
            for agent in self.agents():
                transform = self.transforms.get(agent, np.eye(4))
                identity = np.allclose(transform, np.eye(4))
                fused.merge(self.maps[agent], None if identity else transform)
            self._fused = fused
        return self._fused
