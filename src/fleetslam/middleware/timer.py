"""Timers: a small thread per timer posts ticks to the node's executor, which runs the callback."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from fleetslam.errors import MiddlewareError

if TYPE_CHECKING:
    from fleetslam.middleware.node import Node


class Timer:
    """Calls a callback on the node's executor every ``period_s`` (skips ticks while one is still queued)."""

    def __init__(self, node: Node, period_s: float, callback: Callable[[], Any]) -> None:
        if period_s <= 0:
            raise MiddlewareError(f"timer period must be positive, got {period_s}")
        self.period_s = period_s
        self.callback = callback
        self._node = node
        self._stop = threading.Event()
        self._queued = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"timer:{node.name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_tick = time.monotonic() + self.period_s
        while not self._stop.wait(max(0.0, next_tick - time.monotonic())):
            next_tick += self.period_s
            if time.monotonic() - next_tick > self.period_s:  # fell far behind: don't burst
                next_tick = time.monotonic() + self.period_s
            if not self._queued.is_set():
                self._queued.set()
                self._node.call_soon(self._fire)

    def _fire(self) -> None:
        self._queued.clear()
        if not self._stop.is_set():
            self.callback()

    def cancel(self) -> None:
        self._stop.set()
