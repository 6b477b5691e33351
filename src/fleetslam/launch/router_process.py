"""The fleet's router as a child process of a launcher (the demo): started before any node, stopped after them.

In a process of its own its CPU shows apart from the launcher's (the demo's report lists both), and the launcher's
own work (monitoring, recording) does not share a GIL or an event loop with the routing.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType

from fleetslam.errors import MiddlewareError
from fleetslam.launch.supervisor import ProcessSample, ProcessUsage, _parent_death_signal, sample_process


def _tcp_port(endpoint: str) -> tuple[str, int]:
    """Host and port of a ``tcp/HOST:PORT`` or ``tls/HOST:PORT`` endpoint."""
    scheme, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    if scheme not in ("tcp", "tls") or not host or not port.isdigit():
        raise MiddlewareError(f"the router process needs a tcp/HOST:PORT or tls/HOST:PORT endpoint, not {endpoint!r}")
    return host.strip("[]"), int(port)


class RouterProcess:
    """``fleetslam router --listen ENDPOINT`` (with ``security``: ``--security DIR``, whose router config listens
    on ENDPOINT) in a child process; a context manager.

    Raises:
        MiddlewareError: the port is taken, or the router did not accept connections within ``start_timeout_s``
            (its output says why).
    """

    def __init__(self, endpoint: str, *, security: Path | None = None, start_timeout_s: float = 20.0) -> None:
        self.endpoint = endpoint
        host, port = _tcp_port(endpoint)
        if accepts_connections(host, port):
            raise MiddlewareError(f"cannot start the router on {endpoint}: something already listens there")
        # Its output goes to a file, not a pipe nobody drains (a full pipe would block the router).
        self._log = tempfile.TemporaryFile()  # noqa: SIM115 (closed in _stop)
        where = ["--listen", endpoint] if security is None else ["--security", str(security)]
        self.process = subprocess.Popen(
            [sys.executable, "-m", "fleetslam.cli.main", "router", *where],
            stdout=self._log, stderr=subprocess.STDOUT, preexec_fn=_parent_death_signal(),
        )  # fmt: skip
        deadline = time.monotonic() + start_timeout_s
        while not accepts_connections(host, port):
            if self.process.poll() is not None or time.monotonic() > deadline:
                output = self._stop()
                raise MiddlewareError(f"the router on {endpoint} did not start: {output.strip() or 'no output'}")
            time.sleep(0.05)
        self._start: ProcessSample | None = sample_process(self.process.pid)

    def usage(self, label: str = "router") -> ProcessUsage | None:
        """CPU and peak memory since it accepted connections (None once it is gone)."""
        end = sample_process(self.process.pid)
        if self._start is None or end is None:
            return None
        return ProcessUsage.between(label, self.process.pid, self._start, end)

    def _stop(self) -> str:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(10.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self._log.closed:
            return ""
        self._log.seek(0)
        output = self._log.read()[-4000:].decode(errors="replace")
        self._log.close()
        return output

    def close(self) -> None:
        """Stop routing (SIGINT, then SIGKILL after 10 s); idempotent."""
        self._stop()

    def __enter__(self) -> RouterProcess:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self.close()


def accepts_connections(host: str, port: int) -> bool:
    """Whether something listens on ``host:port`` (TCP)."""
    try:
        with socket.create_connection((host, port), timeout=0.2):
            return True
    except OSError:
        return False
