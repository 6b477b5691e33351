"""Numba kernels of the octree engine's ray casting: OctoMap's exact ray keys of whole scans, in parallel.

The ray tracing and the scan preparation run in parallel. The lighter passes (occupied marking, grid
collection) stay serial: on a shared 2-core machine every parallel region waits for a thread that may be
descheduled, and for them that wait costs more than the second core saves. The voxel table's kernels are in
:mod:`fleetslam.mapping._table_kernels`.

Arithmetic mirrors OctoMap 1.10 line by line where it matters for exactness: points and directions are float32
(``point3d``), ray lengths float32, tMax/tDelta float64, keys ⌊c·(1/res)⌋ + 32768 in float64.
"""

from __future__ import annotations

import math

import numpy as np

from fleetslam._imports import require
from fleetslam.mapping._atomics import fetch_add

numba = require("numba", "mapping")
njit, prange = numba.njit, numba.prange

TREE_MAX_VAL = 32768
EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
DBL_MAX = 1.7976931348623157e308
#: Rays a thread of :func:`trace_into_grid` takes at a time.
TRACE_BLOCK = 512


@njit(cache=True, inline="always")
def _coord_to_key(coordinate: float, factor: float) -> int:
    # Range check before the floor (⌊x⌋ ≥ n ⇔ x ≥ n for an integer n): NaN and huge values must not go through
    # an integer conversion.
    scaled = factor * coordinate
    if not (scaled >= -TREE_MAX_VAL and scaled < TREE_MAX_VAL):
        return -1
    return math.floor(scaled) + TREE_MAX_VAL


@njit(cache=True)
def _ray_end(points, origin, maxrange, i):  # type: ignore[no-untyped-def]
    """OctoMap computeUpdate's end point of ray i and whether its endpoint counts as occupied."""
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    ox, oy, oz = origin[0], origin[1], origin[2]
    dx = np.float32(px - ox)
    dy = np.float32(py - oy)
    dz = np.float32(pz - oz)
    norm_sq = np.float32(np.float32(np.float32(dx * dx) + np.float32(dy * dy)) + np.float32(dz * dz))
    norm = math.sqrt(np.float64(norm_sq))
    if maxrange < 0.0 or norm <= maxrange:
        return px, py, pz, True
    # Cut at maxrange: direction normalised in float32, end = origin + direction * (float) maxrange.
    length = np.float32(norm)
    fr = np.float32(maxrange)
    ex = np.float32(ox + np.float32(np.float32(dx / length) * fr))
    ey = np.float32(oy + np.float32(np.float32(dy / length) * fr))
    ez = np.float32(oz + np.float32(np.float32(dz / length) * fr))
    return ex, ey, ez, False


COUNT, BUFFER = 0, 1


@njit(cache=True, inline="always")
def _pack(kx, ky, kz):  # type: ignore[no-untyped-def]
    return (np.uint64(kx) << np.uint64(32)) | (np.uint64(ky) << np.uint64(16)) | np.uint64(kz)


@njit(cache=True, inline="always")
def _emit(mode, out, out_index, kx, ky, kz):  # type: ignore[no-untyped-def]
    if mode == BUFFER:
        out[out_index] = _pack(kx, ky, kz)


@njit(cache=True, inline="always")
def _axis_init(direction, key, origin, resolution):  # type: ignore[no-untyped-def]
    """Step, tMax and tDelta of one axis, as computeRayKeys' initialisation phase."""
    if direction > 0.0:
        step = 1
    elif direction < 0.0:
        step = -1
    else:
        return 0, DBL_MAX, DBL_MAX
    border = (np.float64(key - TREE_MAX_VAL) + 0.5) * resolution
    border += np.float64(np.float32(step * resolution * 0.5))
    return step, (border - np.float64(origin)) / np.float64(direction), resolution / abs(np.float64(direction))


