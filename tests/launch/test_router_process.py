"""The demo's router in a child process: nodes reach each other through it, its usage is measured, it stops."""

from __future__ import annotations

import pytest

from fleetslam.errors import MiddlewareError
from fleetslam.launch.router_process import RouterProcess, accepts_connections
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.typesys import get_type

from ..support import free_port, wait_until


def test_nodes_meet_through_the_router_process_and_it_stops() -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with RouterProcess(endpoint) as router:
        assert accepts_connections("127.0.0.1", port)
        received: list[str] = []
        with (
            Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}) as a,
            Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}) as b,
        ):
            Node("listener", context=b, statistics_period_s=0).create_subscription(
                "std_msgs/msg/String", "/chatter", lambda msg, _: received.append(msg.data), QoSProfile(depth=10)
            )
            talker = Node("talker", context=a, statistics_period_s=0).create_publisher(
                "std_msgs/msg/String", "/chatter"
            )
            hello = get_type("std_msgs/msg/String")(data="hello")
            assert wait_until(lambda: talker.publish(hello) is None and bool(received), 10.0)
        usage = router.usage()
        assert usage is not None and usage.label == "router" and usage.cpu_s >= 0.0 and usage.peak_rss_mib > 0
    assert router.process.poll() is not None  # stopped with the block
    assert not accepts_connections("127.0.0.1", port)
    assert router.usage() is None


def test_a_router_that_cannot_start_is_a_clear_error() -> None:
    port = free_port()
    with (
        RouterProcess(f"tcp/127.0.0.1:{port}"),
        pytest.raises(MiddlewareError, match="something already listens there"),
    ):
        RouterProcess(f"tcp/127.0.0.1:{port}")
    with pytest.raises(MiddlewareError, match="tcp/HOST:PORT or tls/HOST:PORT"):
        RouterProcess("udp/127.0.0.1:7447")
