"""A node's executor (one thread running its callbacks in order) and the rate-limited log of its errors."""

from __future__ import annotations

import collections
import functools
import logging
import os
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
    """One thread running a node's callbacks in order.

    Work waits in a deque. The thread sleeps on a wake-up file descriptor (an eventfd; a pipe where the platform
    has none) only when it finds the deque empty, and a post writes to it only then: a post to a busy executor is
    an append, nothing more. The write gives up the GIL for its system call, so a woken thread that gets going
    meanwhile takes the GIL at once instead of finding it held by the poster and sleeping again until the poster
    lets it go (a queue's lock release keeps the GIL). Measured for the lone 1 MB frame's hand-off in
    docs/middleware-api.md ("The executor's wake-up per lone frame").
    """

    def __init__(self, name: str, on_error: Callable[[str, BaseException], None]) -> None:
        self._work: collections.deque[Callable[[], None] | None] = collections.deque()
        self._waiting = False
        """The thread sleeps on the fd, or is about to (it looks at the deque once more after setting this)."""
        self._wake_lock = threading.Lock()
        """A wake-up's write and the closing of the fds never overlap (a closed fd's number may be reused)."""
        self._closed = False
        self._fds, self._signal, self._sleep = _wakeup_fds()
        self._on_error = on_error
        self._thread = threading.Thread(target=self._run, name=f"executor:{name}", daemon=True)
        self._thread.start()

    def post(self, work: Callable[[], None]) -> None:
        """Queue work for the thread (from any thread); wakes it only if it sleeps."""
        self._work.append(work)
        if self._waiting:
            self._wake()

    def _wake(self) -> None:
        with self._wake_lock:
            if self._waiting and not self._closed:  # one write per sleep, whoever posts
                self._waiting = False
                self._signal()

    def _run(self) -> None:
        work, sleep = self._work, self._sleep
        try:
            while True:
                if not work:
                    self._waiting = True
                    if not work:  # a post between the first look and the flag did not see the flag: look again
                        sleep()
                    self._waiting = False
                    continue
                item = work.popleft()
                if item is None:
                    return
                try:
                    item()
                except Exception as err:
                    self._on_error(getattr(item, "__qualname__", "callback"), err)
        finally:
            with self._wake_lock:
                self._closed = True
                for fd in self._fds:
                    os.close(fd)

    def stop(self, timeout_s: float = 2.0) -> None:
        self._work.append(None)  # the end of the line: what was posted before it still runs
        if self._waiting:
            self._wake()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        if self._thread.is_alive():  # a long callback: the exit must still wait for it (see lifetime)
            join_at_exit(self._thread)


def _wakeup_fds() -> tuple[tuple[int, ...], Callable[[], object], Callable[[], object]]:
    """The executor's wake-up: its fds, the write that wakes it and the read it sleeps in (both without the GIL)."""
    if hasattr(os, "eventfd"):  # Linux: a counter, read back to 0 in one call however many writes came
        fd = os.eventfd(0, os.EFD_CLOEXEC)
        return (fd,), functools.partial(os.eventfd_write, fd, 1), functools.partial(os.eventfd_read, fd)
    read_fd, write_fd = os.pipe()  # at most a few bytes wait in it: a post writes only to a sleeping executor
    return (read_fd, write_fd), functools.partial(os.write, write_fd, b"\0"), functools.partial(os.read, read_fd, 512)
