"""Start, watch and stop a fleet's processes on this host.

Each process runs in its own process group; its stdout and stderr are read line by line and written with a
`[label]` prefix. A process that exits is restarted according to its policy with exponential back-off. On
``stop()`` (Ctrl-C) every process gets SIGINT, then SIGTERM after the grace period, then SIGKILL. On Linux a
process also gets SIGTERM when the supervising thread dies without stopping it (the launcher killed with
SIGKILL, a test runner that aborts): its own process group keeps Ctrl-C of the terminal from reaching it, so
nothing else would end it.

:meth:`Supervisor.usage` reports each process's CPU time and peak memory from ``/proc`` (Linux): CPU % of one
core averaged over its lifetime, peak resident set (``VmHWM``); a restarted process counts all its runs.
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
from pathlib import Path
from typing import TextIO

from fleetslam.launch.description import ProcessSpec

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1
#: How often the running processes' CPU and memory are sampled (the figures of a run that ends count too).
USAGE_SAMPLE_PERIOD_S = 1.0


@dataclass(frozen=True)
class ProcessSample:
    """CPU and memory of one process since it started, read from ``/proc``."""

    cpu_s: float
    """User and system CPU time (s) of all its threads, and of its children that it waited for."""
    wall_s: float
    """Time since it started (s)."""
    peak_rss_mib: float
    """Peak resident set size (``VmHWM``, MiB)."""


def sample_process(pid: int, *, proc: Path = Path("/proc")) -> ProcessSample | None:
    """CPU time, age and peak memory of a running process; None when it is gone or ``/proc`` is not Linux's."""
    try:
        stat = (proc / str(pid) / "stat").read_text()
        status = (proc / str(pid) / "status").read_text()
        uptime_s = float((proc / "uptime").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    # The command name (field 2) may hold spaces and parentheses: the fields after it follow the last ')'.
    fields = stat[stat.rindex(")") + 2 :].split()
    ticks = os.sysconf("SC_CLK_TCK")
    utime, stime, cutime, cstime = (int(v) for v in fields[11:15])
    started_s = int(fields[19]) / ticks
    peak_kib = next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmHWM:")), 0)
    return ProcessSample((utime + stime + cutime + cstime) / ticks, max(0.0, uptime_s - started_s), peak_kib / 1024)


def descendants(root: int, *, proc: Path = Path("/proc")) -> list[int]:
    """Every process below ``root`` now, children first (from ``/proc``; empty where it is not Linux's)."""
    parent: dict[int, int] = {}
    for stat in proc.glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        parent[int(stat.parent.name)] = int(text[text.rindex(")") + 2 :].split()[1])
    found, frontier = [], [root]
    while frontier:
        frontier = [pid for pid, ppid in parent.items() if ppid in frontier]
        found += frontier
    return found


def _exited(pid: int) -> bool:
    """Whether a child has exited, without reaping it (Linux ``waitid`` with ``WNOWAIT``; False elsewhere)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        return os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
    except ChildProcessError:
        return False


@dataclass(frozen=True)
class ProcessUsage:
    """What one supervised process cost over its runs."""

    label: str
    pid: int | None
    """Its latest process id (None if it never started)."""
    cpu_s: float
    """CPU time (s), all runs."""
    wall_s: float
    """Time it ran (s), all runs."""
    peak_rss_mib: float
    """Largest peak resident set of its runs (MiB)."""
    restarts: int = 0

    @property
    def cpu_percent(self) -> float:
        """Average CPU load in % of one core (100 % = one core busy all the time)."""
        return 100.0 * self.cpu_s / self.wall_s if self.wall_s > 0 else 0.0

    def as_dict(self) -> dict[str, object]:
        return {"label": self.label, "pid": self.pid, "cpu_percent": round(self.cpu_percent, 2),
                "cpu_s": round(self.cpu_s, 3), "wall_s": round(self.wall_s, 3),
                "peak_rss_mib": round(self.peak_rss_mib, 1), "restarts": self.restarts}  # fmt: skip

    @classmethod
    def between(cls, label: str, pid: int, start: ProcessSample, end: ProcessSample) -> ProcessUsage:
        """Usage of a process between two samples (peak memory: the process's own peak at ``end``)."""
        return cls(label, pid, end.cpu_s - start.cpu_s, end.wall_s - start.wall_s, end.peak_rss_mib)


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
    last_pid: int | None = None
    sample: ProcessSample | None = None
    """Latest sample of the running process."""
    ended_cpu_s: float = 0.0
    ended_wall_s: float = 0.0
    ended_peak_rss_mib: float = 0.0
    """Totals of the runs that ended (their last samples)."""

    def end_run(self) -> None:
        if self.sample is not None:
            self.ended_cpu_s += self.sample.cpu_s
            self.ended_wall_s += self.sample.wall_s
            self.ended_peak_rss_mib = max(self.ended_peak_rss_mib, self.sample.peak_rss_mib)
        self.sample = None


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
        self._next_sample_at = 0.0
        self._usage_lock = threading.Lock()

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

    def usage(self) -> list[ProcessUsage]:
        """CPU and peak memory of every process, all its runs (the running one read now), in start order.

        Running processes are sampled every ``USAGE_SAMPLE_PERIOD_S`` and once more when they have exited, before
        they are reaped (a zombie still shows its CPU time, no longer its memory: the peak is that of the samples).
        """
        with self._usage_lock:
            self._sample_running()
            return [
                ProcessUsage(
                    m.spec.label,
                    m.last_pid,
                    m.ended_cpu_s + (m.sample.cpu_s if m.sample else 0.0),
                    m.ended_wall_s + (m.sample.wall_s if m.sample else 0.0),
                    max(m.ended_peak_rss_mib, m.sample.peak_rss_mib if m.sample else 0.0),
                    m.restarts,
                )
                for m in self._managed
            ]

    def _sample_running(self) -> None:
        for managed in self._managed:
            process = managed.process  # another thread may reap it meanwhile: its run ends under the lock
            sample = sample_process(process.pid) if process is not None else None
            if sample is None:
                continue
            if managed.sample is not None:  # an exited, not yet reaped process shows no memory any more
                sample = ProcessSample(
                    sample.cpu_s, sample.wall_s, max(sample.peak_rss_mib, managed.sample.peak_rss_mib)
                )
            managed.sample = sample

    # -- lifecycle -------------------------------------------------------------------------------------
    def poll(self) -> bool:
        """Start what is due, reap what exited, schedule restarts; False once nothing is left to run."""
        now = self._clock()
        alive = False
        if now >= self._next_sample_at:
            self._next_sample_at = now + USAGE_SAMPLE_PERIOD_S
            with self._usage_lock:
                self._sample_running()
        for managed in self._managed:
            process = managed.process
            if process is not None:
                if _exited(process.pid):  # its final figures, while the zombie still shows them
                    with self._usage_lock:
                        self._sample_running()
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
        with self._usage_lock:  # the stopped processes' final figures, before they are reaped
            self._sample_running()
        for managed in self._managed:
            if managed.process is not None:
                managed.exit_codes.append(managed.process.wait())
                managed.process = None
                with self._usage_lock:
                    managed.end_run()
            for reader in managed.readers:
                reader.join(timeout=2.0)
            managed.next_start_at = None

    # -- internals -------------------------------------------------------------------------------------
    def _child_setup(self, niceness: int) -> Callable[[], None] | None:
        """The ``preexec_fn`` of a child: the parent-death signal, and its niceness (run in the child)."""
        death_signal = self._preexec
        if niceness == 0:
            return death_signal

        def setup() -> None:
            if death_signal is not None:
                death_signal()
            os.nice(niceness)

        return setup

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
                preexec_fn=self._child_setup(spec.niceness),
            )
        except OSError as err:
            self._emit(spec.label, f"cannot start {spec.argv[0]!r}: {err.strerror}")
            managed.exit_codes.append(127)
            self._schedule_restart(managed, 127, now)
            return
        managed.process = process
        managed.last_pid = process.pid
        managed.started_at = now
        managed.next_start_at = None
        with self._usage_lock:
            managed.sample = sample_process(process.pid)
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
        with self._usage_lock:
            managed.end_run()
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
