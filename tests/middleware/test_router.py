import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from fleetslam.errors import ConfigError, MiddlewareError
from fleetslam.middleware import Context, Node, Router
from fleetslam.msg.typesys import get_type

from ..support import free_port, wait_until

String = get_type("std_msgs/msg/String")


def test_router_sees_its_peers_and_relays_between_them(
    router_endpoint: str, make_context: Callable[..., Context]
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint], environ={}) as router:
        # The Rust Display form of a ZID: lowercase hex without leading zeros (31 digits in one run of 16).
        assert router.listen == [endpoint] and re.fullmatch(r"[0-9a-f]{1,32}", router.zid)
        a = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={})
        b = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={})
        try:
            assert wait_until(lambda: {a.zid, b.zid} <= set(router.peers()))
            got: list[str] = []
            Node("listener", context=b).create_subscription("std_msgs/msg/String", "/x", lambda m: got.append(m.data))
            pub = Node("talker", context=a).create_publisher("std_msgs/msg/String", "/x")
            assert wait_until(lambda: pub.matched_subscriptions == 1)
            pub.publish(String(data="via router"))
            assert wait_until(lambda: got == ["via router"])
        finally:
            a.close()
            b.close()


def test_router_errors_name_the_problem(router_endpoint: str, tmp_path: Path) -> None:
    with pytest.raises(MiddlewareError, match=f"cannot start the router listening on {router_endpoint}"):
        Router([router_endpoint], environ={})  # the fixture's router holds the port
    bad = tmp_path / "router.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(ConfigError, match="ZENOH_ROUTER_CONFIG_URI="):
        Router(environ={"ZENOH_ROUTER_CONFIG_URI": str(bad)})


def test_router_config_file_and_overrides(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    path = tmp_path / "router.json5"
    path.write_text(
        f"{{ mode: 'router', listen: {{ endpoints: ['{endpoint}'] }},"
        " scouting: { multicast: { enabled: false } } }"
    )
    env = {"ZENOH_ROUTER_CONFIG_URI": str(path), "ZENOH_CONFIG_OVERRIDE": "adminspace/enabled=true;broken"}
    with Router(None, environ=env) as router:
        assert router.listen == [endpoint]
        with Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}) as ctx:
            assert [str(z) for z in ctx.session.info.routers_zid()] == [router.zid]


def test_router_command_runs_until_ctrl_c() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    process = subprocess.Popen(
        [sys.executable, "-m", "fleetslam.cli.main", "router", "--listen", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert "listening on " + endpoint in line, line
        start = time.monotonic()
        with Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}) as ctx:
            assert list(ctx.session.info.routers_zid())
        assert time.monotonic() - start < 2.0  # reached at once (4 ms measured), within the 2 s router check
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=10) == 0
        assert "Traceback" not in process.stdout.read()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
