"""Typed configuration of the occupancy mapping: resolution, sensor model, ray limits.

Defaults are OctoMap 1.10's library defaults (clamping 0.1192 / 0.971); octomap_server uses 0.12 / 0.97.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pydantic import Field, model_validator

from fleetslam.config import ConfigModel

if TYPE_CHECKING:
    from fleetslam.mapping.octree import OccupancyOctree


class MappingConfig(ConfigModel):
    """Occupancy octree and scan integration (OctoMap semantics)."""

    resolution: float = Field(default=0.05, gt=0.0)
    """Edge of the finest voxels, m."""
    prob_hit: float = Field(default=0.7, gt=0.5, lt=1.0)
    """Occupancy probability applied to a voxel holding a measured endpoint."""
    prob_miss: float = Field(default=0.4, gt=0.0, lt=0.5)
    """Occupancy probability applied to a voxel a measurement ray passes through."""
    clamp_min: float = Field(default=0.1192, gt=0.0, lt=1.0)
    """Lower clamping probability: a voxel never gets less certain of being free than this."""
    clamp_max: float = Field(default=0.971, gt=0.0, lt=1.0)
    """Upper clamping probability: a voxel never gets more certain of being occupied than this."""
    occupancy_threshold: float = Field(default=0.5, gt=0.0, lt=1.0)
    """Probability from which a voxel counts as occupied."""
    max_range: float = -1.0
    """Longer rays are cut here and only clear space, m; negative means unlimited."""
    min_range: float = -1.0
    """Points nearer to the sensor are ignored (octomap_server's min_range), m; negative disables."""
    discretize: bool = False
    """Merge endpoints falling in one voxel and cast rays to voxel centres (OctoMap's discretize)."""
    prune_every: int = Field(default=0, ge=0)
    """Compact the store into the pruned tree every N scans (0: never; node counts are unaffected)."""
    accelerator: Literal["auto", "cpu", "cuda"] = "auto"
    """Where rays are walked: the GPU when one is found ("auto"), always the CPU, or a required CUDA GPU; the map
    is identical either way."""

    @model_validator(mode="after")
    def _clamps_ordered(self) -> MappingConfig:
        if not self.clamp_min < self.occupancy_threshold < self.clamp_max:
            raise ValueError(
                f"need clamp_min < occupancy_threshold < clamp_max, got {self.clamp_min}, "
                f"{self.occupancy_threshold}, {self.clamp_max}"
            )
        return self


def make_octree(config: MappingConfig, *, track_changes: bool = True) -> OccupancyOctree:
    """An empty octree with the configured resolution and sensor model (``track_changes``: see the octree)."""
    from fleetslam.mapping.octree import OccupancyOctree

    return OccupancyOctree(
        config.resolution,
        prob_hit=config.prob_hit,
        prob_miss=config.prob_miss,
        clamp_min=config.clamp_min,
        clamp_max=config.clamp_max,
        occupancy_threshold=config.occupancy_threshold,
        accelerator=config.accelerator,
        track_changes=track_changes,
    )
