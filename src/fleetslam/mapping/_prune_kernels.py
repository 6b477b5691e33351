"""Numba kernels of the canonical (maximally pruned) tree: table compaction and Morton radix sort (both in
parallel), and the bottom-up collapse of equal siblings, level by level over Morton-sorted arrays.

A node's children are a contiguous run of the Morton-sorted codes one level down (the code without its last
three bits is the parent's), so every level is one linear pass; no tree of pointers is built.
"""

from __future__ import annotations

import numpy as np

from fleetslam._imports import require
from fleetslam.mapping._kernels import EMPTY
from fleetslam.mapping.keys import TREE_DEPTH

numba = require("numba", "mapping")
njit, prange = numba.njit, numba.prange


@njit(cache=True, inline="always")
def _spread3(v):  # type: ignore[no-untyped-def]
    # keys._spread3 on one 16-bit scalar (that one is NumPy array code for up to 21 bits).
    v = v & np.uint64(0xFFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


@njit(cache=True, parallel=True)
def table_morton(keys, values, chunks):  # type: ignore[no-untyped-def]
    """Morton codes (x → bit 0, y → bit 1, z → bit 2 of each triple) and values of the table's filled slots, in
    slot order; ``chunks`` parts of the table in parallel."""
    n_slots = keys.shape[0]
    size = (n_slots + chunks - 1) // chunks
    starts = np.zeros(chunks + 1, dtype=np.int64)
    for c in prange(chunks):
        filled = 0
        for i in range(c * size, min(n_slots, (c + 1) * size)):
            if keys[i] != EMPTY:
                filled += 1
        starts[c + 1] = filled
    for c in range(chunks):
        starts[c + 1] += starts[c]
    codes = np.empty(starts[chunks], dtype=np.uint64)
    out_values = np.empty(starts[chunks], dtype=np.float32)
    mask = np.uint64(0xFFFF)
    for c in prange(chunks):
        j = starts[c]
        for i in range(c * size, min(n_slots, (c + 1) * size)):
            k = keys[i]
            if k == EMPTY:
                continue
            x = (k >> np.uint64(32)) & mask
            y = (k >> np.uint64(16)) & mask
            z = k & mask
            codes[j] = _spread3(x) | (_spread3(y) << np.uint64(1)) | (_spread3(z) << np.uint64(2))
            out_values[j] = values[i]
            j += 1
    return codes, out_values


@njit(cache=True, parallel=True)
def radix_sort_pairs48(codes, values, chunks):  # type: ignore[no-untyped-def]
    """48-bit codes sorted ascending with their values (any 1-D array; stable LSD radix sort, three 16-bit
    digits). With ``np.arange(n)`` as the values it is an argsort.

    Each pass counts the digits of ``chunks`` parts of the input in parallel, then scatters the parts in parallel
    to disjoint places. Moving the values along costs less than sorting indices and gathering afterwards.
    """
    n = codes.shape[0]
    keys = codes.copy()
    vals = values.copy()
    next_keys = np.empty(n, dtype=np.uint64)
    next_vals = np.empty_like(values)
    size = (n + chunks - 1) // chunks
    places = np.empty((chunks, 65536), dtype=np.int64)
    digit_mask = np.uint64(0xFFFF)
    for shift in (0, 16, 32):
        s = np.uint64(shift)
        for c in prange(chunks):
            for d in range(65536):
                places[c, d] = 0
            for i in range(c * size, min(n, (c + 1) * size)):
                places[c, np.int64((keys[i] >> s) & digit_mask)] += 1
        # Exclusive prefix by (digit, part): part c's codes of a digit follow those of parts < c (stable).
        total = 0
        for d in range(65536):
            for c in range(chunks):
                count = places[c, d]
                places[c, d] = total
                total += count
        for c in prange(chunks):
            for i in range(c * size, min(n, (c + 1) * size)):
                digit = np.int64((keys[i] >> s) & digit_mask)
                j = places[c, digit]
                places[c, digit] = j + 1
                next_keys[j] = keys[i]
                next_vals[j] = vals[i]
        keys, next_keys = next_keys, keys
        vals, next_vals = next_vals, vals
    return keys, vals


@njit(cache=True, inline="always")
def _compact3(v):  # type: ignore[no-untyped-def]
    # keys._compact3 on one code (the inverse of _spread3).
    v = v & np.uint64(0x1249249249249249)
    v = (v ^ (v >> np.uint64(2))) & np.uint64(0x10C30C30C30C30C3)
    v = (v ^ (v >> np.uint64(4))) & np.uint64(0x100F00F00F00F00F)
    v = (v ^ (v >> np.uint64(8))) & np.uint64(0x1F0000FF0000FF)
    v = (v ^ (v >> np.uint64(16))) & np.uint64(0x1F00000000FFFF)
    return v


@njit(cache=True)
def unmorton_keys(codes):  # type: ignore[no-untyped-def]
    """``(N, 3)`` uint16 keys of Morton codes: :func:`fleetslam.mapping.keys.unmorton` in one pass (the NumPy
    version makes a dozen passes over the arrays, 25× slower)."""
    out = np.empty((codes.shape[0], 3), dtype=np.uint16)
    for i in range(codes.shape[0]):
        c = codes[i]
        out[i, 0] = _compact3(c)
        out[i, 1] = _compact3(c >> np.uint64(1))
        out[i, 2] = _compact3(c >> np.uint64(2))
    return out


@njit(cache=True)
def morton_keys(keys):  # type: ignore[no-untyped-def]
    """Morton codes of ``(N, 3)`` keys: :func:`fleetslam.mapping.keys.morton` in one pass."""
    out = np.empty(keys.shape[0], dtype=np.uint64)
    for i in range(keys.shape[0]):
        out[i] = (
            _spread3(np.uint64(keys[i, 0]))
            | (_spread3(np.uint64(keys[i, 1])) << np.uint64(1))
            | (_spread3(np.uint64(keys[i, 2])) << np.uint64(2))
        )
    return out


@njit(cache=True)
def collapse_levels(fine_codes, fine_values, coarse_codes, coarse_depths, coarse_values):  # type: ignore[no-untyped-def]
    """Canonical pruning: OctoMap's pruneNode (8 children, all leaves, equal values) applied bottom-up.

    ``fine_codes`` are sorted finest Morton codes; coarse leaves are given by their Morton code at their own depth,
    sorted by (depth, code). Returns the final leaves — Morton code of their min corner at the finest level,
    depth, value — in pre-order, and the number of inner nodes (each counted where a run of children that does
    not collapse makes its parent).
    """
    n_total = fine_codes.shape[0] + coarse_codes.shape[0]
    out_codes = np.empty(n_total, dtype=np.uint64)
    out_depths = np.empty(n_total, dtype=np.uint8)
    out_values = np.empty(n_total, dtype=np.float32)
    n_out = 0
    inner = 0
    level_codes = fine_codes
    level_values = fine_values
    level_leaf = np.ones(fine_codes.shape[0], dtype=np.bool_)
    c = coarse_codes.shape[0]
    next_coarse = c - 1  # coarse leaves are taken from the deepest (the end of the list) up
    depth = TREE_DEPTH
    while True:
        # Merge the coarse leaves of this depth into the level (both sorted).
        first = next_coarse
        while first >= 0 and coarse_depths[first] == depth:
            first -= 1
        if first < next_coarse:
            extra = next_coarse - first
            m = level_codes.shape[0]
            merged_codes = np.empty(m + extra, dtype=np.uint64)
            merged_values = np.empty(m + extra, dtype=np.float32)
            merged_leaf = np.empty(m + extra, dtype=np.bool_)
            i, j, k = 0, first + 1, 0
            while i < m or j <= next_coarse:
                if j > next_coarse or (i < m and level_codes[i] < coarse_codes[j]):
                    merged_codes[k], merged_values[k], merged_leaf[k] = level_codes[i], level_values[i], level_leaf[i]
                    i += 1
                else:
                    merged_codes[k], merged_values[k], merged_leaf[k] = coarse_codes[j], coarse_values[j], True
                    j += 1
                k += 1
            level_codes, level_values, level_leaf = merged_codes, merged_values, merged_leaf
            next_coarse = first
        m = level_codes.shape[0]
        if depth == 0:  # the root: a leaf if everything collapsed into it, else counted as inner at depth 1
            for i in range(m):
                if level_leaf[i]:
                    out_codes[n_out], out_depths[n_out], out_values[n_out] = 0, 0, level_values[i]
                    n_out += 1
            break
        # Parents: one per run of equal code >> 3.
        parent_codes = np.empty(m, dtype=np.uint64)
        parent_values = np.empty(m, dtype=np.float32)
        parent_leaf = np.empty(m, dtype=np.bool_)
        n_parents = 0
        shift = np.uint64(3 * (TREE_DEPTH - depth))
        start = 0
        while start < m:
            parent = level_codes[start] >> np.uint64(3)
            end = start + 1
            while end < m and (level_codes[end] >> np.uint64(3)) == parent:
                end += 1
            collapse = end - start == 8
            if collapse:
                value = level_values[start]
                for i in range(start, end):
                    if not level_leaf[i] or level_values[i] != value:
                        collapse = False
                        break
            parent_codes[n_parents] = parent
            parent_values[n_parents] = level_values[start]
            parent_leaf[n_parents] = collapse
            n_parents += 1
            if not collapse:
                inner += 1
                for i in range(start, end):
                    if level_leaf[i]:
                        out_codes[n_out] = level_codes[i] << shift
                        out_depths[n_out] = depth
                        out_values[n_out] = level_values[i]
                        n_out += 1
            start = end
        level_codes = parent_codes[:n_parents]
        level_values = parent_values[:n_parents]
        level_leaf = parent_leaf[:n_parents]
        depth -= 1
    codes, order = radix_sort_pairs48(out_codes[:n_out], np.arange(n_out), 1)
    return codes, out_depths[order], out_values[order], inner
