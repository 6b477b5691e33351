"""Numba kernels of the octree's voxel table: open addressing with linear probing over packed finest keys, with
float32 log-odds values.

They run serially. I tried a parallel update and rehash (the batch sorted by slot range, the threads taking
ranges from a shared counter): on this 2-core shared machine, the extra passes and the parallel regions' start
and end cost more than the second core saved (the three Kinect scans of the benchmark: 23 ms against 12 ms).
"""

from __future__ import annotations

import numpy as np

from fleetslam._imports import require
from fleetslam.mapping._kernels import EMPTY

numba = require("numba", "mapping")
njit = numba.njit


@njit(cache=True, inline="always")
def _slot(key, mask):  # type: ignore[no-untyped-def]
    # splitmix64 finaliser: spreads the packed key bits over the table.
    h = key
    h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    h = h ^ (h >> np.uint64(31))
    return np.int64(h & mask)


@njit(cache=True, inline="always")
def _probe(keys, key, mask):  # type: ignore[no-untyped-def]
    """The slot holding ``key``, or the empty slot where it goes (linear probing from its home slot)."""
    i = _slot(key, mask)
    while True:
        k = keys[i]
        if k == key or k == EMPTY:  # noqa: SIM109 - plain comparisons compile to two integer compares
            return i
        i = (i + 1) & np.int64(mask)


@njit(cache=True)
def table_find(keys, key):  # type: ignore[no-untyped-def]
    i = _probe(keys, key, np.uint64(keys.shape[0] - 1))
    return i if keys[i] == key else -1


@njit(cache=True)
def table_find_many(keys, queries):  # type: ignore[no-untyped-def]
    out = np.empty(queries.shape[0], dtype=np.int64)
    for j in range(queries.shape[0]):
        out[j] = table_find(keys, queries[j])
    return out


@njit(cache=True)
def table_update(keys, values, updates, deltas, base_values, has_base, clamp_min, clamp_max, touched, room):  # type: ignore[no-untyped-def]
    """Apply one log-odds update per key (OctoMap's updateNode at the finest level).

    A missing key starts from ``base_values[j]`` when ``has_base[j]`` (the value of the pruned leaf it was
    expanded from), else from 0. ``touched[j]`` tells whether key j changed. Stops before adding key number
    ``room + 1`` (the caller grows the table and goes on). Returns (new keys, updates processed).
    """
    mask = np.uint64(keys.shape[0] - 1)
    added = 0
    for j in range(updates.shape[0]):
        key = updates[j]
        delta = deltas[j]
        i = _probe(keys, key, mask)
        if keys[i] == key:
            value = values[i]
            # OctoMap's early abort: already clamped in the update's direction.
            if (delta >= 0 and value >= clamp_max) or (delta <= 0 and value <= clamp_min):
                touched[j] = False
                continue
        else:
            if added == room:
                return added, j
            keys[i] = key
            added += 1
            value = base_values[j] if has_base[j] else np.float32(0.0)
        value = np.float32(value + delta)
        if value < clamp_min:
            value = clamp_min
        elif value > clamp_max:
            value = clamp_max
        values[i] = value
        touched[j] = True
    return added, updates.shape[0]


@njit(cache=True)
def table_add(keys, values, updates, delta, room):  # type: ignore[no-untyped-def]
    """Add ``delta`` to each key's value, unclamped (a missing key starts at 0). Stops before adding key number
    ``room + 1`` (the caller grows the table and goes on). Returns (new keys, updates processed)."""
    mask = np.uint64(keys.shape[0] - 1)
    added = 0
    for j in range(updates.shape[0]):
        key = updates[j]
        i = _probe(keys, key, mask)
        if keys[i] != key:
            if added == room:
                return added, j
            keys[i] = key
            values[i] = 0.0
            added += 1
        values[i] += delta
    return added, updates.shape[0]


@njit(cache=True)
def table_rehash(keys, values, new_keys, new_values):  # type: ignore[no-untyped-def]
    """Insert the table's entries into an empty table (``new_keys`` all EMPTY, a power-of-two size).

    The caller allocates the new table with NumPy, which asks the kernel for huge pages: page faults of a
    fresh multi-megabyte table cost more than the insertions.
    """
    mask = np.uint64(new_keys.shape[0] - 1)
    for i in range(keys.shape[0]):
        key = keys[i]
        if key == EMPTY:
            continue
        j = _slot(key, mask)
        while new_keys[j] != EMPTY:
            j = (j + 1) & np.int64(mask)
        new_keys[j] = key
        new_values[j] = values[i]


@njit(cache=True)
def table_set(keys, values, updates, new_values):  # type: ignore[no-untyped-def]
    """Set values (inserting missing keys); returns the number of new keys."""
    mask = np.uint64(keys.shape[0] - 1)
    added = 0
    for j in range(updates.shape[0]):
        key = updates[j]
        i = _probe(keys, key, mask)
        if keys[i] == EMPTY:
            keys[i] = key
            added += 1
        values[i] = new_values[j]
    return added


@njit(cache=True)
def table_delete(keys, values, dels):  # type: ignore[no-untyped-def]
    """Remove keys (absent ones are skipped) by backward-shift deletion, which keeps every remaining key reachable
    from its home slot without tombstones; returns the number removed."""
    mask = np.uint64(keys.shape[0] - 1)
    imask = np.int64(mask)
    removed = 0
    for j in range(dels.shape[0]):
        key = dels[j]
        i = _probe(keys, key, mask)
        if keys[i] != key:
            continue
        removed += 1
        # Pull later entries of the probe run into the hole when their home slot does not lie after the hole.
        k = i
        while True:
            k = (k + 1) & imask
            other = keys[k]
            if other == EMPTY:
                break
            home = _slot(other, mask)
            # `other` may move to the hole i unless its home lies cyclically in (i, k].
            if (i <= k and i < home <= k) or (i > k and (home > i or home <= k)):
                continue
            keys[i] = other
            values[i] = values[k]
            i = k
        keys[i] = EMPTY
    return removed