@njit(cache=True)
def _trace(ox, oy, oz, ex, ey, ez, resolution, factor, mode, out, out_start):  # type: ignore[no-untyped-def]
    """computeRayKeys: counts the ray's keys, and in BUFFER mode writes them packed into out[out_start:]."""
    kx = _coord_to_key(np.float64(ox), factor)
    ky = _coord_to_key(np.float64(oy), factor)
    kz = _coord_to_key(np.float64(oz), factor)
    end_x = _coord_to_key(np.float64(ex), factor)
    end_y = _coord_to_key(np.float64(ey), factor)
    end_z = _coord_to_key(np.float64(ez), factor)
    if kx < 0 or ky < 0 or kz < 0 or end_x < 0 or end_y < 0 or end_z < 0:
        return 0
    if kx == end_x and ky == end_y and kz == end_z:
        return 0
    _emit(mode, out, out_start, kx, ky, kz)
    n = 1
    dx = np.float32(ex - ox)
    dy = np.float32(ey - oy)
    dz = np.float32(ez - oz)
    norm_sq = np.float32(np.float32(np.float32(dx * dx) + np.float32(dy * dy)) + np.float32(dz * dz))
    length = np.float32(math.sqrt(np.float64(norm_sq)))
    sx, tmx, tdx = _axis_init(np.float32(dx / length), kx, ox, resolution)
    sy, tmy, tdy = _axis_init(np.float32(dy / length), ky, oy, resolution)
    sz, tmz, tdz = _axis_init(np.float32(dz / length), kz, oz, resolution)
    length64 = np.float64(length)
    while True:
        if tmx < tmy:
            if tmx < tmz:
                kx += sx
                tmx += tdx
            else:
                kz += sz
                tmz += tdz
        elif tmy < tmz:
            ky += sy
            tmy += tdy
        else:
            kz += sz
            tmz += tdz
        if kx == end_x and ky == end_y and kz == end_z:
            break
        if min(min(tmx, tmy), tmz) > length64:
            break
        _emit(mode, out, out_start + n, kx, ky, kz)
        n += 1
    return n


@njit(cache=True, parallel=True)
def ray_key_counts(points, origin, resolution, maxrange):  # type: ignore[no-untyped-def]
    """Number of free keys of every ray (first pass, to size the buffer)."""
    factor = 1.0 / resolution
    counts = np.zeros(points.shape[0], dtype=np.int64)
    dummy = np.zeros(1, dtype=np.uint64)
    for i in prange(points.shape[0]):
        ex, ey, ez, _ = _ray_end(points, origin, maxrange, i)
        counts[i] = _trace(origin[0], origin[1], origin[2], ex, ey, ez, resolution, factor, COUNT, dummy, 0)
    return counts


@njit(cache=True, parallel=True)
def ray_keys(points, origin, resolution, maxrange, offsets, total):  # type: ignore[no-untyped-def]
    """Free keys of all rays, packed, concatenated (second pass), and each point's occupied key or EMPTY."""
    factor = 1.0 / resolution
    out = np.empty(total, dtype=np.uint64)
    occupied = np.full(points.shape[0], EMPTY, dtype=np.uint64)
    for i in prange(points.shape[0]):
        ex, ey, ez, is_hit = _ray_end(points, origin, maxrange, i)
        _trace(origin[0], origin[1], origin[2], ex, ey, ez, resolution, factor, BUFFER, out, offsets[i])
        if is_hit:
            kx = _coord_to_key(np.float64(points[i, 0]), factor)
            ky = _coord_to_key(np.float64(points[i, 1]), factor)
            kz = _coord_to_key(np.float64(points[i, 2]), factor)
            if kx >= 0 and ky >= 0 and kz >= 0:
                occupied[i] = _pack(kx, ky, kz)
    return out, occupied


