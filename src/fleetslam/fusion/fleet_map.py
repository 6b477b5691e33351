"""The fleet's global map: every agent's occupancy octree moved into the fleet frame and fused.

Each agent maps in its own `map` frame. Its transform into the fleet frame comes from its known start pose, from the
fleet back-end's joint optimisation (:mod:`fleetslam.fusion.fleet_graph`), or from the agent's own pairwise-consistent
inter-agent closures (:mod:`fleetslam.fusion.collaboration`). An agent's voxel lands in the fleet voxel that
holds its moved centre; where several land in one, the strongest evidence counts (:mod:`fleetslam.fusion._kernels`).
Fusion adds the agents' log-odds evidence voxel by voxel (in agent name order, clamped), as if one robot had made
all the observations; an agent's latest map replaces its previous one, so re-optimised agent maps never leave
doubled walls in the fleet map.

The fused map is kept up to date incrementally: a new agent map is compared with the previous one leaf by leaf, and
only the fleet voxels that its changed voxels land in are fused again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleetslam.fusion import _kernels as F
from fleetslam.mapping import _prune_kernels as P
from fleetslam.mapping.keys import TREE_DEPTH, pack
from fleetslam.mapping.leaves import LeafArrays
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.mapping.voxel_table import VoxelTable


def _expand(
    codes: NDArray[np.uint64], depths: NDArray[np.uint8], values: NDArray[np.float32]
) -> tuple[NDArray[np.uint64], NDArray[np.float32]]:
    """Finest Morton codes (ascending, for leaves in pre-order) and values of every voxel of the leaves: a leaf at
    depth d holds the 8^(16-d) codes from its own on."""
    sizes = np.left_shift(1, 3 * (TREE_DEPTH - depths.astype(np.int64)))
    firsts = np.cumsum(sizes) - sizes
    offsets = np.arange(int(sizes.sum()), dtype=np.int64) - np.repeat(firsts, sizes)
    return np.repeat(codes, sizes) + offsets.astype(np.uint64), np.repeat(values, sizes)


@dataclass(frozen=True)
class _Leaves:
    """A tree's leaves by the Morton code of their min corner (ascending: pre-order), depth and value."""

    codes: NDArray[np.uint64]
    depths: NDArray[np.uint8]
    log_odds: NDArray[np.float32]

    @classmethod
    def of(cls, leaves: LeafArrays) -> _Leaves:
        return cls(P.morton_keys(np.ascontiguousarray(leaves.keys)), leaves.depths, leaves.log_odds)

    def __len__(self) -> int:
        return len(self.codes)


_NO_LEAVES = _Leaves(np.zeros(0, np.uint64), np.zeros(0, np.uint8), np.zeros(0, np.float32))


def _changed_voxels(old: _Leaves, new: _Leaves) -> tuple[NDArray[np.uint64], NDArray[np.float32]]:
    """Finest voxels (packed keys) whose value differs between two trees' leaves, with their new values (NaN:
    unknown now). Leaves found unchanged in both are skipped whole; only the others are expanded."""
    old_codes, new_codes = old.codes, new.codes
    same = np.zeros(len(new_codes), np.bool_)
    kept = np.zeros(len(old_codes), np.bool_)
    if len(old_codes):
        idx = np.minimum(np.searchsorted(old_codes, new_codes), len(old_codes) - 1)
        same = (old_codes[idx] == new_codes) & (old.depths[idx] == new.depths) & (old.log_odds[idx] == new.log_odds)
        kept[idx[same]] = True
    gone_codes, gone_values = _expand(old_codes[~kept], old.depths[~kept], old.log_odds[~kept])
    came_codes, came_values = _expand(new_codes[~same], new.depths[~same], new.log_odds[~same])
    # A voxel in both: its leaf changed (a value, or only how the tree is pruned around it).
    differs = np.ones(len(came_codes), np.bool_)
    still = np.zeros(len(gone_codes), np.bool_)
    if len(gone_codes):
        at = np.minimum(np.searchsorted(gone_codes, came_codes), len(gone_codes) - 1)
        in_both = gone_codes[at] == came_codes
        still[at[in_both]] = True
        differs = ~in_both | (gone_values[at] != came_values)
    codes = np.concatenate([came_codes[differs], gone_codes[~still]])
    values = np.concatenate([came_values[differs], np.full(int((~still).sum()), np.nan, np.float32)])
    return pack(P.unmorton_keys(codes)), values.astype(np.float32)


