"""A node's executor (one thread running its callbacks in order) and the rate-limited log of its errors."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable

from fleetslam.middleware.lifetime import join_at_exit

log = logging.getLogger("fleetslam.middleware.node")
"""Warnings keep the logger they always had (users filter on it)."""


class RateLimitedLogger:
    """Logs the first few occurrences of each cause, then at most one line per interval with a count."""

    def __init__(self, first: int = 3, interval_s: float = 10.0) -> None:
        self._first = first
        self._interval = interval_s
        self._state: dict[str, list[float]] = {}
        self._lock = threading.Lock()

    def warning(self, cause: str, message: str, *args: object) -> None:
        now = time.monotonic()
        with self._lock:
            count, last, suppressed = self._state.get(cause, [0, 0.0, 0])
            count += 1
            emit = count <= self._first or now - last >= self._interval
            self._state[cause] = [count, now if emit else last, 0 if emit else suppressed + 1]
        if emit:
            more = f" ({int(suppressed)} more suppressed)" if suppressed else ""
            log.warning(message + more, *args)


class Executor:
    """One thread running a node's callbacks in order."""

    def __init__(self, name: str, on_error: Callable[[str, BaseException], None]) -> None:
        self._queue: queue.SimpleQueue[Callable[[], None] | None] = queue.SimpleQueue()
        self.post: Callable[[Callable[[], None]], None] = self._queue.put
        """Queue work for the thread (from any thread): the queue's own put, one call less for every sample."""
        self._on_error = on_error
        self._thread = threading.Thread(target=self._run, name=f"executor:{name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        get = self._queue.get
        while True:
            work = get()
            if work is None:
                return
            try:
                work()
            except Exception as err:
                self._on_error(getattr(work, "__qualname__", "callback"), err)

    def stop(self, timeout_s: float = 2.0) -> None:
        self._queue.put(None)
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        if self._thread.is_alive():  # a long callback: the exit must still wait for it (see lifetime)
            join_at_exit(self._thread)