@njit(cache=True, parallel=True)
def prepare_scan(points, origin, resolution, maxrange):  # type: ignore[no-untyped-def]
    """One pass over a scan: status per point (0 used, 1 non-finite, 2 outside the key range), ray ends (cut at
    maxrange; without a maxrange, the points themselves), occupied keys (packed or EMPTY) and the key bounding
    box of origin and ends."""
    factor = 1.0 / resolution
    n = points.shape[0]
    status = np.empty(n, dtype=np.uint8)
    cut = maxrange >= 0.0
    ends = np.empty((n, 3), dtype=np.float32) if cut else points
    occupied = np.empty(n, dtype=np.uint64)
    chunks = 64
    mins = np.empty((chunks, 3), dtype=np.int64)
    maxs = np.empty((chunks, 3), dtype=np.int64)
    size = (n + chunks - 1) // chunks
    far = 1 << 20
    if not cut:
        # Selects instead of branches, written out here (through an inlined helper numba's output no longer
        # vectorises): 3× faster on the benchmark's Kinect scans. The same tests as _coord_to_key; NaN fails every
        # comparison, so a non-finite point is never inside.
        for c in prange(chunks):
            # The box in locals: stores into mins/maxs in the loop would have to be redone for every point.
            lx = ly = lz = far
            hx = hy = hz = -1
            for i in range(c * size, min(n, (c + 1) * size)):
                px, py, pz = points[i, 0], points[i, 1], points[i, 2]
                finite = np.isfinite(px) & np.isfinite(py) & np.isfinite(pz)
                sx, sy, sz = factor * np.float64(px), factor * np.float64(py), factor * np.float64(pz)
                inside = (sx >= -TREE_MAX_VAL) & (sx < TREE_MAX_VAL) & (sy >= -TREE_MAX_VAL) & (sy < TREE_MAX_VAL)
                inside = inside & (sz >= -TREE_MAX_VAL) & (sz < TREE_MAX_VAL)
                kx = math.floor(sx if inside else 0.0) + TREE_MAX_VAL
                ky = math.floor(sy if inside else 0.0) + TREE_MAX_VAL
                kz = math.floor(sz if inside else 0.0) + TREE_MAX_VAL
                status[i] = 0 if inside else (2 if finite else 1)
                occupied[i] = _pack(kx, ky, kz) if inside else EMPTY
                lx = min(lx, kx if inside else far)
                ly = min(ly, ky if inside else far)
                lz = min(lz, kz if inside else far)
                hx = max(hx, kx if inside else -1)
                hy = max(hy, ky if inside else -1)
                hz = max(hz, kz if inside else -1)
            mins[c, 0], mins[c, 1], mins[c, 2] = lx, ly, lz
            maxs[c, 0], maxs[c, 1], maxs[c, 2] = hx, hy, hz
    else:
        for c in prange(chunks):
            lx = ly = lz = far
            hx = hy = hz = -1
            for i in range(c * size, min(n, (c + 1) * size)):
                occupied[i] = EMPTY
                px, py, pz = points[i, 0], points[i, 1], points[i, 2]
                if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
                    status[i] = 1
                    continue
                kx = _coord_to_key(np.float64(px), factor)
                ky = _coord_to_key(np.float64(py), factor)
                kz = _coord_to_key(np.float64(pz), factor)
                if kx < 0 or ky < 0 or kz < 0:
                    status[i] = 2
                    continue
                status[i] = 0
                ex, ey, ez, is_hit = _ray_end(points, origin, maxrange, i)
                ends[i, 0], ends[i, 1], ends[i, 2] = ex, ey, ez
                if is_hit:
                    occupied[i] = _pack(kx, ky, kz)
                else:
                    kx = _coord_to_key(np.float64(ex), factor)
                    ky = _coord_to_key(np.float64(ey), factor)
                    kz = _coord_to_key(np.float64(ez), factor)
                    if kx < 0 or ky < 0 or kz < 0:
                        continue
                lx, ly, lz = min(lx, kx), min(ly, ky), min(lz, kz)
                hx, hy, hz = max(hx, kx), max(hy, ky), max(hz, kz)
            mins[c, 0], mins[c, 1], mins[c, 2] = lx, ly, lz
            maxs[c, 0], maxs[c, 1], maxs[c, 2] = hx, hy, hz
    lo = np.empty(3, dtype=np.int64)
    hi = np.empty(3, dtype=np.int64)
    for a in range(3):
        lo[a] = mins[:, a].min()
        hi[a] = maxs[:, a].max()
    return status, ends, occupied, lo, hi


@njit(cache=True, inline="always")
def grid_padding(dims):  # type: ignore[no-untyped-def]
    """Cells kept on each side of a trace grid (cell c at ``grid[pad + c]``): one step along every axis from any
    cell of the grid stays inside the array."""
    return dims[1] * dims[2] + dims[2] + 1


