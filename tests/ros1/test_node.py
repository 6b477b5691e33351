"""The pure-Python ROS 1 node against a real roscore and rostopic: hostile peers, master restarts, no master."""

from __future__ import annotations

import logging
import os
import signal
import socket
import struct
import subprocess
import xmlrpc.client

import pytest

from fleetslam.ros1 import messages, tcpros
from fleetslam.ros1.node import MasterUnreachableError, Ros1Node

from ..support import free_port, wait_until
from .conftest import Master, need_ros1

STRING = messages.type_info("std_msgs/String")


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _echo_once(master: Master, topic: str, timeout_s: float = 60.0) -> str:
    # rostopic (rospy) takes seconds to import on a loaded 2-core machine: a generous bound, not a speed claim.
    done = subprocess.run(
        ["rostopic", "echo", "-n", "1", topic], env=master.env, capture_output=True, text=True, timeout=timeout_s
    )
    return done.stdout


def test_unreachable_master_is_named() -> None:
    uri = f"http://127.0.0.1:{free_port()}"
    with pytest.raises(MasterUnreachableError, match=f"ROS master at {uri} is unreachable"):
        Ros1Node("lonely", master_uri=uri).start()


def test_hostile_peers_do_not_stop_a_latched_publisher(roscore: Master) -> None:
    need_ros1("rostopic")
    with Ros1Node("hostile_target", master_uri=roscore.uri) as node:
        pub = node.advertise("/greeting", STRING, latch=True)
        pub.publish(_string("still here"))
        for garbage in (b"\xff\xff\xff\x7f", b"\x10\x00\x00\x00short", struct.pack("<I", 8) + b"\x04\x00\x00\x00abcd"):
            with socket.create_connection(("127.0.0.1", node.tcpros_port)) as sock:
                sock.sendall(garbage)
        with socket.create_connection(("127.0.0.1", node.tcpros_port)) as sock:  # wrong type asked for
            sock.sendall(tcpros.encode_header({"topic": "/greeting", "md5sum": "0" * 32, "callerid": "/x"}))
            assert "error" in tcpros.recv_header(sock)
        assert 'data: "still here"' in _echo_once(roscore, "/greeting")


def test_registers_again_when_the_master_restarts(roscore: Master) -> None:
    need_ros1("rostopic")
    with Ros1Node("survivor", master_uri=roscore.uri, watchdog_period_s=0.2) as node:
        pub = node.advertise("/after_restart", STRING, latch=True)
        pub.publish(_string("again"))
        roscore.restart()
        # roscore restarts in ~3 s on a quiet machine, several times that beside a running demo.
        assert wait_until(lambda: node.registrations == 2, timeout_s=30)
        assert 'data: "again"' in _echo_once(roscore, "/after_restart")


def test_a_master_that_stalls_and_answers_again_is_not_a_restart(
    roscore: Master, caplog: pytest.LogCaptureFixture
) -> None:
    # A loaded master misses the watchdog's 2 s getPid and answers again, still holding our registrations:
    # registering again would count a restart that never happened (and made the restart test above flaky).
    need_ros1("rostopic")
    caplog.set_level(logging.INFO, logger="fleetslam.ros1.node")
    with Ros1Node("patient", master_uri=roscore.uri, watchdog_period_s=0.2) as node:
        pub = node.advertise("/through_a_stall", STRING, latch=True)
        pub.publish(_string("kept"))
        master_pid = int(xmlrpc.client.ServerProxy(roscore.uri).getPid("/test")[2])
        os.kill(master_pid, signal.SIGSTOP)
        try:
            assert wait_until(lambda: "lost" in caplog.text, timeout_s=30)
        finally:
            os.kill(master_pid, signal.SIGCONT)
        assert wait_until(lambda: "answers again" in caplog.text, timeout_s=30)
        assert node.registrations == 1
        assert 'data: "kept"' in _echo_once(roscore, "/through_a_stall")


def test_malformed_xmlrpc_and_bogus_publisher_updates_are_survived(roscore: Master) -> None:
    need_ros1("rostopic")
    with Ros1Node("xmlrpc_target", master_uri=roscore.uri) as node:
        pub = node.advertise("/steady", STRING, latch=True)
        pub.publish(_string("steady"))
        node.subscribe("/nobody", STRING, lambda data, publisher: None)
        host, port = node.uri.removeprefix("http://").rstrip("/").split(":")
        for body in (b"<methodCall><methodName>getPid", b"\x00\xff" * 100, b"<?xml version='1.0'?><nope/>"):
            with socket.create_connection((host, int(port))) as sock:
                sock.sendall(b"POST / HTTP/1.0\r\nContent-Length: %d\r\n\r\n" % len(body) + body)
                answer = b"".join(iter(lambda: sock.recv(4096), b""))
                assert answer.startswith(b"HTTP/1.0 200") and b"faultCode" in answer, answer[:200]
        proxy = xmlrpc.client.ServerProxy(node.uri)
        for bogus in (["ftp://nowhere/"], [f"http://127.0.0.1:{free_port()}/"], "not a list"):
            assert proxy.publisherUpdate("/evil", "/nobody", bogus)[0] == 1
        assert proxy.requestTopic("/evil", "/steady", [["UDPROS"]])[0] == 0
        assert proxy.getPid("/evil")[1:] == ["", os.getpid()]
        assert 'data: "steady"' in _echo_once(roscore, "/steady")
