"""Services across the bridge, both ways, checked with the ROS 1 tools themselves (rosservice, a rospy server)
and fleetslam's own (``fleetslam service call``, the middleware's client): answers, failures, time-outs, types
one side lacks, and hostile callers."""

from __future__ import annotations

import logging
import re
import shutil
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from fleetslam.cli.main import main
from fleetslam.errors import ServiceError
from fleetslam.middleware import Context, Node
from fleetslam.msg.typesys import message_from_dict
from fleetslam.ros1 import messages, tcpros
from fleetslam.ros1.bridge import Ros1Bridge, TopicRule
from fleetslam.ros1.node import Ros1Node

from ..support import wait_until
from .conftest import Master, need_ros1

SERVICES = Path(__file__).resolve().parent / "ros1_services.py"
TIMEOUT_S = 1.0


@pytest.fixture
def bridge(roscore: Master, make_context: Callable[..., Context]) -> Iterator[Ros1Bridge]:
    need_ros1("rosservice")
    with (
        Ros1Node("fleetslam_bridge", master_uri=roscore.uri) as ros1,
        Node("fleetslam_bridge", context=make_context()) as node,
        Ros1Bridge(node, ros1, services_to_ros1=[TopicRule.parse("/c3po/*")],
                   services_from_ros1=[TopicRule.parse("/ros1/*")], service_timeout_s=TIMEOUT_S,
                   scan_period_s=0.2) as bridge,
    ):  # fmt: skip
        yield bridge


@pytest.fixture
def fleet_server(make_context: Callable[..., Context]) -> Iterator[Node]:
    """An ordinary fleet node with services of the SLAM node's types, a failing one, a slow one, and one of a
    type ROS 1 lacks."""
    calls: list[object] = []

    def reset(request: Any) -> Any:
        calls.append(request)
        return message_from_dict("std_srvs/srv/Trigger_Response", {"success": True, "message": f"reset {len(calls)}"})

    def pause(request: Any) -> Any:
        if not request.data:
            raise RuntimeError("cannot resume: no map")
        return message_from_dict("std_srvs/srv/SetBool_Response", {"success": True, "message": "paused"})

    def save(request: Any) -> Any:
        return message_from_dict(
            "fleetslam_msgs/srv/SaveMap_Response", {"success": True, "message": "saved", "path": request.path}
        )

    def slow(request: Any) -> Any:
        time.sleep(TIMEOUT_S + 1.0)
        return message_from_dict("std_srvs/srv/Trigger_Response", {"success": True})

    node = Node("slam", context=make_context(), namespace="/c3po")
    node.create_service("std_srvs/srv/Trigger", "slam/reset", reset)
    node.create_service("std_srvs/srv/SetBool", "slam/pause", pause)
    node.create_service("fleetslam_msgs/srv/SaveMap", "slam/save_map", save)
    node.create_service("example_interfaces/srv/AddTwoInts", "add", lambda r: None)
    slow_node = Node("slow", context=make_context(), namespace="/c3po")  # its own executor: it blocks no one
    slow_node.create_service("std_srvs/srv/Trigger", "slow", slow)
    yield node
    slow_node.destroy()
    node.destroy()