@njit(cache=True, inline="always")
def _origin_cell(origin, factor, lo, dims):  # type: ignore[no-untyped-def]
    """The sensor origin's coordinates and key, the grid's strides, and the origin's cell in the grid."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    kx0 = _coord_to_key(np.float64(ox), factor)
    ky0 = _coord_to_key(np.float64(oy), factor)
    kz0 = _coord_to_key(np.float64(oz), factor)
    stride_x = dims[1] * dims[2]
    stride_y = dims[2]
    start = (kx0 - lo[0]) * stride_x + (ky0 - lo[1]) * stride_y + (kz0 - lo[2])
    return ox, oy, oz, kx0, ky0, kz0, stride_x, stride_y, start


@njit(cache=True, parallel=True)
def trace_into_grid(ends, status, origin, resolution, lo, dims, threads, copies):  # type: ignore[no-untyped-def]
    """Mark every free key of every used ray in a dense grid over [lo, lo + dims) (1 = free).

    The threads write into ``copies`` private grids (OR-ed at the end): rays near the sensor all cross the same
    cells, and shared cache lines written by both cores cost more than the second grid. The caller's box has a
    margin of 2 keys around the origin and all ends, more than DDA round-off can overshoot.
    """
    factor = 1.0 / resolution
    size = dims[0] * dims[1] * dims[2]
    pad = grid_padding(dims)
    grids = np.zeros((copies, size + 2 * pad), dtype=np.uint8)
    ox, oy, oz, kx0, ky0, kz0, stride_x, stride_y, start = _origin_cell(origin, factor, lo, dims)
    # Each thread takes blocks of consecutive rays from a shared counter until none is left: rays differ a lot
    # in length (floor vs far wall), and on a shared machine one core is often slowed down for a while; a fixed
    # split would leave the other core waiting at the end. Consecutive rays keep each thread's walk local.
    n = ends.shape[0]
    blocks = (n + TRACE_BLOCK - 1) // TRACE_BLOCK
    next_block = np.zeros(1, dtype=np.int64)
    for thread in prange(threads):
        grid = grids[thread % copies]
        while True:
            b = fetch_add(next_block, 0, 1)
            if b >= blocks:
                break
            for i in range(b * TRACE_BLOCK, min(n, (b + 1) * TRACE_BLOCK)):
                _trace_one_into_grid(
                    grid, size, pad, ends, status, i, ox, oy, oz, kx0, ky0, kz0, start, factor, resolution, lo,
                    stride_x, stride_y,
                )  # fmt: skip
    out = grids[0, pad : pad + size].copy()
    for c in range(1, copies):
        for j in prange(size):
            out[j] |= grids[c, pad + j]
    return out


@njit(cache=True, parallel=True)
def ray_starts(ends, status, origin, resolution, lo, dims):  # type: ignore[no-untyped-def]
    """:func:`_ray_start` of every ray as arrays, for a walk elsewhere (the GPU): ``reals`` (N, 7) float64
    (length, tA, dA, tB, dB, tC, dC), ``ints`` (N, 6) int64 (used, end cell, iA, iB, iC, fast slabs), ``ties`` (N, 3)
    (B, C win ties with A; no fast slab can pass the length), and the origin's cell."""
    factor = 1.0 / resolution
    n = ends.shape[0]
    reals = np.empty((n, 7), dtype=np.float64)
    ints = np.empty((n, 6), dtype=np.int64)
    ties = np.empty((n, 3), dtype=np.bool_)
    ox, oy, oz, kx0, ky0, kz0, stride_x, stride_y, start = _origin_cell(origin, factor, lo, dims)
    for i in prange(n):
        (ok, end_index, length, tA, dA, iA, tB, dB, iB, tC, dC, iC, b_wins_a, c_wins_a, slabs, safe) = _ray_start(
            ends, status, i, ox, oy, oz, kx0, ky0, kz0, factor, resolution, lo, stride_x, stride_y
        )
        reals[i, 0], reals[i, 1], reals[i, 2], reals[i, 3] = length, tA, dA, tB
        reals[i, 4], reals[i, 5], reals[i, 6] = dB, tC, dC
        ints[i, 0], ints[i, 1], ints[i, 2], ints[i, 3], ints[i, 4], ints[i, 5] = ok, end_index, iA, iB, iC, slabs
        ties[i, 0], ties[i, 1], ties[i, 2] = b_wins_a, c_wins_a, safe
    return reals, ints, ties, start


