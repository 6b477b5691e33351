"""A probabilistic occupancy octree with OctoMap 1.10's semantics, built for speed.

Semantics (see ``shared/specs/octomap_format.md``): each scan's free keys (3D DDA from the sensor origin to each
endpoint, origin voxel in, end voxel out) and occupied keys (endpoints) are collected as sets, occupied wins,
and every voxel is updated once per scan with the miss or hit log-odds, clamped. OctoMap prunes along every
updated path, so its node structure is the canonical maximal pruning of the leaf values; this engine stores the
finest voxels in a hash table (plus coarse leaves read from files or left by :meth:`prune`) and derives that
canonical structure when asked (node counts, leaves, files) — the same nodes, the same bytes.

Speed: rays are traced in parallel (numba, both cores) into a dense scan-local grid, so deduplication costs one
byte write per traversed voxel; only the distinct voxels touch the table.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam._imports import require
from fleetslam.errors import MapFileError
from fleetslam.mapping import _kernels as K
from fleetslam.mapping import _prune_kernels as P
from fleetslam.mapping import _table_kernels as T
from fleetslam.mapping.keys import (
    TREE_DEPTH,
    TREE_MAX_VAL,
    coords_to_keys,
    morton,
    node_centers,
    pack,
    unpack,
)
from fleetslam.mapping.leaves import LeafArrays
from fleetslam.mapping.raycast import cast_ray, scan_keys

numba = require("numba", "mapping")
log = logging.getLogger(__name__)

#: Largest fill of the voxel table, LOAD_NUM / LOAD_DEN, before it doubles. 5/8 rather than 1/2: the table takes
#: about 0.8× the memory (half of it in the Kinect benchmark) for linear probes about 20 % slower.
LOAD_NUM, LOAD_DEN = 5, 8


def logodds(probability: float) -> np.float32:
    """OctoMap's logodds(): float(log(p / (1 - p)))."""
    return np.float32(math.log(probability / (1.0 - probability)))


def probability(log_odds: ArrayLike) -> NDArray[np.float64]:
    """Occupancy probability of log-odds values (OctoMap's probability()), in float64."""
    return 1.0 - 1.0 / (1.0 + np.exp(np.asarray(log_odds, dtype=np.float64)))


@dataclass(frozen=True)
class InsertSummary:
    """What one scan did."""

    points: int
    used: int
    skipped_nonfinite: int
    skipped_out_of_range: int
    free_voxels: int
    occupied_voxels: int


@dataclass(frozen=True)
class _Structure:
    """Canonical pruned tree: leaves (pre-order) and the inner nodes."""

    leaves: LeafArrays
    inner_count: int


