"""Issue 18, D5: a peer sending huge messages. Zenoh's default (1 GiB messages) let two 300 MB payloads grow the
router and the subscriber by ~300 MB each, never returned; our sessions and routers refuse messages over
MAX_MESSAGE_BYTES while they arrive. Router and attacker run as their own processes so that each one's memory is
its own; the node under attack is this process."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from typing import Any

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.context import MAX_MESSAGE_BYTES
from fleetslam.middleware.wire import encode_attachment, topic_key
from fleetslam.msg.typesys import get_type, serialize

from ..support import free_port, wait_until

ATTACKER = """
import json, sys, time, zenoh
endpoint, key, size, attachment, small = sys.argv[1], sys.argv[2], int(sys.argv[3]), bytes.fromhex(sys.argv[4]), \\
    bytes.fromhex(sys.argv[5])
config = zenoh.Config()
config.insert_json5("connect/endpoints", json.dumps([endpoint]))
config.insert_json5("scouting/multicast/enabled", "false")
config.insert_json5("transport/link/rx/max_message_size", str(2 * size))
session = zenoh.open(config)
time.sleep(0.5)
for _ in range(2):  # blocking congestion control: Zenoh's default would drop a message this big on the way
    session.put(key, bytes(size), attachment=attachment, congestion_control=zenoh.CongestionControl.BLOCK)
time.sleep(1.0)
for k in range(20):
    session.put(key, small, attachment=attachment)
    time.sleep(0.02)
session.close()
"""


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmRSS for process {pid}")


def test_huge_messages_are_refused_on_arrival_and_leave_router_and_node_their_memory() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("ZENOH_")}
    router = subprocess.Popen(
        [sys.executable, "-m", "fleetslam.cli.main", "router", "--listen", endpoint],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**env, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    try:
        assert router.stdout is not None and "listening on" in router.stdout.readline()
        received: list[Any] = []
        with Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}) as ctx:
            node = Node("listener", context=ctx, namespace="/c3po")
            chatter = node.create_subscription("std_msgs/msg/String", "chatter", received.append, QoSProfile(depth=50))
            router_before, node_before = _rss_mb(router.pid), _rss_mb(os.getpid())
            size = 300 * 1024 * 1024
            assert size > MAX_MESSAGE_BYTES
            small = serialize(get_type("std_msgs/msg/String")(data="still here"), "std_msgs/msg/String")
            attack = subprocess.run(
                [sys.executable, "-c", ATTACKER, endpoint, topic_key(0, "/c3po/chatter", "std_msgs/msg/String"),
                 str(size), encode_attachment(1, time.time_ns(), bytes(range(16))).hex(), small.hex()],
                env=env, capture_output=True, text=True, timeout=120,
            )  # fmt: skip
            assert attack.returncode == 0, attack.stderr
            # The messages after the huge ones still arrive, and nothing big was delivered.
            assert wait_until(lambda: len(received) == 20, 10.0), len(received)
            assert {m.data for m in received} == {"still here"} and chatter.statistics.total_errors == 0
            router_growth = _rss_mb(router.pid) - router_before
            node_growth = _rss_mb(os.getpid()) - node_before
            assert router_growth < 50 and node_growth < 50, (router_growth, node_growth)
            node.destroy()
    finally:
        router.terminate()
        router.wait(timeout=10)