@njit(cache=True, inline="always")
def _trace_one_into_grid(  # type: ignore[no-untyped-def]
    grid, size, pad, ends, status, i, ox, oy, oz, kx0, ky0, kz0, start, factor, resolution, lo, stride_x, stride_y
):
    """One ray of :func:`trace_into_grid`: computeRayKeys with the key as a linear grid index (cell c at
    ``grid[pad + c]``), so "reached the end key" is one comparison.

    The axes are renamed A, B, C with A the one of smallest tDelta, so that A steps once per A-slab and B and C
    at most once each, barring round-off. While the next A step neither lands in the end key's A-slab nor takes
    tMax_A past the ray's length, nothing can stop the walk within the slab: its (up to) three cells are then
    chosen by comparisons without branches (:func:`_walk_slabs`), which the branch predictor cannot miss — the
    cost of the plain walk is mostly mispredicted axis choices. The plain walk finishes the ray from the last
    slab, or from any slab with a tie or where round-off makes B or C step twice, which keeps the result exact.
    """
    (ok, end_index, length, tA, dA, iA, tB, dB, iB, tC, dC, iC, b_wins_a, c_wins_a, slabs, safe) = _ray_start(
        ends, status, i, ox, oy, oz, kx0, ky0, kz0, factor, resolution, lo, stride_x, stride_y
    )
    if ok:
        _walk_ray(grid, size, pad, start, end_index, length, tA, dA, iA, tB, dB, iB, tC, dC, iC, b_wins_a, c_wins_a,
                  slabs, safe)  # fmt: skip


@njit(cache=True, inline="always")
def _ray_start(ends, status, i, ox, oy, oz, kx0, ky0, kz0, factor, resolution, lo, stride_x, stride_y):  # type: ignore[no-untyped-def]
    """computeRayKeys' initialisation for ray i, in the walk's terms: (used, end cell, length, then tMax, tDelta
    and grid step of the axes A, B, C, the tie rules of B and C against A, and the number of fast A-slabs)."""
    ex, ey, ez = ends[i, 0], ends[i, 1], ends[i, 2]
    end_x = _coord_to_key(np.float64(ex), factor)
    end_y = _coord_to_key(np.float64(ey), factor)
    end_z = _coord_to_key(np.float64(ez), factor)
    unused = status[i] != 0 or end_x < 0 or end_y < 0 or end_z < 0 or (kx0 == end_x and ky0 == end_y and kz0 == end_z)
    if unused:
        return False, 0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0, 0.0, 0.0, 0, False, False, 0, False
    end_index = (end_x - lo[0]) * stride_x + (end_y - lo[1]) * stride_y + (end_z - lo[2])
    dx = np.float32(ex - ox)
    dy = np.float32(ey - oy)
    dz = np.float32(ez - oz)
    norm_sq = np.float32(np.float32(np.float32(dx * dx) + np.float32(dy * dy)) + np.float32(dz * dz))
    length = np.float32(math.sqrt(np.float64(norm_sq)))
    sx, tmx, tdx = _axis_init(np.float32(dx / length), kx0, ox, resolution)
    sy, tmy, tdy = _axis_init(np.float32(dy / length), ky0, oy, resolution)
    sz, tmz, tdz = _axis_init(np.float32(dz / length), kz0, oz, resolution)
    ix = sx * stride_x
    iy = sy * stride_y
    iz = sz
    length64 = np.float64(length)
    # OctoMap breaks ties in tMax towards z, then y, then x; B and C keep x-y-z order, so C wins ties with B.
    if tdx <= tdy and tdx <= tdz:
        slabs = (end_x - kx0) * sx - 1
        safe = _slabs_within_length(tmx, tdx, slabs, length64)
        return True, end_index, length64, tmx, tdx, ix, tmy, tdy, iy, tmz, tdz, iz, True, True, slabs, safe
    if tdy <= tdz:
        slabs = (end_y - ky0) * sy - 1
        safe = _slabs_within_length(tmy, tdy, slabs, length64)
        return True, end_index, length64, tmy, tdy, iy, tmx, tdx, ix, tmz, tdz, iz, False, True, slabs, safe
    slabs = (end_z - kz0) * sz - 1
    safe = _slabs_within_length(tmz, tdz, slabs, length64)
    return True, end_index, length64, tmz, tdz, iz, tmx, tdx, ix, tmy, tdy, iy, False, False, slabs, safe