class OccupancyOctree:
    """Occupancy octree (OctoMap OcTree semantics and files).

    Args:
        resolution: edge of the finest voxels (m).
        prob_hit, prob_miss: sensor model.
        clamp_min, clamp_max: probability clamping thresholds.
        occupancy_threshold: probability from which a voxel is occupied.
        accelerator: where scans' rays are walked: ``"cpu"``, ``"cuda"`` (a CUDA GPU, required), or ``"auto"``
            (the GPU when numba finds one, else the CPU; a GPU failure falls back to the CPU). Results are
            identical either way.
        track_changes: note the changed voxels for :meth:`pop_changed_keys` (off: a tree nobody pops).
    """

    def __init__(
        self,
        resolution: float,
        *,
        prob_hit: float = 0.7,
        prob_miss: float = 0.4,
        clamp_min: float = 0.1192,
        clamp_max: float = 0.971,
        occupancy_threshold: float = 0.5,
        accelerator: str = "auto",
        track_changes: bool = True,
    ) -> None:
        if not resolution > 0 or not math.isfinite(resolution):
            raise ValueError(f"resolution must be a positive number, got {resolution}")
        if accelerator not in ("auto", "cpu", "cuda"):
            raise ValueError(f"accelerator must be 'auto', 'cpu' or 'cuda', got {accelerator!r}")
        if accelerator == "cuda" and not _cuda_available():
            raise ValueError("accelerator 'cuda' needs a CUDA GPU, and numba finds none")
        self.accelerator = accelerator
        for name, p in (("prob_hit", prob_hit), ("prob_miss", prob_miss), ("clamp_min", clamp_min),
                        ("clamp_max", clamp_max), ("occupancy_threshold", occupancy_threshold)):  # fmt: skip
            if not 0.0 < p < 1.0:
                raise ValueError(f"{name} must be a probability in (0, 1), got {p}")
        self.resolution = float(resolution)
        self.prob_hit, self.prob_miss = prob_hit, prob_miss
        self.clamp_min, self.clamp_max = clamp_min, clamp_max
        self.occupancy_threshold = occupancy_threshold
        self.hit_log = logodds(prob_hit)
        self.miss_log = logodds(prob_miss)
        self.clamp_min_log = logodds(clamp_min)
        self.clamp_max_log = logodds(clamp_max)
        self.threshold_log = logodds(occupancy_threshold)
        self._keys = np.full(1024, K.EMPTY, dtype=np.uint64)
        self._values = np.zeros(1024, dtype=np.float32)
        self._count = 0
        self._coarse: dict[tuple[int, int], np.float32] = {}
        self.track_changes = track_changes
        self._changes: list[NDArray[np.uint64]] = []
        self._pending_changes = 0
        self._structure: _Structure | None = None

    # -- storage ---------------------------------------------------------------------------------------------
    def _reserve(self, extra: int) -> None:
        needed = self._count + extra
        if needed * LOAD_DEN <= self._keys.shape[0] * LOAD_NUM:
            return
        capacity = self._keys.shape[0]
        while needed * LOAD_DEN > capacity * LOAD_NUM:
            capacity *= 2
        keys, values = np.full(capacity, K.EMPTY, dtype=np.uint64), np.empty(capacity, dtype=np.float32)
        T.table_rehash(self._keys, self._values, keys, values)
        self._keys, self._values = keys, values

    def _update_table(
        self, updates: NDArray[np.uint64], deltas: NDArray[np.float32], base: NDArray[np.float32],
        has_base: NDArray[np.bool_],
    ) -> NDArray[np.bool_]:  # fmt: skip
        """One clamped log-odds update per key; grows the table (load ≤ 5/8) only when new keys need it."""
        touched = np.zeros(len(updates), np.bool_)
        start = 0
        while True:
            room = self._keys.shape[0] * LOAD_NUM // LOAD_DEN - self._count
            added, done = T.table_update(
                self._keys, self._values, updates[start:], deltas[start:], base[start:], has_base[start:],
                self.clamp_min_log, self.clamp_max_log, touched[start:], room,
            )  # fmt: skip
            self._count += int(added)
            start += int(done)
            if start >= len(updates):
                return touched
            self._reserve(len(updates) - start)

    # -- insertion -------------------------------------------------------------------------------------------
    def insert_point_cloud(
        self, points: ArrayLike, origin: ArrayLike, max_range: float = -1.0, discretize: bool = False
    ) -> InsertSummary:
        """Integrate one scan (world frame, float32 like OctoMap's point3d), from the sensor at ``origin``.

        Non-finite points and points outside the key range are skipped and counted (one log line per scan).
        """
        pts, free, occ, status = self._scan_update(points, origin, max_range, discretize)
        self._apply(free, occ)
        n_nonfinite = int(np.count_nonzero(status == 1))
        n_out = int(np.count_nonzero(status == 2))
        used = len(pts) - n_nonfinite - n_out
        return InsertSummary(len(pts), used, n_nonfinite, n_out, len(free), len(occ))

    def compute_update(
        self, points: ArrayLike, origin: ArrayLike, max_range: float = -1.0, discretize: bool = False
    ) -> tuple[NDArray[np.uint64], NDArray[np.uint64]]:
        """OctoMap's computeUpdate: the packed finest keys a scan marks free and occupied, each once (occupied
        wins), without changing the tree. :meth:`apply_update` of them is :meth:`insert_point_cloud`."""
        _, free, occ, _ = self._scan_update(points, origin, max_range, discretize)
        return free, occ

    def _scan_update(
        self, points: ArrayLike, origin: ArrayLike, max_range: float, discretize: bool
    ) -> tuple[NDArray[np.float32], NDArray[np.uint64], NDArray[np.uint64], NDArray[np.uint8]]:
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float32).reshape(-1, 3))
        origin32 = np.ascontiguousarray(np.asarray(origin, dtype=np.float32).reshape(3))
        if not np.isfinite(origin32).all() or not coords_to_keys(origin32, self.resolution)[1][0]:
            raise ValueError(f"sensor origin {origin32.tolist()} is outside the map's key range")
        if discretize and len(pts):
            keys, valid = coords_to_keys(pts, self.resolution)
            _, first = np.unique(pack(keys[valid]), return_index=True)
            centres = (keys[valid][np.sort(first)] - TREE_MAX_VAL + 0.5) * self.resolution
            invalid = pts[~valid]
            pts = np.ascontiguousarray(np.vstack([centres.astype(np.float32), invalid]))
        free, occ, status = self._scan_keys(pts, origin32, float(max_range))
        n_nonfinite = int(np.count_nonzero(status == 1))
        n_out = int(np.count_nonzero(status == 2))
        if n_nonfinite or n_out:
            log.info("scan: skipped %d non-finite and %d out-of-range points of %d", n_nonfinite, n_out, len(pts))
        return pts, free, occ, status

    def apply_update(self, free: NDArray[np.uint64], occupied: NDArray[np.uint64]) -> None:
        """One scan's evidence (keys from :meth:`compute_update`): a miss for each free voxel, a hit for each
        occupied one, clamped (OctoMap's insertPointCloud after computeUpdate)."""
        self._apply(free, occupied)

    def forget(self, packed: NDArray[np.uint64]) -> int:
        """Make finest voxels (packed keys) unknown again; returns how many were known. A voxel inside a pruned
        leaf splits it first, as an update would."""
        packed = np.ascontiguousarray(packed, dtype=np.uint64)
        split = 0
        if self._coarse:
            for key in packed[T.table_find_many(self._keys, packed) < 0].tolist():
                found = self._coarse_containing(key)
                if found is not None:
                    self._split(found, key, self._coarse[found])  # the siblings keep its value; the key is gone
                    split += 1
        removed = int(T.table_delete(self._keys, self._values, packed))
        self._count -= removed
        if removed or split:
            self._record_changes(packed)
            self._structure = None
        return removed + split

    def assign(self, packed: NDArray[np.uint64], log_odds: NDArray[np.floating]) -> None:
        """Set finest voxels (packed keys) to log-odds values, clamped; NaN makes a voxel unknown."""
        packed = np.ascontiguousarray(packed, dtype=np.uint64)
        values = np.asarray(log_odds, dtype=np.float32)
        unknown = np.isnan(values)
        if unknown.any():
            self.forget(packed[unknown])
            packed, values = packed[~unknown], values[~unknown]
        if not len(packed):
            return
        if self._coarse:  # split the pruned leaves holding them: their other voxels keep the leaf's value
            for key in packed[T.table_find_many(self._keys, packed) < 0].tolist():
                found = self._coarse_containing(key)
                if found is not None:
                    self._split(found, key, self._coarse[found])
        self._reserve(len(packed))
        clamped = np.clip(values, self.clamp_min_log, self.clamp_max_log).astype(np.float32)
        self._count += int(T.table_set(self._keys, self._values, packed, clamped))
        self._record_changes(packed)
        self._structure = None

    def _scan_keys(
        self, points: NDArray[np.float32], origin: NDArray[np.float32], max_range: float
    ) -> tuple[NDArray[np.uint64], NDArray[np.uint64], NDArray[np.uint8]]:
        if self.accelerator == "cpu" or not _cuda_available():
            return scan_keys(points, origin, self.resolution, max_range)
        try:
            return scan_keys(points, origin, self.resolution, max_range, use_cuda=True)
        except Exception as err:
            if self.accelerator == "cuda":
                raise
            log.warning("GPU ray tracing failed (%s: %s); this map goes on with the CPU", type(err).__name__, err)
            self.accelerator = "cpu"
            return scan_keys(points, origin, self.resolution, max_range)

    def _apply(self, free: NDArray[np.uint64], occupied: NDArray[np.uint64]) -> None:
        updates = np.concatenate([free, occupied])
        if len(updates) == 0:
            return
        deltas = np.concatenate(
            [np.full(len(free), self.miss_log, np.float32), np.full(len(occupied), self.hit_log, np.float32)]
        )
        self._update_keys(updates, deltas)

    def _update_keys(self, updates: NDArray[np.uint64], deltas: NDArray[np.float32]) -> None:
        """One log-odds update per finest key (pruned leaves expanded first), recorded in the change set."""
        base = np.zeros(len(updates), np.float32)
        has_base = np.zeros(len(updates), np.bool_)
        if self._coarse:
            keep = self._expand_coarse(updates, deltas, base, has_base)
            updates, deltas, base, has_base = updates[keep], deltas[keep], base[keep], has_base[keep]
        touched = self._update_table(updates, deltas, base, has_base)
        self._record_changes(updates[touched])
        self._structure = None

    def _record_changes(self, packed: NDArray[np.uint64]) -> None:
        """Note changed voxels for :meth:`pop_changed_keys`; merged once they outnumber the stored voxels, so a
        tree nobody pops keeps at most about two entries per voxel."""
        if not self.track_changes or not len(packed):
            return
        self._changes.append(packed)
        self._pending_changes += len(packed)
        if self._pending_changes > max(1 << 16, 2 * self._count):
            self._changes = [np.unique(np.concatenate(self._changes))]
            self._pending_changes = len(self._changes[0])

    def _coarse_containing(self, packed: int) -> tuple[int, int] | None:
        x, y, z = (packed >> 32) & 0xFFFF, (packed >> 16) & 0xFFFF, packed & 0xFFFF
        for depth in range(TREE_DEPTH - 1, -1, -1):
            shift = TREE_DEPTH - depth
            code = ((x >> shift) << 32) | ((y >> shift) << 16) | (z >> shift)
            if (depth, code) in self._coarse:
                return depth, code
        return None

    def _expand_coarse(
        self, updates: NDArray[np.uint64], deltas: NDArray[np.float32], base: NDArray[np.float32],
        has_base: NDArray[np.bool_],
    ) -> NDArray[np.bool_]:  # fmt: skip
        """Updates inside pruned leaves: early abort when clamped, else expand the leaf along the key's path."""
        keep = np.ones(len(updates), np.bool_)
        fine_known = T.table_find_many(self._keys, updates) >= 0
        for j in np.flatnonzero(~fine_known):
            packed = int(updates[j])
            found = self._coarse_containing(packed)
            if found is None:
                continue
            value = self._coarse[found]
            delta = deltas[j]
            if (delta >= 0 and value >= self.clamp_max_log) or (delta <= 0 and value <= self.clamp_min_log):
                keep[j] = False
                continue
            self._split(found, packed, value)
            base[j], has_base[j] = value, True
        return keep

    def _split(self, leaf: tuple[int, int], packed: int, value: np.float32) -> None:
        """OctoMap's expandNode along the path to ``packed``: 7 siblings per level keep the leaf's value."""
        depth, _ = leaf
        del self._coarse[leaf]
        x, y, z = (packed >> 32) & 0xFFFF, (packed >> 16) & 0xFFFF, packed & 0xFFFF
        siblings_fine: list[int] = []
        for level in range(depth + 1, TREE_DEPTH + 1):
            shift = TREE_DEPTH - level
            px, py, pz = (x >> shift) & ~1, (y >> shift) & ~1, (z >> shift) & ~1
            on_path = ((x >> shift) & 1, (y >> shift) & 1, (z >> shift) & 1)
            for child in range(8):
                bits = (child & 1, (child >> 1) & 1, (child >> 2) & 1)
                if bits == on_path:
                    continue
                code = ((px | bits[0]) << 32) | ((py | bits[1]) << 16) | (pz | bits[2])
                if level == TREE_DEPTH:
                    siblings_fine.append(code)
                else:
                    self._coarse[(level, code)] = value
        if siblings_fine:
            self._reserve(len(siblings_fine))
            sib = np.array(siblings_fine, dtype=np.uint64)
            self._count += T.table_set(self._keys, self._values, sib, np.full(len(sib), value, np.float32))

    # -- canonical structure ------------------------------------------------------------------------------------
    def _canonical(self) -> _Structure:
        if self._structure is None:
            fine_morton, fine_values = P.table_morton(self._keys, self._values, numba.get_num_threads())
            items = list(self._coarse.items())
            self._structure = _collapse(
                fine_morton,
                fine_values,
                np.array([d for (d, _), _ in items], np.int64),
                np.array([c for (_, c), _ in items], np.uint64),
                np.array([v for _, v in items], np.float32),
            )
        return self._structure

    def leaves(self) -> LeafArrays:
        """Leaves of the canonical (pruned) tree, in pre-order."""
        return self._canonical().leaves

    def num_nodes(self) -> int:
        """Number of nodes (inner and leaves), as OctoMap's size()."""
        s = self._canonical()
        return s.inner_count + len(s.leaves)

    def num_leaf_nodes(self) -> int:
        return len(self._canonical().leaves)

    def memory_bytes(self) -> int:
        """Bytes held by the voxel store (table arrays and pruned leaves)."""
        return int(self._keys.nbytes + self._values.nbytes + 64 * len(self._coarse))

    def prune(self) -> None:
        """Store the canonical pruned tree (frees memory; later updates expand pruned leaves as OctoMap does)."""
        leaves = self.leaves()
        self._load_leaves(leaves)

    def _load_leaves(self, leaves: LeafArrays) -> None:
        fine = leaves.depths == TREE_DEPTH
        keys = pack(leaves.keys[fine])
        self._count = 0
        self._keys = np.full(1024, K.EMPTY, dtype=np.uint64)
        self._values = np.zeros(1024, dtype=np.float32)
        self._reserve(len(keys))
        self._count = T.table_set(self._keys, self._values, keys, leaves.log_odds[fine])
        self._coarse = {}
        coarse_idx = np.flatnonzero(~fine)
        for i in coarse_idx:
            depth = int(leaves.depths[i])
            shift = TREE_DEPTH - depth
            kx, ky, kz = (int(v) >> shift for v in leaves.keys[i])
            self._coarse[(depth, (kx << 32) | (ky << 16) | kz)] = np.float32(leaves.log_odds[i])
        self._structure = None

    @classmethod
    def from_leaves(cls, resolution: float, leaves: LeafArrays, **sensor_model: Any) -> OccupancyOctree:
        tree = cls(resolution, **sensor_model)
        tree._load_leaves(leaves)
        return tree

    def copy(self) -> OccupancyOctree:
        other = OccupancyOctree(
            self.resolution, prob_hit=self.prob_hit, prob_miss=self.prob_miss, clamp_min=self.clamp_min,
            clamp_max=self.clamp_max, occupancy_threshold=self.occupancy_threshold, accelerator=self.accelerator,
        )  # fmt: skip
        other._keys, other._values, other._count = self._keys.copy(), self._values.copy(), self._count
        other._coarse = dict(self._coarse)
        return other

    # -- queries -----------------------------------------------------------------------------------------------
    def _values_at(self, packed: NDArray[np.uint64]) -> NDArray[np.float64]:
        """Log-odds of the leaves holding packed finest keys (NaN = unknown)."""
        idx = T.table_find_many(self._keys, packed)
        values = np.where(idx >= 0, self._values[np.maximum(idx, 0)], np.nan).astype(np.float64)
        if self._coarse:
            for j in np.flatnonzero(idx < 0):
                found = self._coarse_containing(int(packed[j]))
                if found is not None:
                    values[j] = float(self._coarse[found])
        return values

    def voxel_log_odds(self, packed: ArrayLike) -> NDArray[np.float64]:
        """Log-odds of finest voxels given by packed keys (NaN: unknown)."""
        return self._values_at(np.ascontiguousarray(packed, dtype=np.uint64))

    def log_odds(self, xyz: ArrayLike) -> float | NDArray[np.float64] | None:
        """Log-odds at points: a float (None if unknown) for one point ``(3,)``, an array (NaN = unknown) for
        ``(N, 3)``."""
        pts = np.asarray(xyz, dtype=np.float64)
        single = pts.ndim == 1
        keys, valid = coords_to_keys(pts.reshape(-1, 3), self.resolution)
        out = np.full(len(keys), np.nan)
        out[valid] = self._values_at(pack(keys[valid]))
        if single:
            return None if np.isnan(out[0]) else float(out[0])
        return out

    def is_occupied(self, xyz: ArrayLike) -> bool | NDArray[np.bool_]:
        """Occupied (log-odds ≥ threshold); unknown counts as not occupied."""
        values = self.log_odds(np.asarray(xyz, dtype=np.float64).reshape(-1, 3))
        assert isinstance(values, np.ndarray)
        occupied = np.nan_to_num(values, nan=-np.inf) >= self.threshold_log
        return bool(occupied[0]) if np.asarray(xyz).ndim == 1 else occupied

    def _centers(self, occupied: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        leaves = self.leaves()
        mask = (leaves.log_odds >= self.threshold_log) == occupied
        centres = node_centers(leaves.keys[mask], leaves.depths[mask], self.resolution)
        sizes = self.resolution * np.power(2.0, TREE_DEPTH - leaves.depths[mask].astype(np.float64))
        return centres, sizes

    def occupied_centers(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Centres and edge lengths of occupied leaves."""
        return self._centers(True)

    def free_centers(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Centres and edge lengths of free leaves."""
        return self._centers(False)

    def metric_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Min and max corner of all known space (OctoMap's getMetricMin and getMetricMax; zeros for an empty tree)."""
        leaves = self.leaves()
        if len(leaves) == 0:
            return np.zeros(3), np.zeros(3)
        size = np.power(2.0, TREE_DEPTH - leaves.depths.astype(np.float64))[:, None]
        lo = (leaves.keys.astype(np.float64) - TREE_MAX_VAL) * self.resolution
        return lo.min(axis=0), (lo + size * self.resolution).max(axis=0)

    def pop_changed_keys(self) -> NDArray[np.uint16]:
        """Finest keys ``(K, 3)`` of the voxels whose value changed since the last pop (for incremental viewers)."""
        if not self._changes:
            return np.zeros((0, 3), np.uint16)
        changed = np.unique(np.concatenate(self._changes))
        self._changes = []
        self._pending_changes = 0
        return unpack(changed)

    def pop_changes(self) -> NDArray[np.float64]:
        """Centres ``(K, 3)`` of the finest voxels whose value changed since the last pop."""
        return (self.pop_changed_keys().astype(np.float64) - TREE_MAX_VAL + 0.5) * self.resolution

    # -- editing -------------------------------------------------------------------------------------------------
    def clear_bbox(self, bbox_min: ArrayLike, bbox_max: ArrayLike) -> int:
        """Set every known leaf inside the box to clamp_min (octomap_server's clear_bbx); returns how many."""
        lo = np.asarray(bbox_min, dtype=np.float64)
        hi = np.asarray(bbox_max, dtype=np.float64)
        leaves = self.leaves()
        centres = node_centers(leaves.keys, leaves.depths, self.resolution)
        inside = ((centres >= lo) & (centres <= hi)).all(axis=1)
        if not inside.any():
            return 0
        values = leaves.log_odds.copy()
        values[inside] = self.clamp_min_log
        self._load_leaves(LeafArrays(leaves.keys, leaves.depths, values))
        fine = inside & (leaves.depths == TREE_DEPTH)
        self._record_changes(pack(leaves.keys[fine]))
        return int(inside.sum())

    def merge(self, other: OccupancyOctree, transform: ArrayLike | None = None) -> None:
        """Add another tree's finest-level evidence (log-odds added, clamped), moved by a 4×4 ``transform``.

        Pruned leaves of ``other`` are expanded to their finest voxels first; the same resolution is required.
        """
        if abs(other.resolution - self.resolution) > 1e-12:
            raise ValueError(f"cannot merge a {other.resolution} m tree into a {self.resolution} m tree")
        leaves = other.leaves()
        keys, values = _expand_to_finest(leaves)
        centres = (keys.astype(np.float64) - TREE_MAX_VAL + 0.5) * self.resolution
        if transform is not None:
            t = np.asarray(transform, dtype=np.float64)
            centres = centres @ t[:3, :3].T + t[:3, 3]
        new_keys, valid = coords_to_keys(centres.astype(np.float32), self.resolution)
        packed = pack(new_keys[valid])
        values = values[valid]
        # Several source voxels can land in one target voxel after rotation: keep the strongest evidence.
        order = np.argsort(-np.abs(values), kind="stable")
        packed, first = np.unique(packed[order], return_index=True)
        self._update_keys(packed, values[order][first].astype(np.float32))

    def to_max_likelihood(self, in_place: bool = False) -> OccupancyOctree:
        """Leaves set to clamp_max if occupied else clamp_min (OctoMap's toMaxLikelihood), then pruned.

        Works on a copy, which is returned, unless ``in_place`` (then ``self`` is changed and returned).
        """
        leaves = self.leaves()
        values = np.where(leaves.log_odds >= self.threshold_log, self.clamp_max_log, self.clamp_min_log)
        tree = self if in_place else self.copy()
        tree._load_leaves(LeafArrays(leaves.keys, leaves.depths, values.astype(np.float32)))
        tree.prune()
        return tree

    def cast_ray(
        self, origin: ArrayLike, direction: ArrayLike, max_range: float = -1.0, ignore_unknown: bool = False
    ) -> NDArray[np.float64] | None:
        """Centre of the first occupied voxel along a ray, or None (OctoMap castRay: an occupied origin voxel is
        the hit; stops at unknown space unless ``ignore_unknown``; ``max_range`` <= 0 means unlimited)."""
        return cast_ray(
            origin, direction, self.resolution, lambda keys: self._values_at(pack(keys)), float(self.threshold_log),
            max_range=max_range, ignore_unknown=ignore_unknown,
        )  # fmt: skip

    # -- files -------------------------------------------------------------------------------------------------
    def write_binary(self, path: str | Path) -> int:
        """Write a `.bt` file as OctoMap's writeBinary() does (max-likelihood, pruned), leaving this tree as is;
        returns the number of nodes in the file."""
        from fleetslam.mapping.octomap_io import write_bt

        return write_bt(
            path,
            self.resolution,
            self.leaves(),
            clamp_min_log_odds=float(self.clamp_min_log),
            clamp_max_log_odds=float(self.clamp_max_log),
            occupancy_threshold_log_odds=float(self.threshold_log),
        )

    def write(self, path: str | Path) -> int:
        """Write a full `.ot` file (every node's log-odds); returns the number of nodes in the file."""
        from fleetslam.mapping.octomap_io import write_ot

        return write_ot(path, self.resolution, self.leaves())

    @classmethod
    def read(cls, path: str | Path, **sensor_model: Any) -> OccupancyOctree:
        """Read a `.bt` or `.ot` file."""
        from fleetslam.mapping.octomap_io import read_octree_file

        tree = cls(1.0, **sensor_model)
        octree_file = read_octree_file(
            path, clamp_min_log_odds=float(tree.clamp_min_log), clamp_max_log_odds=float(tree.clamp_max_log)
        )
        if octree_file.tree_id != "OcTree":
            raise MapFileError(f"{path}: tree type {octree_file.tree_id} is not supported (OcTree only)")
        return cls.from_leaves(octree_file.resolution, octree_file.leaves, **sensor_model)


def _expand_to_finest(leaves: LeafArrays) -> tuple[NDArray[np.uint16], NDArray[np.float32]]:
    fine = leaves.depths == TREE_DEPTH
    keys = [leaves.keys[fine]]
    values = [leaves.log_odds[fine]]
    for i in np.flatnonzero(~fine):
        size = 1 << (TREE_DEPTH - int(leaves.depths[i]))
        if size > 64:
            raise ValueError(f"refusing to expand a pruned leaf of {size}³ voxels; prune() the source less coarsely")
        grid = np.stack(np.meshgrid(*(np.arange(size),) * 3, indexing="ij"), -1).reshape(-1, 3)
        keys.append((leaves.keys[i].astype(np.int64) + grid).astype(np.uint16))
        values.append(np.full(len(grid), leaves.log_odds[i], np.float32))
    return np.concatenate(keys), np.concatenate(values)


def _cuda_available() -> bool:
    from fleetslam.mapping.cuda_trace import cuda_available

    return cuda_available()


def _collapse(
    fine_morton: NDArray[np.uint64],
    fine_values: NDArray[np.float32],
    coarse_depths: NDArray[np.int64],
    coarse_codes: NDArray[np.uint64],
    coarse_values: NDArray[np.float32],
) -> _Structure:
    """Canonical maximal pruning of a leaf field and its inner-node count: finest leaves by Morton code, coarse
    leaves by depth, packed key at that depth, and value."""
    sorted_morton, sorted_values = P.radix_sort_pairs48(fine_morton, fine_values, numba.get_num_threads())
    coarse_morton = morton(unpack(coarse_codes)) if len(coarse_codes) else np.zeros(0, np.uint64)
    coarse_order = np.lexsort((coarse_morton, coarse_depths))
    codes, depths, values, inner = P.collapse_levels(
        sorted_morton, sorted_values, coarse_morton[coarse_order],
        np.asarray(coarse_depths, np.int64)[coarse_order], np.asarray(coarse_values, np.float32)[coarse_order],
    )  # fmt: skip
    return _Structure(LeafArrays(P.unmorton_keys(codes), depths, values), int(inner))