def _tool(master: Master, *args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    # rospy tools take seconds to import on a loaded 2-core machine: a generous bound, not a speed claim.
    return subprocess.run(list(args), env=master.env, capture_output=True, text=True, timeout=timeout_s)


def _debian_md5sums() -> dict[str, str]:
    python = shutil.which("python3", path="/usr/bin")
    script = "import std_srvs.srv as s; print(s.Trigger._md5sum, s.SetBool._md5sum)"
    done = subprocess.run([python or "python3", "-c", script], capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        pytest.skip(f"Debian's std_srvs not importable (apt-get install python3-std-srvs): {done.stderr[-200:]}")
    trigger, set_bool = done.stdout.split()
    return {"std_srvs/Trigger": trigger, "std_srvs/SetBool": set_bool}


def test_rosservice_calls_fleet_services(
    roscore: Master, bridge: Ros1Bridge, fleet_server: Node, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="fleetslam.ros1.bridge")
    assert wait_until(lambda: len(bridge.services_bridged_to_ros1) == 4, timeout_s=15), bridge.services_bridged_to_ros1
    listed = _tool(roscore, "rosservice", "list").stdout.split()
    assert {"/c3po/slam/reset", "/c3po/slam/pause", "/c3po/slam/save_map", "/c3po/slow"} <= set(listed), listed
    assert "/c3po/add" not in listed  # example_interfaces/AddTwoInts has no ROS 1 counterpart: skipped, said once
    skipped = [r.getMessage() for r in caplog.records if "/c3po/add" in r.getMessage()]
    assert len(skipped) == 1 and "example_interfaces/srv/AddTwoInts" in skipped[0], skipped

    info = _tool(roscore, "rosservice", "info", "/c3po/slam/reset").stdout
    assert "Type: std_srvs/Trigger" in info and "Node: /fleetslam_bridge" in info, info
    reset = _tool(roscore, "rosservice", "call", "/c3po/slam/reset")
    assert reset.returncode == 0 and "success: True" in reset.stdout and 'message: "reset 1"' in reset.stdout, reset
    paused = _tool(roscore, "rosservice", "call", "/c3po/slam/pause", "data: true")
    assert 'message: "paused"' in paused.stdout, paused

    # The fleet handler's failure is the ROS 1 caller's error, naming the service and the reason.
    failed = _tool(roscore, "rosservice", "call", "/c3po/slam/pause", "data: false")
    assert failed.returncode != 0 and "cannot resume: no map" in failed.stdout + failed.stderr, failed

    # The bridge's reply headers carry the md5sums Debian's std_srvs has.
    with Ros1Node("prober", master_uri=roscore.uri) as prober:
        for name, srv_type in (("/c3po/slam/reset", "std_srvs/Trigger"), ("/c3po/slam/pause", "std_srvs/SetBool")):
            header = prober.probe_service(name)
            assert header["md5sum"] == _debian_md5sums()[srv_type], header
            assert (header["type"], header["request_type"]) == (srv_type, f"{srv_type}Request")
        # fleetslam_msgs has no ROS 1 package to load for rosservice; our own client calls it.
        save_map = messages.service_info("fleetslam_msgs/SaveMap")
        request = messages.message_to_ros1(
            message_from_dict("fleetslam_msgs/srv/SaveMap_Request", {"path": "/tmp/map.ot"}), save_map.request_name
        )
        answer = prober.call_service("/c3po/slam/save_map", save_map, request, timeout_s=10)
        response = messages.ros1_to_message(answer, save_map.response_name)
        assert (response.success, response.path) == (True, "/tmp/map.ot")

        # A fleet service slower than the bridge's timeout: the ROS 1 caller hears so, and the bridge goes on.
        trigger = messages.service_info("std_srvs/Trigger")
        started = time.monotonic()
        with pytest.raises(ServiceError, match=r"/c3po/slow.*gave no response"):
            prober.call_service("/c3po/slow", trigger, b"", timeout_s=10)
        assert time.monotonic() - started < TIMEOUT_S + 2.0
        answer = prober.call_service("/c3po/slam/reset", trigger, b"", timeout_s=10)
        assert messages.ros1_to_message(answer, trigger.response_name).message == "reset 2"
    assert bridge.service_counts()["/c3po/slam/pause"] == {"calls": 1, "errors": 1}


def test_fleet_calls_a_rospy_service(
    roscore: Master,
    bridge: Ros1Bridge,
    make_context: Callable[..., Context],
    fleet_env: str,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="fleetslam.ros1.bridge")
    server = subprocess.Popen(
        ["/usr/bin/python3", str(SERVICES), "--slow", str(TIMEOUT_S + 2.0)],
        env={**roscore.env, "ROS_NAMESPACE": "/ros1"}, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert wait_until(lambda: len(bridge.services_bridged_from_ros1) == 3, timeout_s=30), server.poll()
        assert main(["service", "call", "/ros1/trigger", "std_srvs/srv/Trigger", "--timeout", "10"]) == 0
        out = capsys.readouterr().out
        assert "success: true" in out and "message: from rospy, call 1" in out, out

        with Node("caller", context=make_context()) as caller:
            set_bool = caller.create_client("std_srvs/srv/SetBool", "/ros1/set")
            assert set_bool.wait_for_service(10)
            on = message_from_dict("std_srvs/srv/SetBool_Request", {"data": True})
            assert set_bool.call(on, timeout=10).message == "switched on"
            # rospy's handler raises: the fleet caller gets the middleware's failure with rospy's reason.
            off = message_from_dict("std_srvs/srv/SetBool_Request", {"data": False})
            with pytest.raises(ServiceError, match=r"/ros1/set.*refusing to switch off"):
                set_bool.call(off, timeout=10)
            # Slower than the bridge's timeout: a failure within it, and the next call is answered.
            slow = caller.create_client("std_srvs/srv/Trigger", "/ros1/slow")
            trigger = caller.create_client("std_srvs/srv/Trigger", "/ros1/trigger")
            empty = message_from_dict("std_srvs/srv/Trigger_Request", {})
            started = time.monotonic()
            with pytest.raises(ServiceError, match=f"no response within {TIMEOUT_S} s"):
                slow.call(empty, timeout=10)
            assert time.monotonic() - started < TIMEOUT_S + 2.0
            assert trigger.call(empty, timeout=10).message == "from rospy, call 2"
    finally:
        server.terminate()
        server.wait(timeout=10)
    # rospy's own logger services are roscpp types the fleet lacks: skipped, one line each.
    skipped = [r.getMessage() for r in caplog.records if "roscpp/GetLoggers" in r.getMessage()]
    assert len(skipped) == 1 and "/ros1/services/get_loggers" in skipped[0], skipped
    assert bridge.service_counts()["/ros1/set"] == {"calls": 1, "errors": 1}


def test_hostile_service_callers_close_only_their_connection(
    roscore: Master, bridge: Ros1Bridge, fleet_server: Node
) -> None:
    assert wait_until(lambda: "/c3po/slam/pause" in bridge.services_bridged_to_ros1, timeout_s=15)
    port = bridge.ros1.tcpros_port
    set_bool = messages.service_info("std_srvs/SetBool")
    good = {"service": "/c3po/slam/pause", "md5sum": set_bool.md5sum, "callerid": "/evil"}

    def exchange(header: dict[str, str], body: bytes = b"") -> bytes:
        with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
            sock.sendall(tcpros.encode_header(header) + body)
            return b"".join(iter(lambda: sock.recv(4096), b""))

    assert b"error=service header lacks md5sum" in exchange({"service": "/c3po/slam/pause", "callerid": "/evil"})
    assert b"does not provide service /nowhere" in exchange({**good, "service": "/nowhere"})
    assert b"error=/c3po/slam/pause is std_srvs/SetBool" in exchange({**good, "md5sum": "0" * 32})
    # A request longer than the limit, a truncated one, and bytes that are no SetBool request.
    for body in (b"\xff\xff\xff\x7f", b"\x10\x00\x00\x00short"):
        answer = exchange(good, body)
        assert b"type=std_srvs/SetBool" in answer and answer.endswith(b"response_type=std_srvs/SetBoolResponse")
    answer = exchange(good, struct.pack("<I", 0))
    assert re.search(rb"\x00.{4}/c3po/slam/pause: cannot convert a std_srvs/srv/SetBool_Request", answer, re.S), answer
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:  # persistent: calls until closed
        sock.sendall(tcpros.encode_header({**good, "persistent": "1"}))
        assert tcpros.recv_header(sock)["type"] == "std_srvs/SetBool"
        for _ in range(2):
            sock.sendall(tcpros.frame(b"\x01"))
            assert tcpros.recv_exact(sock, 1) == b"\x01"
            response = messages.ros1_to_message(tcpros.recv_message(sock), set_bool.response_name)
            assert response.message == "paused"
    with socket.create_connection(("127.0.0.1", port)) as sock:  # a silent caller: held a few seconds, no more
        sock.sendall(tcpros.encode_header(good))
        paused = _tool(roscore, "rosservice", "call", "/c3po/slam/pause", "data: true")
    assert 'message: "paused"' in paused.stdout, paused


def test_a_closed_node_withdraws_its_services(roscore: Master) -> None:
    need_ros1("rosservice")
    trigger = messages.service_info("std_srvs/Trigger")
    with Ros1Node("short_lived", master_uri=roscore.uri) as node:
        node.advertise_service("/short_lived/ping", trigger, lambda request, caller: b"\x01" + tcpros.frame(b"pong"))
        assert "/short_lived/ping" in node.services_of()
    assert "/short_lived/ping" not in _tool(roscore, "rosservice", "list").stdout


def test_cli_bridges_a_remapped_service(roscore: Master, fleet_server: Node, fleet_env: str) -> None:
    """`fleetslam bridge ros1 --service-to-ros1 /c3po/slam/reset:=/reset` in its own process, as a user runs it."""
    need_ros1("rosservice")
    fleetslam = Path(sys.executable).with_name("fleetslam")
    bridge = subprocess.Popen(
        [str(fleetslam), "bridge", "ros1", "--service-to-ros1", "/c3po/slam/reset:=/reset", "--duration", "60"],
        env=roscore.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        with Ros1Node("watcher", master_uri=roscore.uri) as watcher:
            assert wait_until(lambda: "/reset" in watcher.services_of(), timeout_s=30), bridge.poll()
        reset = _tool(roscore, "rosservice", "call", "/reset")
        assert 'message: "reset 1"' in reset.stdout, reset
    finally:
        bridge.terminate()
        _, errors = bridge.communicate(timeout=20)
    assert bridge.returncode == 0, errors
    assert "/reset" not in _tool(roscore, "rosservice", "list").stdout.split()  # withdrawn at exit
