import json
import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from fleetslam.errors import ConfigError, MiddlewareError, RouterUnreachableError
from fleetslam.middleware import Context, Node
from fleetslam.middleware.context import apply_config_overrides, session_config
from fleetslam.middleware.recording import BagWriter

from ..support import free_port


def test_default_session_config_is_rmw_zenohs() -> None:
    config = session_config(connect=["tcp/localhost:7447"], listen=["tcp/localhost:0"], environ={})
    assert json.loads(config.get_json("mode")) == "peer"
    assert json.loads(config.get_json("connect/endpoints")) == ["tcp/localhost:7447"]
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/localhost:0"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("scouting/gossip/enabled")) is True
    assert json.loads(config.get_json("timestamping/enabled"))["peer"] is True
    assert json.loads(config.get_json("queries_default_timeout")) == 600000


def test_overrides_apply_and_bad_pairs_are_skipped(caplog: pytest.LogCaptureFixture) -> None:
    config = session_config(environ={})
    with caplog.at_level(logging.WARNING):
        skipped = apply_config_overrides(
            config, "queries_default_timeout=1234; no_equals_sign ;scouting/gossip/enabled=notjson;nonexistent/key=1"
        )
    assert json.loads(config.get_json("queries_default_timeout")) == 1234
    assert skipped == ["no_equals_sign", "scouting/gossip/enabled=notjson", "nonexistent/key=1"]
    assert caplog.text.count("ZENOH_CONFIG_OVERRIDE: skipping") == 3
    via_env = session_config(environ={"ZENOH_CONFIG_OVERRIDE": 'mode="client";bad'})
    assert json.loads(via_env.get_json("mode")) == "client"


def test_environment_configures_the_context(router_endpoint: str) -> None:
    env = {"FLEETSLAM_ROUTER": f" {router_endpoint} ", "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0", "FLEETSLAM_AGENT": "c3po",
           "ROS_DOMAIN_ID": "7", "FLEETSLAM_STATISTICS": "0"}  # fmt: skip
    with Context(environ=env) as ctx:
        assert ctx.router_endpoints == [router_endpoint]
        assert (ctx.namespace, ctx.domain_id, ctx.statistics_enabled) == ("/c3po", 7, False)
        node = Node("base", context=ctx)
        assert node.fq_name == "/c3po/base"
        assert node.create_publisher("std_msgs/msg/String", "odom").key.startswith("7/c3po/odom/")
    # Explicit arguments win over the environment.
    with Context(environ=env, namespace="/r2d2", domain_id=0, statistics=True) as ctx:
        assert (ctx.namespace, ctx.domain_id, ctx.statistics_enabled) == ("/r2d2", 0, True)
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID='x'"):
        Context(environ={**env, "ROS_DOMAIN_ID": "x"})


def test_config_file_replaces_the_defaults(router_endpoint: str, tmp_path: Path) -> None:
    path = tmp_path / "session.json5"
    endpoints = f"connect: {{ endpoints: ['{router_endpoint}'] }}, listen: {{ endpoints: ['tcp/127.0.0.1:0'] }}"
    path.write_text(
        f"// a user's own session config\n{{ mode: 'peer', {endpoints},\n"
        " scouting: { multicast: { enabled: false } } }\n"
    )
    with Context(environ={"ZENOH_SESSION_CONFIG_URI": str(path)}) as ctx:  # no FLEETSLAM_ROUTER: the file's
        assert ctx.router_endpoints == [router_endpoint]
        assert list(ctx.session.info.routers_zid())
    path.write_text("{ mode: 'peer', not_a_key: {} ")
    with pytest.raises(ConfigError, match="ZENOH_SESSION_CONFIG_URI="):
        Context(environ={"ZENOH_SESSION_CONFIG_URI": str(path)})


def test_no_router_fails_fast_with_instructions() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    start = time.monotonic()
    with pytest.raises(RouterUnreachableError) as caught:
        Context(environ={"FLEETSLAM_ROUTER": endpoint, "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0"})
    assert time.monotonic() - start < 3.5  # the default 2 s router check (2.02 s measured) + 1.5 s of start-up
    assert str(caught.value).startswith(f"no router at {endpoint}: start one with `fleetslam router`")
    assert "FLEETSLAM_ROUTER" in str(caught.value)
    # A client-mode session (set by an override) fails in open(): the same error.
    client = {"FLEETSLAM_ROUTER": endpoint, "ZENOH_CONFIG_OVERRIDE": 'mode="client"'}
    with pytest.raises(RouterUnreachableError, match=f"no router at {endpoint}"):
        Context(environ=client)
    # ZENOH_ROUTER_CHECK_ATTEMPTS<0 skips the check, as in rmw_zenoh.
    env = {"FLEETSLAM_ROUTER": endpoint, "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0", "ZENOH_ROUTER_CHECK_ATTEMPTS": "-1"}
    with Context(environ=env) as ctx:
        assert not list(ctx.session.info.routers_zid())


