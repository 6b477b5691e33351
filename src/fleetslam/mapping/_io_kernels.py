"""Numba kernels for OctoMap file bodies: sequential pre-order walks with an explicit stack.

Leaves are given and returned in pre-order as Morton codes (3 bits per level, child index x=1, y=2, z=4, the
root's child in the top triple) with their depth. Status codes: 0 ok, 1 truncated, 2 node below the finest level,
3 overlapping or unsorted leaves.
"""

from __future__ import annotations

import numpy as np

from fleetslam._imports import require

numba = require("numba", "mapping")
njit = numba.njit

DEPTH = 16
OK = 0
TRUNCATED = 1
TOO_DEEP = 2
BAD_ORDER = 3
FLT_LOWEST = np.float32(-3.4028234663852886e38)


@njit(cache=True)
def decode_bt(buffer, start, clamp_min, clamp_max):  # type: ignore[no-untyped-def]
    """readBinaryNode from the root: (codes, depths, values, node count, end, status, error offset)."""
    # Each 2-byte inner node has at most 8 leaf children.
    capacity = max(4 * (buffer.shape[0] - start), 1)
    codes = np.empty(capacity, np.uint64)
    depths = np.empty(capacity, np.uint8)
    values = np.empty(capacity, np.float32)
    count = 0
    stack_prefix = np.empty(8 * (DEPTH + 2), np.uint64)
    stack_depth = np.empty(8 * (DEPTH + 2), np.int64)
    stack_type = np.empty(8 * (DEPTH + 2), np.uint8)
    top = 0
    stack_prefix[0] = 0
    stack_depth[0] = 0
    stack_type[0] = 3
    top = 1
    pos = start
    nodes = 0
    size = buffer.shape[0]
    while top > 0:
        top -= 1
        prefix = stack_prefix[top]
        depth = stack_depth[top]
        kind = stack_type[top]
        nodes += 1
        value = np.float32(0.0)
        leaf = False
        if kind == 3:
            if pos + 2 > size:
                return codes[:count], depths[:count], values[:count], nodes, pos, TRUNCATED, pos
            word = np.int64(buffer[pos]) | (np.int64(buffer[pos + 1]) << 8)
            pos += 2
            if word == 0:
                leaf = True
                # A root without children keeps the occupied default; any other inner node takes the max of no
                # children, the lowest float.
                value = clamp_max if depth == 0 else FLT_LOWEST
            else:
                for i in range(7, -1, -1):
                    child_kind = (word >> (2 * i)) & 3
                    if child_kind == 0:
                        continue
                    if depth + 1 > DEPTH or (child_kind == 3 and depth + 1 >= DEPTH):
                        return codes[:count], depths[:count], values[:count], nodes, pos - 2, TOO_DEEP, pos - 2
                    stack_prefix[top] = (prefix << np.uint64(3)) | np.uint64(i)
                    stack_depth[top] = depth + 1
                    stack_type[top] = child_kind
                    top += 1
        else:
            leaf = True
            value = clamp_max if kind == 2 else clamp_min
        if leaf:
            if count == capacity:
                capacity *= 2
                codes2 = np.empty(capacity, np.uint64)
                codes2[:count] = codes[:count]
                codes = codes2
                depths2 = np.empty(capacity, np.uint8)
                depths2[:count] = depths[:count]
                depths = depths2
                values2 = np.empty(capacity, np.float32)
                values2[:count] = values[:count]
                values = values2
            codes[count] = prefix << np.uint64(3 * (DEPTH - depth))
            depths[count] = depth
            values[count] = value
            count += 1
    return codes[:count], depths[:count], values[:count], nodes, pos, OK, pos


