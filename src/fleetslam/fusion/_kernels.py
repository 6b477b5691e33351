"""Numba kernels of the fleet map: an agent's voxels moved into the fleet frame, and the strongest evidence that
lands in a fleet voxel.

A source voxel maps to the fleet voxel holding its transformed centre (coordinates rounded to float32 and keyed as
:func:`fleetslam.mapping.keys.coords_to_keys` does). Under a rotation several source voxels may land in one fleet
voxel: it takes the strongest evidence (largest |log-odds|; on a tie the larger value). Every source voxel landing
in a fleet voxel lies within one voxel, per axis, of the key of the fleet voxel's centre moved back, so the 27 keys
around it hold them all.
"""

from __future__ import annotations

import numpy as np

from fleetslam._imports import require
from fleetslam.mapping._kernels import EMPTY
from fleetslam.mapping._table_kernels import table_find
from fleetslam.mapping.keys import TREE_MAX_VAL

numba = require("numba", "mapping")
njit = numba.njit

_MASK = np.uint64(0xFFFF)
#: A source voxel whose centre lands in a fleet voxel lies, per axis, within half the voxel diagonal (√3/2 of a
#: voxel) of the fleet voxel's centre moved back; a little more covers the float32 rounding of the landing point.
_REACH = 0.87


@njit(cache=True, inline="always")
def _key_of(transform, x, y, z, factor):  # type: ignore[no-untyped-def]
    """Packed key of ``transform · (x, y, z)`` (float32 coordinates), or EMPTY outside the key range."""
    packed = np.uint64(0)
    for row in range(3):
        c = transform[row, 0] * x + transform[row, 1] * y + transform[row, 2] * z + transform[row, 3]
        scaled = np.floor(factor * np.float64(np.float32(c)))
        if not (-TREE_MAX_VAL <= scaled < TREE_MAX_VAL):
            return EMPTY
        packed = (packed << np.uint64(16)) | np.uint64(np.int64(scaled) + TREE_MAX_VAL)
    return packed


@njit(cache=True, inline="always")
def _centre(packed, axis, resolution):  # type: ignore[no-untyped-def]
    key = (packed >> np.uint64(16 * (2 - axis))) & _MASK
    return (np.float64(key) - TREE_MAX_VAL + 0.5) * resolution


@njit(cache=True)
def forward_keys(packed, transform, resolution):  # type: ignore[no-untyped-def]
    """Fleet keys of agent voxels (EMPTY where they fall outside the key range)."""
    factor = 1.0 / resolution
    out = np.empty(packed.shape[0], np.uint64)
    for j in range(packed.shape[0]):
        key = packed[j]
        out[j] = _key_of(
            transform, _centre(key, 0, resolution), _centre(key, 1, resolution), _centre(key, 2, resolution), factor
        )
    return out


@njit(cache=True)
def strongest_sources(targets, forward, inverse, source_keys, source_values, resolution):  # type: ignore[no-untyped-def]
    """For each fleet voxel, the strongest value among the agent's voxels (a hash table's slot arrays) that land
    in it; NaN where none does."""
    factor = 1.0 / resolution
    out = np.empty(targets.shape[0], np.float32)
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for j in range(targets.shape[0]):
        target = targets[j]
        outside = False
        for row in range(3):  # the fleet voxel's centre moved back, in source voxel units
            c = inverse[row, 3]
            for axis in range(3):
                c += inverse[row, axis] * _centre(target, axis, resolution)
            u = c * factor + TREE_MAX_VAL - 0.5  # source voxel k has its centre at u = k
            first, last = np.int64(np.ceil(u - _REACH)), np.int64(np.floor(u + _REACH))
            lo[row] = first if first > 0 else 0
            hi[row] = last if last < 0xFFFF else 0xFFFF
            outside = outside or lo[row] > hi[row]
        best = np.float32(np.nan)
        if not outside:
            for kx in range(lo[0], hi[0] + 1):
                for ky in range(lo[1], hi[1] + 1):
                    for kz in range(lo[2], hi[2] + 1):
                        source = (np.uint64(kx) << np.uint64(32)) | (np.uint64(ky) << np.uint64(16)) | np.uint64(kz)
                        slot = table_find(source_keys, source)
                        if slot < 0:
                            continue
                        lands = _key_of(
                            forward, _centre(source, 0, resolution), _centre(source, 1, resolution),
                            _centre(source, 2, resolution), factor,
                        )  # fmt: skip
                        if lands != target:
                            continue
                        value = source_values[slot]
                        if np.isnan(best) or abs(value) > abs(best) or (abs(value) == abs(best) and value > best):
                            best = value
        out[j] = best
    return out