@njit(cache=True, inline="always")
def _slabs_within_length(tA, dA, slabs, length):  # type: ignore[no-untyped-def]
    """Whether tMax_A stays within the length over all fast slabs, so that they need not test it.

    The walk adds dA to tA at most ``slabs`` (< 2^16) times; each addition errs by at most half an ulp, so the sum
    stays within 2^16 · 2^-53 · (|tA| + slabs·dA) < 10^-11 · (|tA| + slabs·dA) of the exact one. With a margin of
    10^-9 of that this decides conservatively: a ray near the bound just keeps the test.
    """
    span = np.float64(slabs) * dA
    magnitude = (tA if tA >= 0.0 else -tA) + span
    return tA + span + magnitude * 1e-9 <= length


@njit(cache=True, inline="always")
def _walk_ray(  # type: ignore[no-untyped-def]
    grid, size, pad, start, end_index, length, tA, dA, iA, tB, dB, iB, tC, dC, iC, b_wins_a, c_wins_a, slabs, safe
):
    """The walk of one ray from :func:`_ray_start`'s state: only additions and comparisons."""
    grid[start + pad] = 1
    usize = np.uint64(size)
    # Two compiled copies of the fast loop: without and (rarely) with the length test.
    if safe:
        index, tA, tB, tC, ok = _walk_slabs(grid, usize, pad, start, slabs, length, tA, dA, iA, tB, dB, iB, tC, dC, iC,
                                            False)  # fmt: skip
    else:
        index, tA, tB, tC, ok = _walk_slabs(grid, usize, pad, start, slabs, length, tA, dA, iA, tB, dB, iB, tC, dC, iC,
                                            True)  # fmt: skip
    if not ok:
        return
    while True:
        if _before(tB, tA, b_wins_a):
            if tC <= tB:
                index += iC
                tC += dC
            else:
                index += iB
                tB += dB
        elif _before(tC, tA, c_wins_a):
            index += iC
            tC += dC
        else:
            index += iA
            tA += dA
        if index == end_index:
            return
        if tA > length and tB > length and tC > length:  # min(...) > length, without builtins (CUDA)
            return
        if np.uint64(index) >= usize:
            return  # memory guard only; the margin makes it unreachable
        grid[np.uint64(index + pad)] = 1


@njit(cache=True, inline="always")
def _before(t1, t2, wins_tie):  # type: ignore[no-untyped-def]
    """Whether the axis at tMax t1 steps before the one at t2 (``wins_tie``: it does when they are equal)."""
    return (t1 < t2) | (wins_tie & (t1 == t2))


