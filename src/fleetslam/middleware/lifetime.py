"""Middleware contexts a program leaves open are closed at exit, without cutting off threads that still use them.

A Python callback that Zenoh invokes runs on a (non-daemon) thread Zenoh starts when the subscriber or queryable
is declared, and that thread lives as long as the session. Left open, a session therefore keeps the interpreter
waiting at exit forever; and when its threads were started from a daemon thread, finalization tears them down
inside Zenoh's native code, which aborts the process ("FATAL: exception not rethrown").

So: ``threading``'s exit hook, which runs before the interpreter joins non-daemon threads, closes the open
contexts unless a thread of the program's own is still running (it may still use a context); then an `atexit`
hook, which runs once those threads have ended and before finalization, closes whatever is left.
"""

from __future__ import annotations

import atexit
import logging
import threading
import weakref
from collections.abc import Callable
from typing import Protocol, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")


class Closable(Protocol):
    def close(self) -> None: ...


_open: weakref.WeakSet[Closable] = weakref.WeakSet()
_callback_threads: weakref.WeakSet[threading.Thread] = weakref.WeakSet()


def close_at_exit(context: Closable) -> None:
    """Close ``context`` at exit if the program has not (closing twice must be harmless)."""
    _open.add(context)


def declare_with_callback(declare: Callable[[], T]) -> T:
    """Run a Zenoh declaration that takes a Python callback, noting the thread Zenoh starts to run it."""
    before = set(threading.enumerate())
    declared = declare()
    _callback_threads.update(set(threading.enumerate()) - before)
    return declared


def _program_threads_running() -> bool:
    current = threading.current_thread()
    return any(
        t is not current and not t.daemon and t.is_alive() and t not in _callback_threads for t in threading.enumerate()
    )


def close_open_contexts() -> None:
    for context in list(_open):
        try:
            context.close()
        except Exception as err:  # exiting anyway: report, never mask the program's own exit status
            log.warning("closing a middleware context at exit: %s", err)


def _before_joining_threads() -> None:
    if not _program_threads_running():
        close_open_contexts()


# CPython has had threading's hook since 3.9; it is private, hence the fallback to atexit alone.
_register_threading_hook = getattr(threading, "_register_atexit", None)
if _register_threading_hook is not None:
    _register_threading_hook(_before_joining_threads)
atexit.register(close_open_contexts)
