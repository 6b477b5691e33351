"""Colour and depth images paired by stamp, newest pair first (pure, thread-safe): the SLAM node's frame budget.

A camera publishes colour and depth separately; a pair is complete when both of one stamp arrived. The consumer
(the SLAM worker) always takes the newest complete pair: a pair that completes while another waits replaces it,
and the replaced one is counted as dropped — a node that cannot keep up with the camera falls back to a lower
frame rate instead of an ever-growing delay. Unpaired halves are kept only for the last few stamps, evicted in
arrival order, so images with wrong or far-future stamps cannot hold the queue (a stamp-ordered eviction would
keep those forever).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any


@dataclass
class FramePair:
    """A colour and a depth message of one stamp, and when the pair completed (monotonic seconds)."""

    stamp_ns: int
    rgb: Any
    depth: Any
    completed: float


class FrameQueue:
    """Pairs colour and depth by stamp; hands out the newest complete pair (see the module docstring)."""

    def __init__(self, max_pending: int = 4) -> None:
        self.max_pending = max_pending
        self._rgb: OrderedDict[int, Any] = OrderedDict()
        self._depth: OrderedDict[int, Any] = OrderedDict()
        self._ready: FramePair | None = None
        self._cond = threading.Condition()
        self._closed = False
        self.received = 0
        """Camera frames seen (distinct stamps, counted at their first half)."""
        self.dropped = 0
        """Frames never handed out: complete pairs replaced by a newer one before the consumer took them, and
        halves evicted without their partner (the other half lost on the way or overwritten in a full queue)."""

    def put_rgb(self, stamp_ns: int, msg: Any) -> None:
        self._put(stamp_ns, msg, self._rgb, self._depth, rgb_first=True)

    def put_depth(self, stamp_ns: int, msg: Any) -> None:
        self._put(stamp_ns, msg, self._depth, self._rgb, rgb_first=False)

    def _put(
        self, stamp_ns: int, msg: Any, mine: OrderedDict[int, Any], other: OrderedDict[int, Any], *, rgb_first: bool
    ) -> None:
        with self._cond:
            partner = other.pop(stamp_ns, None)
            if partner is None:
                if stamp_ns not in mine:
                    self.received += 1
                mine[stamp_ns] = msg
                mine.move_to_end(stamp_ns)
                while len(mine) > self.max_pending:
                    mine.popitem(last=False)
                    self.dropped += 1
                return
            rgb, depth = (msg, partner) if rgb_first else (partner, msg)
            if self._ready is not None:
                self.dropped += 1
            self._ready = FramePair(stamp_ns, rgb, depth, time.monotonic())
            self._cond.notify_all()

    @property
    def pending(self) -> int:
        """Frames seen but neither handed out nor dropped yet (a half waiting, or a pair ready)."""
        with self._cond:
            return len(self._rgb) + len(self._depth) + (self._ready is not None)

    def take(self, timeout_s: float | None = None) -> FramePair | None:
        """The newest complete pair, waiting up to ``timeout_s`` for one (None on timeout or when closed)."""
        with self._cond:
            if self._ready is None and not self._closed:
                self._cond.wait(timeout_s)
            pair, self._ready = self._ready, None
            return pair

    def close(self) -> None:
        """Wake a waiting consumer for good."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
