"""Numba kernel for the exact two nearest binary words of each query (the vocabulary's hot path).

OpenCV's ``batchDistance`` with ``K=2`` keeps its top two by a generic insertion that costs several times the
distances themselves; a plain loop that XORs and counts bits of packed 64-bit lanes and keeps the best two in
registers gives the same answer 3-6 times faster on one core. Ties resolve to the lowest row, as in the NumPy and
OpenCV paths.
"""

from __future__ import annotations

import numpy as np

from fleetslam._imports import require

numba = require("numba", "slam")
njit, types = numba.njit, numba.types
intrinsic = require("numba.extending", "slam").intrinsic
llvm_ir = require("llvmlite.ir", "slam")

#: Distance returned as the second nearest when there is only one word.
NO_SECOND = 1 << 30


@intrinsic
def _popcount(typingctx, value):  # type: ignore[no-untyped-def]
    """The number of set bits of a uint64 (LLVM's ctpop: one POPCNT instruction on x86-64)."""
    signature = types.int64(types.uint64)

    def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]
        ctpop = builder.module.declare_intrinsic("llvm.ctpop", [llvm_ir.IntType(64)])
        return builder.call(ctpop, [args[0]])

    return signature, codegen


@njit(cache=True, nogil=True)
def nearest2_packed(queries, words):  # type: ignore[no-untyped-def]
    """For each row of ``queries`` (Q, L) uint64: the row of ``words`` (W, L) uint64 at the smallest Hamming
    distance, that distance and the second smallest (``NO_SECOND`` when W < 2)."""
    n, lanes = queries.shape
    m = words.shape[0]
    nearest = np.full(n, -1, np.int64)
    first = np.full(n, NO_SECOND, np.int64)
    second = np.full(n, NO_SECOND, np.int64)
    for i in range(n):
        best, runner_up, best_row = NO_SECOND, NO_SECOND, -1
        for j in range(m):
            distance = 0
            for lane in range(lanes):
                distance += _popcount(queries[i, lane] ^ words[j, lane])  # type: ignore[call-arg]
            if distance < runner_up:
                if distance < best:
                    runner_up, best, best_row = best, distance, j
                else:
                    runner_up = distance
        nearest[i], first[i], second[i] = best_row, best, runner_up
    return nearest, first, second
