"""Optional GPU ray tracing (numba CUDA): the CPU kernel's exact walk, one GPU thread per ray.

Only the walks move to the GPU (they are most of the work). Each ray's start — direction, length, tMax and
tDelta, which need multiplications, divisions and a square root — is computed on the CPU by the CPU's own code
(:func:`fleetslam.mapping._kernels.ray_starts`), because NVVM fuses a multiply and an add into one FMA even
without fast math, which rounds differently. The walk (:func:`fleetslam.mapping._kernels._walk_ray`, compiled
for the GPU) only adds and compares, so its results are the CPU's bit for bit; tests check the compiled PTX
for that and run the kernel in numba's CUDA simulator.

Used only when ``numba.cuda.is_available()`` (a CUDA driver and a GPU are present).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require
from fleetslam.mapping import _kernels as K

cuda = require("numba.cuda", "mapping")

THREADS_PER_BLOCK = 128


@functools.cache
def cuda_available() -> bool:
    """Whether a CUDA GPU can run the tracing kernel (numba's CUDA simulator counts, for tests)."""
    try:
        return bool(cuda.is_available())
    except Exception:  # any driver or library problem means "no GPU"
        return False


def _walk_kernel(grid, size, pad, start, reals, ints, ties):  # type: ignore[no-untyped-def]
    """One thread per ray (compiled by :func:`_kernel`)."""
    i: int = cuda.grid(1)  # type: ignore[call-arg]
    if i >= ints.shape[0] or ints[i, 0] == 0:
        return
    K._walk_ray(
        grid, size, pad, start, ints[i, 1], reals[i, 0], reals[i, 1], reals[i, 2], ints[i, 2], reals[i, 3],
        reals[i, 4], ints[i, 3], reals[i, 5], reals[i, 6], ints[i, 4], ties[i, 0], ties[i, 1], ints[i, 5], ties[i, 2],
    )  # fmt: skip


@functools.cache
def _kernel() -> Any:
    return cuda.jit(fastmath=False)(_walk_kernel)


def trace_into_grid_cuda(
    ends: NDArray[np.float32],
    status: NDArray[np.uint8],
    origin: NDArray[np.float32],
    resolution: float,
    lo: NDArray[np.int64],
    dims: NDArray[np.int64],
) -> NDArray[np.uint8]:
    """GPU version of :func:`fleetslam.mapping._kernels.trace_into_grid`: the same grid (1 = free)."""
    reals, ints, ties, start = K.ray_starts(ends, status, origin, resolution, lo, dims)
    size = int(dims[0] * dims[1] * dims[2])
    pad = int(K.grid_padding(dims))
    grid = cuda.to_device(np.zeros(size + 2 * pad, np.uint8))
    n = ints.shape[0]
    if n:
        blocks = (n + THREADS_PER_BLOCK - 1) // THREADS_PER_BLOCK
        _kernel()[blocks, THREADS_PER_BLOCK](
            grid, size, pad, int(start), cuda.to_device(reals), cuda.to_device(ints), cuda.to_device(ties)
        )
    host = grid.copy_to_host()
    return np.ascontiguousarray(host[pad : pad + size])


def kernel_ptx(compute_capability: tuple[int, int] = (8, 0)) -> str:
    """PTX of the walk kernel for a compute capability (needs NVVM, not a GPU): to check what it compiles to."""
    from numba import types

    signature = (
        types.uint8[::1], types.int64, types.int64, types.int64, types.float64[:, ::1], types.int64[:, ::1],
        types.bool_[:, ::1],
    )  # fmt: skip
    ptx, _ = cuda.compile_ptx(_walk_kernel, signature, cc=compute_capability, fastmath=False)
    return str(ptx)
