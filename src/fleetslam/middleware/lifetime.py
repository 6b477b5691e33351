"""Middleware contexts a program leaves open are closed at exit, without cutting off threads that still use them.

A Python callback that Zenoh invokes runs on a (non-daemon) thread Zenoh starts when the subscriber or queryable
is declared, and that thread lives as long as the session. Left open, a session therefore keeps the interpreter
waiting at exit forever; and when its threads were started from a daemon thread, finalization tears them down
inside Zenoh's native code, which aborts the process ("FATAL: exception not rethrown").

So: ``threading``'s exit hook, which runs before the interpreter joins non-daemon threads, closes the open
contexts unless a thread of the program's own is still running (it may still use a context); then an `atexit`
hook, which runs once those threads have ended and before finalization, closes whatever is left and waits for
the nodes' executors that were still finishing a callback when their node was destroyed. A daemon thread that
is inside Zenoh when finalization starts aborts the process the same way.
"""

from __future__ import annotations

import atexit
import logging
import threading
import time
import weakref
from collections.abc import Callable
from typing import Protocol, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")


class Closable(Protocol):
    def close(self) -> None: ...


_open: weakref.WeakSet[Closable] = weakref.WeakSet()
_callback_threads: weakref.WeakSet[threading.Thread] = weakref.WeakSet()
_finishing: weakref.WeakSet[threading.Thread] = weakref.WeakSet()

#: How long the exit waits, in all, for executors still finishing a callback.
FINISH_TIMEOUT_S = 30.0


def close_at_exit(context: Closable) -> None:
    """Close ``context`` at exit if the program has not (closing twice must be harmless)."""
    _open.add(context)


def declare_with_callback(declare: Callable[[], T]) -> T:
    """Run a Zenoh declaration that takes a Python callback, noting the thread Zenoh starts to run it."""
    before = set(threading.enumerate())
    declared = declare()
    _callback_threads.update(set(threading.enumerate()) - before)
    return declared


def note_callback_thread(thread: threading.Thread) -> None:
    """Count ``thread`` as one of the middleware's callback threads (not one of the program's own)."""
    _callback_threads.add(thread)


def join_at_exit(thread: threading.Thread) -> None:
    """Wait for ``thread`` (told to stop, still finishing its work) before the interpreter finalizes."""
    _finishing.add(thread)


def _program_threads_running() -> bool:
    current = threading.current_thread()
    return any(
        t is not current and not t.daemon and t.is_alive() and t not in _callback_threads for t in threading.enumerate()
    )


def _close_open_contexts() -> None:
    for context in list(_open):
        try:
            context.close()
        except Exception as err:  # exiting anyway: report, never mask the program's own exit status
            log.warning("closing a middleware context at exit: %s", err)


def _before_joining_threads() -> None:
    if not _program_threads_running():
        _close_open_contexts()


def _before_finalizing() -> None:
    _close_open_contexts()
    deadline = time.monotonic() + FINISH_TIMEOUT_S
    for thread in list(_finishing):
        thread.join(max(0.0, deadline - time.monotonic()))
        if thread.is_alive():
            log.warning("exiting while %s is still running a callback", thread.name)


# CPython has had threading's hook since 3.9; it is private, hence the fallback to atexit alone.
_register_threading_hook = getattr(threading, "_register_atexit", None)
if _register_threading_hook is not None:
    _register_threading_hook(_before_joining_threads)
atexit.register(_before_finalizing)
