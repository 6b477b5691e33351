"""Start, watch and stop a fleet's processes on this host.

Each process runs in its own process group; its stdout and stderr are read line by line and written with a
`[label]` prefix. A process that exits is restarted according to its policy with exponential back-off. On
``stop()`` (Ctrl-C) every process gets SIGINT, then SIGTERM after the grace period, then SIGKILL. On Linux a
process also gets SIGTERM when the supervising thread dies without stopping it (the launcher killed with
SIGKILL, a test runner that aborts): its own process group keeps Ctrl-C of the terminal from reaching it, so
nothing else would end it.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TextIO

from fleetslam.launch.description import ProcessSpec

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1


def _parent_death_signal() -> Callable[[], None] | None:
    """A ``preexec_fn`` asking the kernel to send the child SIGTERM when the thread that started it ends
    (Linux ``prctl(PR_SET_PDEATHSIG)``); None elsewhere. libc is looked up here, in the parent: after fork,
    the child only makes the call."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
    arguments = (_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)

    def set_parent_death_signal() -> None:
        prctl(*arguments)

    return set_parent_death_signal


@dataclass
class _Managed:
    spec: ProcessSpec
    process: subprocess.Popen[bytes] | None = None
    started_at: float = 0.0
    restarts: int = 0
    crashes_in_row: int = 0
    next_start_at: float | None = 0.0
    exit_codes: list[int] = field(default_factory=list)
    readers: list[threading.Thread] = field(default_factory=list)


class Supervisor:
    """Supervises processes on this host.

    Args:
        specs: processes to run.
        output: where prefixed log lines go.
        grace_s: seconds between SIGINT and SIGTERM (and between SIGTERM and SIGKILL) on stop.
        clock: monotonic clock (injectable for tests).
    """

    def __init__(
        self,
        specs: Sequence[ProcessSpec],
        *,
        output: TextIO,
        grace_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._managed = [_Managed(spec) for spec in specs]
        self._output = output
        self._output_lock = threading.Lock()
        self._grace_s = grace_s
        self._clock = clock
        self._preexec = _parent_death_signal()
        self._stopping = False

    # -- state -----------------------------------------------------------------------------------------
    def status(self) -> dict[str, dict[str, object]]:
        """Per label: pid (or None), restarts so far, exit codes seen."""
        return {
            m.spec.label: {
                "pid": m.process.pid if m.process is not None and m.process.poll() is None else None,
                "restarts": m.restarts,
                "exit_codes": list(m.exit_codes),
            }
            for m in self._managed
        }

    # -- lifecycle -------------------------------------------------------------------------------------
    def poll(self) -> bool:
        """Start what is due, reap what exited, schedule restarts; False once nothing is left to run."""
        now = self._clock()
        alive = False
        for managed in self._managed:
            process = managed.process
            if process is not None:
                code = process.poll()
                if code is None:
                    alive = True
                    if now - managed.started_at >= managed.spec.restart.stable_after_s:
                        managed.crashes_in_row = 0
                    continue
                self._reap(managed, code, now)
            if managed.next_start_at is not None and not self._stopping:
                alive = True
                if now >= managed.next_start_at:
                    self._start(managed, now)
        return alive

    def run(self, poll_interval_s: float = 0.1) -> None:
        """Supervise until every process has ended for good or ``stop()`` is called (Ctrl-C calls it)."""
        previous = signal.getsignal(signal.SIGINT)
        in_main_thread = threading.current_thread() is threading.main_thread()
        if in_main_thread:
            signal.signal(signal.SIGINT, lambda *_: self._request_stop())
            signal.signal(signal.SIGTERM, lambda *_: self._request_stop())
        try:
            while not self._stopping and self.poll():
                time.sleep(poll_interval_s)
        finally:
            self.stop()
            if in_main_thread:
                signal.signal(signal.SIGINT, previous)
                signal.signal(signal.SIGTERM, signal.SIG_DFL)

    def _request_stop(self) -> None:
        self._emit("launch", "shutting down (Ctrl-C)")
        self._stopping = True

    def stop(self) -> None:
        """Stop every process: SIGINT, then SIGTERM, then SIGKILL, each after the grace period."""
        self._stopping = True
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            running = [m for m in self._managed if m.process is not None and m.process.poll() is None]
            if not running:
                break
            for managed in running:
                assert managed.process is not None
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(managed.process.pid, sig)
            deadline = time.monotonic() + self._grace_s
            while time.monotonic() < deadline and any(m.process.poll() is None for m in running if m.process):
                time.sleep(0.05)
        for managed in self._managed:
            if managed.process is not None:
                managed.exit_codes.append(managed.process.wait())
                managed.process = None
            for reader in managed.readers:
                reader.join(timeout=2.0)
            managed.next_start_at = None

    # -- internals -------------------------------------------------------------------------------------
    def _start(self, managed: _Managed, now: float) -> None:
        spec = managed.spec
        env = {**os.environ, **spec.environment, "PYTHONUNBUFFERED": "1"}
        try:
            process = subprocess.Popen(
                spec.argv,
                env=env,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
                preexec_fn=self._preexec,
            )
        except OSError as err:
            self._emit(spec.label, f"cannot start {spec.argv[0]!r}: {err.strerror}")
            managed.exit_codes.append(127)
            self._schedule_restart(managed, 127, now)
            return
        managed.process = process
        managed.started_at = now
        managed.next_start_at = None
        self._emit(spec.label, f"started (pid {process.pid}): {' '.join(spec.argv)}")
        assert process.stdout is not None and process.stderr is not None
        managed.readers = [
            threading.Thread(target=self._pump, args=(spec.label, stream), daemon=True)
            for stream in (process.stdout, process.stderr)
        ]
        for reader in managed.readers:
            reader.start()

    def _reap(self, managed: _Managed, code: int, now: float) -> None:
        managed.process = None
        managed.exit_codes.append(code)
        for reader in managed.readers:
            reader.join(timeout=1.0)
        self._emit(managed.spec.label, f"exited with code {code}")
        self._schedule_restart(managed, code, now)

    def _schedule_restart(self, managed: _Managed, code: int, now: float) -> None:
        policy = managed.spec.restart
        wanted = policy.mode == "always" or (policy.mode == "on-failure" and code != 0)
        if not wanted or self._stopping:
            managed.next_start_at = None
            return
        if policy.max_restarts >= 0 and managed.restarts >= policy.max_restarts:
            self._emit(managed.spec.label, f"gave up after {managed.restarts} restarts")
            managed.next_start_at = None
            return
        delay = min(policy.max_backoff_s, policy.initial_backoff_s * (2**managed.crashes_in_row))
        managed.crashes_in_row += 1
        managed.restarts += 1
        managed.next_start_at = now + delay
        self._emit(managed.spec.label, f"restarting in {delay:.1f} s (restart {managed.restarts})")

    def _pump(self, label: str, stream: object) -> None:
        for raw in iter(stream.readline, b""):  # type: ignore[attr-defined]
            self._emit(label, raw.decode("utf-8", errors="replace").rstrip("\n"))

    def _emit(self, label: str, text: str) -> None:
        with self._output_lock:
            self._output.write(f"[{label}] {text}\n")
            self._output.flush()