@njit(cache=True, inline="always")
def _walk_slabs(grid, usize, pad, index, slabs, length, tA, dA, iA, tB, dB, iB, tC, dC, iC, check_length):  # type: ignore[no-untyped-def]
    """Up to ``slabs`` whole A-slabs of :func:`_trace_one_into_grid`, without branches on the axis order.

    Returns the walk's state and False when a cell left the grid (memory guard). Stops early, state intact,
    where the plain walk must take over: at a step past the length, when B or C would step twice, and at an
    exact tie of tMax_B or tMax_C with tMax_A (the minor axis does not step, so its tMax stays equal to tMax_A):
    the plain walk applies OctoMap's tie rules.
    """
    while slabs > 0:
        tA_next = tA + dA
        if check_length and tA_next > length:
            break
        b_steps = tB < tA
        c_steps = tC < tA
        tB_next = tB + dB if b_steps else tB
        tC_next = tC + dC if c_steps else tC
        # One test for both minor axes: a single branch per slab is worth a select (6 % of the walk).
        if (tB_next if tB_next < tC_next else tC_next) <= tA:
            break
        step_b = iB if b_steps else 0
        step_c = iC if c_steps else 0
        # The cell after the first minor step (B first unless C is earlier or tied); when only one minor axis
        # steps, "first" may name the other one, whose step is 0: the walk's current cell, marked already.
        first = index + (step_b if tB < tC else step_c)
        both = index + step_b + step_c
        after_a = both + iA
        if np.uint64(after_a) >= usize:
            return index, tA, tB, tC, False  # cells one step from a grid cell stay within the padding
        grid[np.uint64(first + pad)] = 1
        grid[np.uint64(both + pad)] = 1
        grid[np.uint64(after_a + pad)] = 1
        index = after_a
        tA, tB, tC = tA_next, tB_next, tC_next
        slabs -= 1
    return index, tA, tB, tC, True


@njit(cache=True)
def mark_occupied(grid, occupied, lo, dims):  # type: ignore[no-untyped-def]
    mask = np.uint64(0xFFFF)
    for i in range(occupied.shape[0]):
        k = occupied[i]
        if k == EMPTY:
            continue
        x = np.int64((k >> np.uint64(32)) & mask) - lo[0]
        y = np.int64((k >> np.uint64(16)) & mask) - lo[1]
        z = np.int64(k & mask) - lo[2]
        grid[(x * dims[1] + y) * dims[2] + z] = 2


@njit(cache=True)
def collect_grid(grid, lo, dims):  # type: ignore[no-untyped-def]
    """Packed keys of the grid's free and occupied cells."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    slab = ny * nz
    free_counts = np.zeros(nx, dtype=np.int64)
    occ_counts = np.zeros(nx, dtype=np.int64)
    for x in prange(nx):
        f = 0
        o = 0
        base = x * slab
        for j in range(slab):
            v = grid[base + j]
            if v == 1:
                f += 1
            elif v == 2:
                o += 1
        free_counts[x] = f
        occ_counts[x] = o
    free_offsets = np.zeros(nx + 1, dtype=np.int64)
    occ_offsets = np.zeros(nx + 1, dtype=np.int64)
    for x in range(nx):
        free_offsets[x + 1] = free_offsets[x] + free_counts[x]
        occ_offsets[x + 1] = occ_offsets[x] + occ_counts[x]
    free = np.empty(free_offsets[nx], dtype=np.uint64)
    occ = np.empty(occ_offsets[nx], dtype=np.uint64)
    for x in prange(nx):
        f = free_offsets[x]
        o = occ_offsets[x]
        base = x * slab
        kx = np.uint64(x + lo[0]) << np.uint64(32)
        for j in range(slab):
            v = grid[base + j]
            if v == 0:
                continue
            y = j // nz
            z = j - y * nz
            packed = kx | (np.uint64(y + lo[1]) << np.uint64(16)) | np.uint64(z + lo[2])
            if v == 1:
                free[f] = packed
                f += 1
            else:
                occ[o] = packed
                o += 1
    return free, occ


@njit(cache=True)
def rays_crossing_boxes(points, origin, lows, highs):  # type: ignore[no-untyped-def]
    """Which segments ``origin → points[i]`` cross any of the axis-aligned boxes ``[lows[b], highs[b]]`` (slab
    test, boxes in the points' frame)."""
    hit = np.zeros(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        for b in range(lows.shape[0]):
            near, far = 0.0, 1.0
            for axis in range(3):
                step = points[i, axis] - origin[axis]
                lo, hi = lows[b, axis] - origin[axis], highs[b, axis] - origin[axis]
                if step == 0.0:
                    if lo > 0.0 or hi < 0.0:
                        near, far = 1.0, 0.0
                        break
                    continue
                t1, t2 = lo / step, hi / step
                if t1 > t2:
                    t1, t2 = t2, t1
                near, far = max(near, t1), min(far, t2)
                if near > far:
                    break
            if near <= far:
                hit[i] = True
                break
    return hit
