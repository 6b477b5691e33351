"""The atomic fetch-and-add that hands out work to the threads of the ray-tracing kernel."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from fleetslam.mapping._atomics import fetch_add


@njit(parallel=True)
def _claim_all(claims: int) -> tuple[np.ndarray, np.ndarray]:
    counters = np.zeros(2, dtype=np.int64)
    seen = np.zeros(claims, dtype=np.int64)
    for _ in prange(claims):
        ticket = fetch_add(counters, 1, 1)
        seen[ticket] += 1
    return counters, seen


def test_every_claim_gets_its_own_ticket_across_threads() -> None:
    counters, seen = _claim_all(200_000)
    assert counters[1] == 200_000
    assert counters[0] == 0  # only the addressed counter moves
    assert (seen == 1).all()  # a lost update would hand one ticket out twice and leave another unused


@njit
def _add(counters: np.ndarray, index: int, amount: int) -> tuple[int, int]:
    before = fetch_add(counters, index, amount)
    return before, counters[index]


def test_returns_the_value_before_the_addition() -> None:
    counters = np.array([5, 40], dtype=np.int64)
    assert _add(counters, 1, 7) == (40, 47)
    assert _add(counters, 0, -5) == (5, 0)
