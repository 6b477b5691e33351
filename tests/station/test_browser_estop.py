"""The console in real Chromium renders the e-stop from the robot's reply, never from the click, and shows a refusal;
the statistics table groups a topic's subscribers under it."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from fleetslam.middleware import Context, Node
from fleetslam.msg.typesys import get_type
from fleetslam.station.server import StationServer

from ..support import wait_until
from .conftest import RobotUnderTest


def _button(page) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    return page.evaluate(
        "(() => { const b = document.getElementById('estop'); return {text: b.textContent, "
        "engaged: b.classList.contains('engaged'), message: document.getElementById('estop-message').textContent}; })()"
    )


def test_the_e_stop_shows_engaged_only_once_the_robot_confirms_and_a_refusal_is_shown(
    browser_page,
    make_context: Callable[..., Context],
    test_robot: RobotUnderTest,  # type: ignore[no-untyped-def]
) -> None:
    page, errors = browser_page
    answer = threading.Event()
    refuse = threading.Event()
    requests: list[bool] = []
    response = get_type("std_srvs/srv/SetBool_Response")

    def on_estop(request: Any) -> Any:  # a robot that takes its time, and may refuse
        requests.append(bool(request.data))
        answer.wait(2.5)
        if refuse.is_set():
            return response(success=False, message="interlock: arm is moving")
        return response(success=True, message="latched" if request.data else "released")

    slow = Node("base", context=make_context("r2d2"))
    slow.create_service("std_srvs/srv/SetBool", "e_stop", on_estop)
    slow.create_publisher("nav_msgs/msg/Odometry", "odom")  # what makes the console find an agent
    try:
        with StationServer(make_context(), port=0) as server:
            page.goto(server.url)
            page.wait_for_function("window.fleetslam && window.fleetslam.agents.includes('r2d2')", timeout=20000)
            page.click("#agents button:has-text('r2d2')")
            page.click("#estop")
            assert wait_until(lambda: requests == [True], 5.0)
            pending = _button(page)
            assert not pending["engaged"] and "waiting for r2d2" in pending["text"]  # asked, not confirmed
            answer.set()
            page.wait_for_function("document.getElementById('estop').classList.contains('engaged')", timeout=10000)
            engaged = _button(page)
            assert "ENGAGED" in engaged["text"] and "latched" in engaged["message"]
            # Releasing, refused by the robot: the button stays engaged and the operator reads why.
            answer.clear()
            refuse.set()
            page.click("#estop")
            answer.set()
            page.wait_for_function("document.getElementById('estop-message').textContent.includes('refused')",
                                   timeout=10000)  # fmt: skip
            refused = _button(page)
            assert refused["engaged"] and "interlock: arm is moving" in refused["message"]
            assert requests == [True, False]
            # Another robot's e-stop is its own: c3po's button is not engaged.
            page.click("#agents button:has-text('c3po')")
            assert not _button(page)["engaged"]
            # The statistics: each topic once per agent, its subscribers listed under it with both node names.
            page.wait_for_function("document.querySelectorAll('#stats tr.subscriber').length > 0", timeout=15000)
            topics = page.evaluate(
                "[...document.querySelectorAll('#stats tr.topic td:first-child')].map(t => t.textContent)"
            )
            subscribers = page.evaluate(
                "[...document.querySelectorAll('#stats tr.subscriber td:first-child')].map(t => t.textContent)"
            )
            assert topics and all("→" in s for s in subscribers)
    finally:
        slow.destroy()
    assert not errors, errors
