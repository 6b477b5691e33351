"""A node's executor (its callbacks one at a time, in order, on its thread) and the rate-limited log of its errors."""

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
    """Runs a node's callbacks one at a time, in the order they were posted: on its own thread, or (see
    :meth:`run_here`) on the thread that brings the work while the executor is idle."""

    def __init__(self, name: str, on_error: Callable[[str, BaseException], None]) -> None:
        self._queue: queue.SimpleQueue[Callable[[], None] | None] = queue.SimpleQueue()
        self.post: Callable[[Callable[[], None]], None] = self._queue.put
        """Queue work for the thread (from any thread): the queue's own put, one call less for every sample."""
        self._on_error = on_error
        self._running = threading.Lock()
        """Held while a callback runs, on whichever thread: the node's callbacks run one at a time."""
        self._guest: int | None = None
        """The thread that runs a callback through :meth:`run_here` now (its ident), if any."""
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name=f"executor:{name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        get, running, call = self._queue.get, self._running, self._call
        while True:
            work = get()
            if work is None:
                return
            with running:
                call(work)

    def _call(self, work: Callable[[], None]) -> None:
        """Run one callback; what it raises is reported, never passed on (on either thread)."""
        try:
            work()
        except Exception as err:
            self._on_error(getattr(work, "__qualname__", "callback"), err)

    def run_here(self, work: Callable[[], None]) -> bool:
        """Run ``work`` on the calling thread at once if the executor is idle (nothing queued, no callback
        running), else return False (the caller posts it).

        A subscription's receive thread, awake with a lone sample, delivers it this way instead of waking the
        executor's thread for it: one thread switch less per message (a 1 MB image's subscriber spent ~25 µs more
        per message than raw Zenoh's callback thread, the most of it in that hand-off). Callbacks still run one at
        a time. Work posted by another thread at the very moment the executor takes it from the queue may run
        after this one: the two arrived together, and neither was first.
        """
        if self._stopped or not self._queue.empty() or not self._running.acquire(blocking=False):
            return False
        self._guest = threading.get_ident()
        try:
            self._call(work)
        finally:
            self._guest = None
            self._running.release()
        return True

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stopped = True
        self._queue.put(None)
        # A callback that stops its own node's executor (on either thread) returns before the thread ends; waiting
        # here would wait for itself (the executor's thread may be waiting for the callback's turn to end).
        from_callback = threading.current_thread() is self._thread or self._guest == threading.get_ident()
        deadline = time.monotonic() + timeout_s
        if not from_callback:
            self._thread.join(timeout_s)
        if self._thread.is_alive():  # a long callback, or this one: the exit must still wait for it (see lifetime)
            join_at_exit(self._thread)
        elif not from_callback and self._running.acquire(timeout=max(0.0, deadline - time.monotonic())):
            self._running.release()  # a callback that ran on another thread (run_here) has ended too