@njit(cache=True)
def decode_ot(buffer, start):  # type: ignore[no-untyped-def]
    """readNodesRecurs from the root: (codes, depths, values, node count, end, status, error offset)."""
    capacity = max((buffer.shape[0] - start) // 5, 1)
    codes = np.empty(capacity, np.uint64)
    depths = np.empty(capacity, np.uint8)
    values = np.empty(capacity, np.float32)
    count = 0
    stack_prefix = np.empty(8 * (DEPTH + 2), np.uint64)
    stack_depth = np.empty(8 * (DEPTH + 2), np.int64)
    stack_prefix[0] = 0
    stack_depth[0] = 0
    top = 1
    pos = start
    nodes = 0
    size = buffer.shape[0]
    raw = np.empty(4, np.uint8)
    while top > 0:
        top -= 1
        prefix = stack_prefix[top]
        depth = stack_depth[top]
        if pos + 5 > size:
            return codes[:count], depths[:count], values[:count], nodes, pos, TRUNCATED, pos
        nodes += 1
        raw[:] = buffer[pos : pos + 4]
        value = raw.view(np.float32)[0]
        mask = buffer[pos + 4]
        pos += 5
        if mask == 0:
            if count == capacity:
                capacity *= 2
                codes2 = np.empty(capacity, np.uint64)
                codes2[:count] = codes[:count]
                codes = codes2
                depths2 = np.empty(capacity, np.uint8)
                depths2[:count] = depths[:count]
                depths = depths2
                values2 = np.empty(capacity, np.float32)
                values2[:count] = values[:count]
                values = values2
            codes[count] = prefix << np.uint64(3 * (DEPTH - depth))
            depths[count] = depth
            values[count] = value
            count += 1
            continue
        if depth >= DEPTH:
            return codes[:count], depths[:count], values[:count], nodes, pos - 1, TOO_DEEP, pos - 1
        for i in range(7, -1, -1):
            if mask & (1 << i):
                stack_prefix[top] = (prefix << np.uint64(3)) | np.uint64(i)
                stack_depth[top] = depth + 1
                top += 1
    return codes[:count], depths[:count], values[:count], nodes, pos, OK, pos


@njit(cache=True, inline="always")
def _common_depth(a, b):  # type: ignore[no-untyped-def]
    """Depth of the deepest node containing both Morton codes (16 if equal)."""
    x = a ^ b
    if x == 0:
        return DEPTH
    high = 0
    while x > np.uint64(1):
        x >>= np.uint64(1)
        high += 1
    # Bits 3(16-k)..3(16-k)+2 hold the child index at depth k; the codes first differ at depth k.
    return DEPTH - high // 3 - 1


@njit(cache=True)
def encode(codes, depths, values, threshold, full):  # type: ignore[no-untyped-def]
    """writeBinaryNode (full=False) or writeNodesRecurs (full=True) of the tree spanned by pre-order leaves.

    Returns (bytes, node count, status, index of the offending leaf).
    """
    n = codes.shape[0]
    # Pass 1: count inner nodes and check order.
    inner = 0
    open_depth = -1
    for i in range(n):
        d = int(depths[i])
        if i > 0:
            common = _common_depth(codes[i - 1], codes[i])
            if common >= d or common >= int(depths[i - 1]) or codes[i] < codes[i - 1]:
                return np.empty(0, np.uint8), 0, BAD_ORDER, i
            open_depth = common
        if d - 1 > open_depth:
            inner += d - 1 - open_depth
        open_depth = d - 1
    record = 5 if full else 2
    if n == 1 and depths[0] == 0:
        out = np.zeros(record, np.uint8)
        if full:
            out[:4] = np.array([values[0]], np.float32).view(np.uint8)
        return out, 1, OK, 0
    out = np.zeros(record * (inner + n if full else inner), np.uint8)
    pos = 0
    at = np.zeros(DEPTH + 1, np.int64)
    bits = np.zeros(DEPTH + 1, np.int64)
    vmax = np.zeros(DEPTH + 1, np.float32)
    open_depth = -1
    for i in range(n):
        c = codes[i]
        d = int(depths[i])
        common = -1 if i == 0 else _common_depth(codes[i - 1], c)
        # Close finished inner nodes, deepest first.
        while open_depth > common:
            _close(out, at, bits, vmax, open_depth, full)
            open_depth -= 1
        # Open the inner nodes down to this leaf's parent.
        for j in range(open_depth + 1, d):
            at[j] = pos
            bits[j] = 0
            vmax[j] = FLT_LOWEST
            pos += record
            if j > 0:
                child = np.int64((c >> np.uint64(3 * (DEPTH - j))) & np.uint64(7))
                bits[j - 1] |= (3 << (2 * child)) if not full else (1 << child)
        open_depth = d - 1
        child = np.int64((c >> np.uint64(3 * (DEPTH - d))) & np.uint64(7))
        if full:
            out[pos : pos + 4] = np.array([values[i]], np.float32).view(np.uint8)
            out[pos + 4] = 0
            pos += 5
            bits[d - 1] |= 1 << child
        else:
            kind = 2 if values[i] >= threshold else 1
            bits[d - 1] |= kind << (2 * child)
        if values[i] > vmax[d - 1]:
            vmax[d - 1] = values[i]
    while open_depth >= 0:
        _close(out, at, bits, vmax, open_depth, full)
        open_depth -= 1
    return out, inner + n, OK, 0


@njit(cache=True, inline="always")
def _close(out, at, bits, vmax, depth, full):  # type: ignore[no-untyped-def]
    p = at[depth]
    if full:
        out[p : p + 4] = np.array([vmax[depth]], np.float32).view(np.uint8)
        out[p + 4] = bits[depth]
    else:
        out[p] = bits[depth] & 0xFF
        out[p + 1] = (bits[depth] >> 8) & 0xFF
    if depth > 0 and vmax[depth] > vmax[depth - 1]:
        vmax[depth - 1] = vmax[depth]


@njit(cache=True)
def prune_levels(codes, depths, values):  # type: ignore[no-untyped-def]
    """OctoMap prune(): passes for depth 15 … 1 collapsing 8 equal leaf children; stop after a pass with none.

    The root (depth 0) is never collapsed. Returns the new (codes, depths, values).
    """
    n = codes.shape[0]
    codes = codes.copy()
    depths = depths.copy()
    values = values.copy()
    for level in range(DEPTH - 1, 0, -1):
        child_depth = level + 1
        pruned = 0
        write = 0
        i = 0
        while i < n:
            collapsible = False
            if depths[i] == child_depth and i + 7 < n:
                child = (codes[i] >> np.uint64(3 * (DEPTH - child_depth))) & np.uint64(7)
                if child == 0 and depths[i + 7] == child_depth:
                    parent = codes[i] >> np.uint64(3 * (DEPTH - level))
                    if (codes[i + 7] >> np.uint64(3 * (DEPTH - level))) == parent:
                        collapsible = True
                        for k in range(1, 8):
                            if depths[i + k] != child_depth or values[i + k] != values[i]:
                                collapsible = False
                                break
            if collapsible:
                codes[write] = codes[i]
                depths[write] = level
                values[write] = values[i]
                write += 1
                pruned += 1
                i += 8
            else:
                codes[write] = codes[i]
                depths[write] = depths[i]
                values[write] = values[i]
                write += 1
                i += 1
        n = write
        if pruned == 0:
            break
    return codes[:n], depths[:n], values[:n]
