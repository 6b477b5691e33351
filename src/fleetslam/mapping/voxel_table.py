"""A hash table from finest voxels (packed keys) to one float32 each: the octree's table kernels without the
occupancy semantics, for bookkeeping beside a map (how many scans saw a voxel, an agent's evidence per voxel).

Open addressing with linear probing, at most 5/8 full (the octree's load factor); deletion shifts entries back, so
no tombstones pile up.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.mapping import _kernels as K
from fleetslam.mapping import _table_kernels as T
from fleetslam.mapping.octree import LOAD_DEN, LOAD_NUM


class VoxelTable:
    """Packed finest keys → float32 values."""

    def __init__(self) -> None:
        self._keys: NDArray[np.uint64] = np.full(1024, K.EMPTY, dtype=np.uint64)
        self._values: NDArray[np.float32] = np.zeros(1024, dtype=np.float32)
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def _reserve(self, extra: int) -> None:
        needed = self._count + extra
        capacity = self._keys.shape[0]
        if needed * LOAD_DEN <= capacity * LOAD_NUM:
            return
        while needed * LOAD_DEN > capacity * LOAD_NUM:
            capacity *= 2
        keys, values = np.full(capacity, K.EMPTY, dtype=np.uint64), np.empty(capacity, dtype=np.float32)
        T.table_rehash(self._keys, self._values, keys, values)
        self._keys, self._values = keys, values

    def get(self, packed: ArrayLike) -> NDArray[np.float32]:
        """Values of keys, NaN where absent."""
        idx = T.table_find_many(self._keys, np.ascontiguousarray(packed, dtype=np.uint64))
        return np.where(idx >= 0, self._values[np.maximum(idx, 0)], np.float32(np.nan)).astype(np.float32)

    def set(self, packed: ArrayLike, values: ArrayLike) -> None:
        """Insert or overwrite (the last of repeated keys wins)."""
        keys = np.ascontiguousarray(packed, dtype=np.uint64)
        self._reserve(len(keys))
        self._count += int(T.table_set(self._keys, self._values, keys, np.ascontiguousarray(values, np.float32)))

    def add(self, packed: ArrayLike, delta: float) -> None:
        """Add ``delta`` to each key's value (absent keys start at 0)."""
        keys = np.ascontiguousarray(packed, dtype=np.uint64)
        self._reserve(len(keys))
        room = self._keys.shape[0] * LOAD_NUM // LOAD_DEN - self._count
        added, done = T.table_add(self._keys, self._values, keys, np.float32(delta), room)
        assert done == len(keys)  # reserved above
        self._count += int(added)

    def delete(self, packed: ArrayLike) -> int:
        """Remove keys (absent ones are skipped); returns how many were present."""
        removed = int(T.table_delete(self._keys, self._values, np.ascontiguousarray(packed, dtype=np.uint64)))
        self._count -= removed
        return removed

    @property
    def slots(self) -> tuple[NDArray[np.uint64], NDArray[np.float32]]:
        """The open-addressing arrays (keys, EMPTY where free; values), for kernels that probe the table with
        :func:`fleetslam.mapping._table_kernels.table_find`; valid until the table changes."""
        return self._keys, self._values

    def items(self) -> tuple[NDArray[np.uint64], NDArray[np.float32]]:
        """Every key and its value, in slot order."""
        filled = self._keys != K.EMPTY
        return self._keys[filled], self._values[filled]

    def clear(self) -> None:
        """Remove every key."""
        self._keys = np.full(1024, K.EMPTY, dtype=np.uint64)
        self._values = np.zeros(1024, dtype=np.float32)
        self._count = 0
