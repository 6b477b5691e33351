"""The operator console of a running demo in Chromium: the real simulated robots, maps and camera.

Holds the deadman and W: c3po's ground-truth pose moves forward; releases: it stops within 0.5 s; closes the
page while driving: the robot stops within its command timeout.
"""

from __future__ import annotations

import io
import math
import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from fleetslam.middleware import Context, Node, QoSProfile

from ..support import free_port, wait_until
from .conftest import save_screenshot

pytest.importorskip("mujoco")


def test_console_drives_a_simulated_robot(browser_page: Any, tmp_path: Path) -> None:
    from fleetslam.launch.demo import run_demo

    page, errors = browser_page
    router_port, port = free_port(), free_port()
    demo = threading.Thread(
        target=run_demo,
        kwargs={"robots": ["c3po", "r2d2"], "duration_s": 50.0, "out_dir": tmp_path / "demo", "port": port,
                "router_port": router_port, "output": io.StringIO()},
        daemon=True,
    )  # fmt: skip
    demo.start()
    truth: list[tuple[float, float, float, float]] = []
    with Context(
        router=f"tcp/127.0.0.1:{router_port}", listen="tcp/127.0.0.1:0", environ={}, router_timeout_s=30
    ) as ctx:
        watcher = Node("watcher", context=ctx, statistics_period_s=0)

        def on_truth(msg: Any) -> None:
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
            truth.append((time.monotonic(), p.x, p.y, yaw))

        watcher.create_subscription("nav_msgs/msg/Odometry", "/c3po/ground_truth/odom", on_truth, QoSProfile(depth=100))

        def console_up() -> bool:
            with socket.socket() as probe:
                return probe.connect_ex(("127.0.0.1", port)) == 0

        assert wait_until(console_up, 60.0), "the demo's console never came up"
        page.goto(f"http://127.0.0.1:{port}/", timeout=60000)
        page.wait_for_function("window.fleetslam && window.fleetslam.voxelCount > 0", timeout=60000)
        page.wait_for_function("window.fleetslam.lastFrameSeq > 2", timeout=30000)
        assert page.evaluate("window.fleetslam.selected") == "c3po"

        def speed_since(t0: float) -> float:
            samples = [s for s in truth if s[0] >= t0]
            if len(samples) < 2:
                return math.nan
            (ta, xa, ya, _), (tb, xb, yb, _) = samples[0], samples[-1]
            return math.hypot(xb - xa, yb - ya) / max(tb - ta, 1e-3)

        page.keyboard.down("Space")
        page.keyboard.down("w")
        pressed = time.monotonic()
        time.sleep(2.0)
        start = next(s for s in truth if s[0] >= pressed + 0.8)
        end = truth[-1]
        forward = (end[1] - start[1]) * math.cos(start[3]) + (end[2] - start[2]) * math.sin(start[3])
        assert forward > 0.2, f"moved {forward:.3f} m forward while W was held"
        save_screenshot(page, tmp_path, "demo-console-driving.png")
        page.keyboard.up("w")
        page.keyboard.up("Space")
        released = time.monotonic()
        time.sleep(1.2)
        assert speed_since(released + 0.5) < 0.05, "still moving 0.5 s after releasing the deadman"
        page.keyboard.down("Space")
        page.keyboard.down("w")
        time.sleep(1.5)
        page.close()
        closed = time.monotonic()
        time.sleep(1.5)
        # Within the command timeout (0.5 s) plus braking, the robot stands; the autopilot waits 3 s to resume.
        assert speed_since(closed + 1.0) < 0.05, "still driving after the page was closed"
    demo.join(120)
    assert not errors, errors
