from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from fleetslam.cli.main import main
from fleetslam.middleware import Context, Node

from ..support import wait_until


def test_robot_routes_lists_the_registry(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["robot", "routes"]) == 0
    out = capsys.readouterr().out
    assert "loop:" in out and "survey:" in out and "square:" in out


def test_robot_run_serves_odometry_and_reports_bad_config(
    fleet_env: str, make_context: Callable[..., Context], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["robot", "run", "--set", "wheel_radius=-1", "--duration", "0.1"]) == 2
    assert "wheel_radius" in capsys.readouterr().err
    odoms: list[Any] = []
    with Node("listener", context=make_context()) as listener:
        listener.create_subscription("nav_msgs/msg/Odometry", "/c3po/odom", odoms.append)
        result: list[int] = []
        worker = threading.Thread(target=lambda: result.append(main(["robot", "run", "--robot", "c3po",
                                                                      "--duration", "2.5"])))  # fmt: skip
        started = time.monotonic()
        worker.start()
        assert wait_until(lambda: len(odoms) >= 10, 5.0)
        worker.join(10.0)
        assert result == [0]
        rate = len(odoms) / (time.monotonic() - started)
        assert rate > 10.0  # 125 odometries (50 Hz for 2.5 s) over start-up + 2.5 s: 38 Hz measured
