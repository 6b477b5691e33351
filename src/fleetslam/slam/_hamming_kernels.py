"""Numba kernel for the exact two nearest binary words of each query (the vocabulary's hot path).

OpenCV's ``batchDistance`` with ``K=2`` keeps its top two by a generic insertion that costs several times the
distances themselves; a loop that XORs and counts bits of packed 64-bit lanes and keeps the best two gives the same
answer 3-6 times faster on one core, and 2.3 times faster again with the words stored lane by lane (see
:func:`nearest2_packed`). Ties resolve to the lowest row, as in the NumPy and
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
def nearest2_packed(queries, words_by_lane):  # type: ignore[no-untyped-def]
    """For each row of ``queries`` (Q, L) uint64: the word at the smallest Hamming distance, that distance and the
    second smallest (``NO_SECOND`` when there are fewer than two words). ``words_by_lane`` (L, W) uint64 holds the
    words lane by lane (one row per 64-bit lane: the packed words transposed).

    Lane by lane, the distances to all words are sums over contiguous rows, which LLVM vectorises (a vector
    popcount of four lanes at a time); four lanes go in one pass over the words (an ORB descriptor is four lanes,
    AKAZE's and BRISK's eight), so the distances are written once per four lanes. Then one scan keeps the best two.
    2.3 times faster than the same loop over word-major rows, with the same answer."""
    n, lanes = queries.shape
    m = words_by_lane.shape[1]
    nearest = np.full(n, -1, np.int64)
    first = np.full(n, NO_SECOND, np.int64)
    second = np.full(n, NO_SECOND, np.int64)
    distance = np.zeros(m, np.int64)
    for i in range(n):
        # The first pass over the words writes the distances and the later ones add to them: zeroing them first and
        # always adding (one loop body fewer) made the search 1.5 times slower (24 against 16 ms, 400 x 50,000).
        lane = 0
        while lane < lanes:
            if lane + 4 <= lanes:
                q0, q1, q2, q3 = queries[i, lane], queries[i, lane + 1], queries[i, lane + 2], queries[i, lane + 3]
                w0, w1 = words_by_lane[lane], words_by_lane[lane + 1]
                w2, w3 = words_by_lane[lane + 2], words_by_lane[lane + 3]
                if lane == 0:
                    for j in range(m):
                        distance[j] = (
                            _popcount(q0 ^ w0[j])
                            + _popcount(q1 ^ w1[j])
                            + _popcount(q2 ^ w2[j])
                            + _popcount(q3 ^ w3[j])
                        )
                else:
                    for j in range(m):
                        distance[j] += (
                            _popcount(q0 ^ w0[j])
                            + _popcount(q1 ^ w1[j])
                            + _popcount(q2 ^ w2[j])
                            + _popcount(q3 ^ w3[j])
                        )
                lane += 4
            else:
                q0, w0 = queries[i, lane], words_by_lane[lane]
                if lane == 0:
                    for j in range(m):
                        distance[j] = _popcount(q0 ^ w0[j])
                else:
                    for j in range(m):
                        distance[j] += _popcount(q0 ^ w0[j])
                lane += 1
        best, runner_up, best_row = NO_SECOND, NO_SECOND, -1
        for j in range(m):
            d = distance[j]
            if d < runner_up:
                if d < best:
                    runner_up, best, best_row = best, d, j
                else:
                    runner_up = d
        nearest[i], first[i], second[i] = best_row, best, runner_up
    return nearest, first, second