def test_one_id_counter_per_context_from_zero(make_context: Callable[..., Context]) -> None:
    ctx = make_context("c3po")
    first = Node("first", context=ctx, statistics_period_s=0)
    pub = first.create_publisher("std_msgs/msg/String", "a")
    second = Node("second", context=ctx, statistics_period_s=0)
    sub = second.create_subscription("std_msgs/msg/String", "a", lambda m: None)
    assert (first.node_id, pub.entity_id, second.node_id, sub.entity_id) == (0, 1, 2, 3)
    assert ctx.closables == [first, second]
    other = make_context()
    assert Node("n", context=other, statistics_period_s=0).node_id == 0


def test_context_closes_what_it_owns_in_order_and_forgets_what_was_closed(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    """The context knows closables, not nodes: a recording handed to it is closed with it, after the node that
    writes into it (owned first), so no callback writes into a closed bag."""
    ctx = make_context("c3po")
    early = Node("early", context=ctx, statistics_period_s=0)
    node = Node("recorder", context=ctx, statistics_period_s=0)
    publisher = node.create_publisher("std_msgs/msg/String", "out")
    writer = BagWriter(tmp_path / "bag")
    ctx.own(writer)
    assert ctx.closables == [early, node, writer]
    early.destroy()
    assert ctx.closables == [node, writer]
    ctx.disown(early)  # already forgotten: nothing happens
    ctx.close()
    assert ctx.closables == [] and (tmp_path / "bag" / "metadata.yaml").is_file()
    with pytest.raises(MiddlewareError, match="destroyed"):  # the node was closed with the context
        publisher.publish_raw(b"\x00\x01\x00\x00")


def test_close_undeclares_everything_and_is_idempotent(make_context: Callable[..., Context]) -> None:
    observer = make_context().graph
    ctx = make_context("c3po")
    node = Node("slam", context=ctx)
    node.create_publisher("std_msgs/msg/String", "a")
    node.create_service("std_srvs/srv/Trigger", "reset", lambda r: r)
    assert observer.wait_for(lambda g: len([t for t in g.tokens() if t.zid == ctx.zid]) == 3, 5)
    ctx.close()
    ctx.close()
    assert ctx.closed and ctx.closables == []
    assert observer.wait_for(lambda g: not [t for t in g.tokens() if t.zid == ctx.zid], 5)


def test_spin_returns_on_timeout_close_and_ctrl_c(make_context: Callable[..., Context]) -> None:
    ctx = make_context()
    start = time.monotonic()
    ctx.spin(0.1)
    assert 0.09 <= time.monotonic() - start < 1.0  # the 0.1 s timeout, 10 ms of clock slack below
    threading.Timer(0.1, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    ctx.spin(5.0)  # Ctrl-C: returns instead of raising KeyboardInterrupt
    assert time.monotonic() - start < 3.0  # Ctrl-C at 0.2 s, not the 5 s timeout

    # Two signals in quick succession (a supervisor signalling the process and its group): one clean return.
    def twice() -> None:
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Timer(0.1, twice).start()
    ctx.spin(5.0)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the program's handler is back
    threading.Timer(0.1, ctx.close).start()
    ctx.spin()
    assert ctx.closed


def test_taken_listen_endpoint_is_a_clear_error(router_endpoint: str) -> None:
    taken = router_endpoint  # the router listens there
    with pytest.raises(MiddlewareError, match=f"cannot open a Zenoh session .*listen \\['{taken}'\\].*in use"):
        Context(router=router_endpoint, listen=taken, environ={})


def test_the_context_knows_closables_not_nodes() -> None:
    """No import cycle: context.py imports nothing of the node modules, not even for typing, and no module reaches
    into the context's private members."""
    import ast

    import fleetslam.middleware
    import fleetslam.middleware.context as context_module

    tree = ast.parse(Path(context_module.__file__).read_text())
    imported = {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    node_modules = ("node", "publisher", "subscription", "service", "client", "timer", "entity", "executor")
    assert not {m for m in imported if m.rsplit(".", 1)[-1] in node_modules}
    for path in Path(fleetslam.middleware.__file__).parent.glob("*.py"):
        if path.name != "context.py":
            assert "context._" not in path.read_text(), path.name