@dataclass
class _Agent:
    transform: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    leaves: _Leaves = _NO_LEAVES
    source: VoxelTable = field(default_factory=VoxelTable)
    """Its map's voxels in its own frame."""
    contribution: VoxelTable | None = None
    """What lands in each fleet voxel (None: the transform keeps voxels where they are, ``source`` serves)."""

    @property
    def in_fleet(self) -> VoxelTable:
        return self.source if self.contribution is None else self.contribution


def _is_grid_identity(transform: NDArray[np.float64]) -> bool:
    return bool(np.array_equal(transform, np.eye(4)))


@dataclass
class FleetMap:
    """Latest map and fleet transform per agent; the fused map kept up to date as they change."""

    resolution: float
    _agents: dict[str, _Agent] = field(default_factory=dict)
    _fused: OccupancyOctree | None = None
    fused_voxel_updates: int = 0
    """Fleet voxels fused again so far (the incremental work done)."""

    @property
    def transforms(self) -> dict[str, NDArray[np.float64]]:
        return {name: agent.transform for name, agent in self._agents.items()}

    def _fused_tree(self) -> OccupancyOctree:
        if self._fused is None:
            self._fused = OccupancyOctree(self.resolution, track_changes=False)
        return self._fused

    def set_transform(self, agent: str, t_fleet_map: NDArray[np.float64]) -> None:
        """Where the agent's map frame sits in the fleet frame (4×4); its whole map lands anew."""
        state = self._agents.setdefault(agent, _Agent())
        state.transform = np.asarray(t_fleet_map, dtype=np.float64)
        before = state.in_fleet.items()[0]
        if _is_grid_identity(state.transform):
            state.contribution = None
        else:
            state.contribution = VoxelTable()
            keys, values = state.source.items()
            targets = F.forward_keys(keys, state.transform, self.resolution)
            inside = targets != F.EMPTY
            targets, values = targets[inside], values[inside]
            # Strongest evidence per fleet voxel: sorted by voxel, then |value| and value, descending.
            order = np.lexsort((-values, -np.abs(values), targets))
            first = np.ones(len(order), np.bool_)
            first[1:] = targets[order][1:] != targets[order][:-1]
            state.contribution.set(targets[order][first], values[order][first])
        self._fuse_again(np.union1d(before, state.in_fleet.items()[0]))

    def update_agent(self, agent: str, tree: OccupancyOctree) -> None:
        """Replace an agent's map with its latest version."""
        if abs(tree.resolution - self.resolution) > 1e-12:
            raise ValueError(
                f"agent {agent}: map resolution {tree.resolution} differs from the fleet's {self.resolution}"
            )
        self.update_agent_leaves(agent, tree.leaves())

    def update_agent_leaves(self, agent: str, leaves: LeafArrays) -> int:
        """Replace an agent's map (its leaves in pre-order, at the fleet's resolution) with its latest version;
        returns how many of its voxels changed."""
        state = self._agents.setdefault(agent, _Agent())
        new = _Leaves.of(leaves)
        keys, values = _changed_voxels(state.leaves, new)
        state.leaves = new
        known = ~np.isnan(values)
        state.source.set(keys[known], values[known])
        state.source.delete(keys[~known])
        if state.contribution is None:
            self._fuse_again(keys)
        else:
            inverse = np.linalg.inv(state.transform)
            targets = np.unique(F.forward_keys(keys, state.transform, self.resolution))
            targets = targets[targets != F.EMPTY]
            best = F.strongest_sources(targets, state.transform, inverse, *state.source.slots, self.resolution)
            landed = ~np.isnan(best)
            state.contribution.set(targets[landed], best[landed])
            state.contribution.delete(targets[~landed])
            self._fuse_again(targets)
        return len(keys)

    def _fuse_again(self, targets: NDArray[np.uint64]) -> None:
        """Fuse the agents' evidence again in these fleet voxels: in agent order, each adds its value, clamped."""
        if not len(targets):
            return
        fused = self._fused_tree()
        total = np.full(len(targets), np.nan, np.float32)
        for name in self.agents():
            value = self._agents[name].in_fleet.get(targets)
            has = ~np.isnan(value)
            summed = np.float32(np.nan_to_num(total[has], nan=0.0)) + value[has]
            total[has] = np.clip(summed, fused.clamp_min_log, fused.clamp_max_log)
        fused.assign(targets, total)
        self.fused_voxel_updates += len(targets)

    def agents(self) -> list[str]:
        """Agents with a map, by name (the order of fusion)."""
        return sorted(name for name, agent in self._agents.items() if len(agent.leaves))

    def fused(self) -> OccupancyOctree:
        """The fleet map (kept up to date; do not edit it)."""
        return self._fused_tree()
