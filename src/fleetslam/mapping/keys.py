"""OctoMap keys: coordinates ↔ 16-bit voxel keys, packing, and Morton (pre-order) codes.

Key of a coordinate c (a float32, as OctoMap's point3d) at resolution r: ⌊c·(1/r)⌋ + 32768, computed in float64
exactly as OctoMap 1.10 does; valid keys are [0, 65536). A key's centre is (k − 32768 + 0.5)·r.
Keys are packed into one uint64 as ``x << 32 | y << 16 | z``. The Morton code interleaves the key bits with,
at each level, the child index of OctoMap (x adds 1, y adds 2, z adds 4), so sorting by it is pre-order.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

TREE_DEPTH = 16
TREE_MAX_VAL = 32768


def coords_to_keys(points: ArrayLike, resolution: float) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Keys ``(N, 3)`` int64 of float32 coordinates and a mask of those inside the key range."""
    pts = np.asarray(points, dtype=np.float32).astype(np.float64).reshape(-1, 3)
    factor = 1.0 / resolution
    with np.errstate(invalid="ignore"):
        scaled = np.floor(factor * pts)
        # Range check before the integer cast: huge coordinates would wrap around in int64.
        valid = np.asarray(((scaled >= -TREE_MAX_VAL) & (scaled < TREE_MAX_VAL)).all(axis=1), dtype=np.bool_)
    keys = np.zeros(pts.shape, dtype=np.int64)
    keys[valid] = scaled[valid].astype(np.int64) + TREE_MAX_VAL
    return keys, valid


def keys_to_coords(keys: ArrayLike, resolution: float) -> NDArray[np.float64]:
    """Centres of finest-level keys."""
    k = np.asarray(keys, dtype=np.int64)
    return np.asarray((k - TREE_MAX_VAL + 0.5) * resolution, dtype=np.float64)


def pack(keys: ArrayLike) -> NDArray[np.uint64]:
    """``(N, 3)`` keys → uint64 ``x << 32 | y << 16 | z``."""
    k = np.asarray(keys, dtype=np.uint64).reshape(-1, 3)
    return (k[:, 0] << np.uint64(32)) | (k[:, 1] << np.uint64(16)) | k[:, 2]


def unpack(packed: ArrayLike) -> NDArray[np.uint16]:
    """uint64 → ``(N, 3)`` uint16 keys."""
    p = np.asarray(packed, dtype=np.uint64)
    mask = np.uint64(0xFFFF)
    return np.stack([(p >> np.uint64(32)) & mask, (p >> np.uint64(16)) & mask, p & mask], axis=1).astype(np.uint16)


def _spread3(v: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """Spread the low bits of v so that bit i goes to bit 3i (valid for up to 21 bits)."""
    v = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def _compact3(v: NDArray[np.uint64]) -> NDArray[np.uint64]:
    v = v.astype(np.uint64) & np.uint64(0x1249249249249249)
    v = (v ^ (v >> np.uint64(2))) & np.uint64(0x10C30C30C30C30C3)
    v = (v ^ (v >> np.uint64(4))) & np.uint64(0x100F00F00F00F00F)
    v = (v ^ (v >> np.uint64(8))) & np.uint64(0x1F0000FF0000FF)
    v = (v ^ (v >> np.uint64(16))) & np.uint64(0x1F00000000FFFF)
    v = (v ^ (v >> np.uint64(32))) & np.uint64(0x1FFFFF)
    return v


def morton(keys: ArrayLike) -> NDArray[np.uint64]:
    """Morton codes of ``(N, 3)`` keys (x → bit 0, y → bit 1, z → bit 2 of each level's triple)."""
    k = np.asarray(keys, dtype=np.uint64).reshape(-1, 3)
    return _spread3(k[:, 0]) | (_spread3(k[:, 1]) << np.uint64(1)) | (_spread3(k[:, 2]) << np.uint64(2))


def unmorton(codes: ArrayLike) -> NDArray[np.uint16]:
    """Inverse of :func:`morton`."""
    c = np.asarray(codes, dtype=np.uint64)
    return np.stack([_compact3(c), _compact3(c >> np.uint64(1)), _compact3(c >> np.uint64(2))], axis=1).astype(
        np.uint16
    )


def node_centers(keys: ArrayLike, depths: ArrayLike, resolution: float) -> NDArray[np.float64]:
    """Centres of nodes given their min-corner finest keys and depths."""
    k = np.asarray(keys, dtype=np.float64).reshape(-1, 3)
    size_in_keys = np.power(2.0, TREE_DEPTH - np.asarray(depths, dtype=np.float64))[:, None]
    return (k - TREE_MAX_VAL + size_in_keys / 2.0) * resolution
