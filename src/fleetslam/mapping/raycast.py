"""Ray keys of whole scans (OctoMap's computeUpdate / computeRayKeys) and single-ray casting (castRay).

The batch path runs numba kernels over all rays in parallel (see :mod:`fleetslam.mapping._kernels`) and
deduplicates through a dense scan-local byte grid, falling back to sorting when the scan spans too much space.
On a GPU (:mod:`fleetslam.mapping.cuda_trace`) only the walks into the grid move; the rest is shared.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam._imports import require
from fleetslam.mapping import _kernels as K
from fleetslam.mapping.keys import TREE_MAX_VAL, coords_to_keys, unpack

numba = require("numba", "mapping")

#: Largest scan-local dense grid (cells = bytes); bigger scans deduplicate by sorting instead.
MAX_GRID_CELLS = 256 * 1024 * 1024
#: Memory for the threads' private copies of the grid (each thread writes its own where they fit).
MAX_GRID_COPIES_BYTES = 512 * 1024 * 1024
_EMPTY_KEYS = np.zeros(0, np.uint64)


def ray_keys(origin: ArrayLike, end: ArrayLike, resolution: float) -> NDArray[np.uint16]:
    """OctoMap's computeRayKeys(origin, end): the keys ``(K, 3)`` a ray crosses, origin voxel in, end voxel out.

    Empty when both lie in one voxel or either is outside the key range (OctoMap warns and returns false).
    """
    o = np.asarray(origin, dtype=np.float32).reshape(3)
    e = np.asarray(end, dtype=np.float32).reshape(1, 3)
    counts = K.ray_key_counts(e, o, resolution, -1.0)
    free, _ = K.ray_keys(e, o, resolution, -1.0, np.zeros(1, np.int64), int(counts[0]))
    return unpack(free)


def scan_keys(
    points: NDArray[np.float32],
    origin: NDArray[np.float32],
    resolution: float,
    max_range: float,
    use_cuda: bool = False,
) -> tuple[NDArray[np.uint64], NDArray[np.uint64], NDArray[np.uint8]]:
    """Packed free and occupied keys of one scan, each once, occupied winning (OctoMap's computeUpdate).

    ``points`` float32 ``(N, 3)`` C-contiguous, ``origin`` float32 ``(3,)`` inside the key range. Also returns
    each point's status: 0 used, 1 not finite, 2 outside the key range (skipped). ``use_cuda`` walks the rays on
    the GPU (:mod:`fleetslam.mapping.cuda_trace`), with identical results.
    """
    status, ends, occupied, lo, hi = K.prepare_scan(points, origin, resolution, max_range)
    if not (status == 0).any():
        return _EMPTY_KEYS, _EMPTY_KEYS, status
    origin_key, _ = coords_to_keys(origin, resolution)
    # Every ray key lies in the box of the origin's and the ends' keys; DDA round-off may step one voxel past.
    lo = np.maximum(np.minimum(lo, origin_key[0]) - 2, 0)
    hi = np.minimum(np.maximum(hi, origin_key[0]) + 2, 2 * TREE_MAX_VAL - 1)
    dims = (hi - lo + 1).astype(np.int64)
    cells = int(np.prod(dims))
    if cells <= MAX_GRID_CELLS:
        if use_cuda:
            from fleetslam.mapping.cuda_trace import trace_into_grid_cuda

            grid = trace_into_grid_cuda(ends, status, origin, resolution, lo, dims)
        else:
            threads = numba.get_num_threads()
            padded = cells + 2 * int(K.grid_padding(dims))
            copies = max(1, min(threads, MAX_GRID_COPIES_BYTES // padded))
            grid = K.trace_into_grid(ends, status, origin, resolution, lo, dims, threads, copies)
        K.mark_occupied(grid, occupied, lo, dims)
        free, occ = K.collect_grid(grid, lo, dims)
        return free, occ, status
    # A scan too large for a dense grid: collect keys in a buffer and deduplicate by sorting.
    used = np.ascontiguousarray(points[status == 0])
    counts = K.ray_key_counts(used, origin, resolution, max_range)
    offsets = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    free_all, occ_all = K.ray_keys(used, origin, resolution, max_range, offsets[:-1], int(offsets[-1]))
    occupied_keys = np.unique(occ_all[occ_all != K.EMPTY])
    free = np.unique(free_all)
    return free[~np.isin(free, occupied_keys, assume_unique=True)], occupied_keys, status


def cast_ray(
    origin: ArrayLike,
    direction: ArrayLike,
    resolution: float,
    lookup: Callable[[NDArray[np.uint16]], NDArray[np.float64]],
    threshold: float,
    max_range: float = -1.0,
    ignore_unknown: bool = False,
    chunk: int = 512,
) -> NDArray[np.float64] | None:
    """OctoMap's castRay: centre of the first occupied voxel from ``origin`` along ``direction``, or None.

    ``lookup`` maps finest keys ``(K, 3)`` to log-odds (NaN = unknown). The walk stops (None) at unknown space
    unless ``ignore_unknown``, beyond ``max_range`` (when > 0), or at the edge of the key range. An occupied
    origin voxel is itself the hit.
    """
    o32 = np.asarray(origin, dtype=np.float32).reshape(3)
    keys, valid = coords_to_keys(o32, resolution)
    if not valid[0]:
        return None
    key = [int(v) for v in keys[0]]

    def centre(k: list[int] | NDArray[np.int64]) -> NDArray[np.float64]:
        return (np.asarray(k, dtype=np.float64) - TREE_MAX_VAL + 0.5) * resolution

    start_value = float(lookup(np.array([key], np.uint16))[0])
    if np.isnan(start_value):
        if not ignore_unknown:
            return None
    elif start_value >= threshold:
        return centre(key)
    d = np.asarray(direction, dtype=np.float32).reshape(3)
    norm = np.float32(np.sqrt(np.float32(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])))
    if norm == 0:
        return None
    d = (d / norm).astype(np.float32)
    step = [int(np.sign(v)) for v in d]
    t_max = [np.inf] * 3
    t_delta = [np.inf] * 3
    for i in range(3):
        if step[i]:
            border = (key[i] - TREE_MAX_VAL + 0.5) * resolution + step[i] * resolution * 0.5
            t_max[i] = (border - float(o32[i])) / float(d[i])
            t_delta[i] = resolution / abs(float(d[i]))
    max_range_sq = max_range * max_range
    while True:
        batch: list[list[int]] = []
        stop_after = False
        for _ in range(chunk):
            # computeRayKeys' tie-break: x only if strictly smallest, then y if below z, else z.
            dim = (0 if t_max[0] < t_max[2] else 2) if t_max[0] < t_max[1] else (1 if t_max[1] < t_max[2] else 2)
            if (step[dim] < 0 and key[dim] == 0) or (step[dim] > 0 and key[dim] == 2 * TREE_MAX_VAL - 1):
                stop_after = True
                break
            key[dim] += step[dim]
            t_max[dim] += t_delta[dim]
            if max_range > 0 and float(((centre(key) - o32) ** 2).sum()) > max_range_sq:
                stop_after = True
                break
            batch.append(list(key))
        if batch:
            values = lookup(np.array(batch, np.uint16))
            for k, value in zip(batch, values, strict=True):
                if np.isnan(value):
                    if not ignore_unknown:
                        return None
                elif value >= threshold:
                    return centre(k)
        if stop_after:
            return None
