"""A real ROS 1 master (Debian's roscore) on a free loopback port, and the environment its tools need.

Tests here skip, naming the packages, when ROS 1 is not installed (``scripts/setup`` installs it as root).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import time
import xmlrpc.client
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from fleetslam.launch.supervisor import descendants

from ..support import free_port

ROS1_PACKAGES = (
    "python3-rosmaster python3-rostopic python3-rosservice python3-rosbag python3-std-msgs python3-std-srvs"
    " python3-sensor-msgs"
)


def need_ros1(*tools: str) -> None:
    missing = [t for t in ("roscore", *tools) if shutil.which(t) is None]
    if missing:
        pytest.skip(f"ROS 1 tools {missing} not installed (apt-get install {ROS1_PACKAGES}, or scripts/setup as root)")


def _answers(uri: str) -> bool:
    try:
        xmlrpc.client.ServerProxy(uri).getPid("/test")
    except OSError:
        return False
    return True


@dataclass
class Master:
    """A running roscore; ``restart()`` kills it and starts a fresh one on the same port."""

    port: int
    home: Path
    process: subprocess.Popen[bytes] | None = None

    @property
    def uri(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def env(self) -> dict[str, str]:
        return {**os.environ, "ROS_MASTER_URI": self.uri, "ROS_IP": "127.0.0.1", "ROS_HOME": str(self.home)}

    def start(self) -> None:
        log = (self.home / "roscore.log").open("ab")
        self.process = subprocess.Popen(
            ["roscore", "-p", str(self.port)],
            env=self.env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                xmlrpc.client.ServerProxy(self.uri).getPid("/test")
                return
            except OSError:
                time.sleep(0.2)
        raise RuntimeError(f"roscore did not come up on {self.uri}; see {self.home / 'roscore.log'}")

    def stop(self) -> None:
        """Stop roscore and everything it started. roslaunch puts rosmaster and rosout in sessions of their own and
        stops them one by one (15 s each at most): under load it was still at it when killed, and the orphaned
        rosmaster kept the port, so the next ``start`` found it answering ("another roscore/master is already
        running") and a "restarted" master was the old one."""
        if self.process is not None and self.process.poll() is None:
            started = descendants(self.process.pid)
            os.killpg(self.process.pid, signal.SIGINT)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
            for pid in started:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        self.process = None
        deadline = time.monotonic() + 10
        while _answers(self.uri):
            if time.monotonic() > deadline:
                raise RuntimeError(f"a ROS master still answers on {self.uri} after roscore was stopped")
            time.sleep(0.1)

    def restart(self) -> None:
        self.stop()
        self.start()


@pytest.fixture
def roscore(tmp_path: Path) -> Iterator[Master]:
    need_ros1()
    master = Master(free_port(), tmp_path / "ros_home")
    master.home.mkdir()
    master.start()
    yield master
    master.stop()
