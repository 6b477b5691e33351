import json
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from fleetslam.config import ConfigModel
from fleetslam.errors import ConfigError, RouterUnreachableError, ServiceError
from fleetslam.middleware import Context, MessageInfo, Node, QoSProfile
from fleetslam.middleware.typesys import get_type, serialize
from fleetslam.middleware.wire import decode_attachment, encode_attachment, topic_key

from ..support import free_port, wait_until

String = get_type("std_msgs/msg/String")
STRING_KEY = "0/c3po/chatter/std_msgs::msg::dds_::String_/" + (
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
)


def test_pub_sub_across_sessions_with_info(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context("c3po"))
    listener = Node("listener", context=make_context("r2d2"))
    got: list[tuple[str, MessageInfo]] = []
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m, i: got.append((m.data, i)))
    pub = talker.create_publisher("std_msgs/msg/String", "chatter")
    assert pub.topic == "/c3po/chatter"
    assert wait_until(lambda: bool(listener.context.graph.publishers_info("/c3po/chatter")))
    for i in range(5):
        pub.publish(String(data=f"m{i}"))
    assert wait_until(lambda: len(got) == 5)
    assert [d for d, _ in got] == [f"m{i}" for i in range(5)]
    assert [i.sequence_number for _, i in got] == [1, 2, 3, 4, 5]
    assert all(i.publisher_gid == pub.gid and i.received_timestamp_ns >= i.source_timestamp_ns for _, i in got)


def test_wire_format_seen_by_a_plain_zenoh_session(make_context: Callable[..., Context], router_endpoint: str) -> None:
    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([router_endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    raw: list[zenoh.Sample] = []
    tokens: list[str] = []
    with zenoh.open(config) as plain:
        plain.declare_subscriber("0/**", raw.append)
        plain.liveliness().declare_subscriber("@ros2_lv/0/**", lambda s: tokens.append(str(s.key_expr)))
        ctx = make_context("c3po")
        node = Node("talker", context=ctx, statistics_period_s=0)
        pub = node.create_publisher("std_msgs/msg/String", "chatter", QoSProfile(depth=7))
        time.sleep(0.3)
        pub.publish(String(data="hi"))
        pub.publish(String(data="again"))
        assert wait_until(lambda: len(raw) == 2)
        assert str(raw[0].key_expr) == STRING_KEY
        assert raw[0].payload.to_bytes() == bytes.fromhex("0001000003000000686900")
        first = decode_attachment(raw[0].attachment.to_bytes())
        assert first.sequence_number == 1 and first.gid == pub.gid
        assert decode_attachment(raw[1].attachment.to_bytes()).sequence_number == 2
        assert abs(first.source_timestamp_ns - time.time_ns()) < 5e9
        node_token = f"@ros2_lv/0/{ctx.zid}/{node.node_id}/{node.node_id}/NN/%/%c3po/talker"
        pub_token = pub.token_info.key()
        assert wait_until(lambda: node_token in tokens and pub_token in tokens)
        assert pub_token.endswith(
            "/%c3po%chatter/std_msgs::msg::dds_::String_/" + STRING_KEY.split("/")[-1] + "/::,7:,:,:,,"
        )
        assert pub_token.split("/")[4] == str(pub.entity_id) and pub.entity_id > node.node_id


def test_service_round_trip_and_timeout(make_context: Callable[..., Context]) -> None:
    server = Node("server", context=make_context("c3po"))
    caller = Node("caller", context=make_context("r2d2"))
    response_type = get_type("example_interfaces/srv/AddTwoInts_Response")
    request_type = get_type("example_interfaces/srv/AddTwoInts_Request")
    server.create_service("example_interfaces/srv/AddTwoInts", "add", lambda r: response_type(sum=r.a + r.b))
    client = caller.create_client("example_interfaces/srv/AddTwoInts", "/c3po/add")
    assert client.wait_for_service(5.0)
    assert client.call(request_type(a=2, b=40), timeout=5.0).sum == 42
    assert client.call(request_type(a=-1, b=1), timeout=5.0).sum == 0
    missing = caller.create_client("example_interfaces/srv/AddTwoInts", "/nobody/add")
    with pytest.raises(ServiceError, match="/nobody/add"):
        missing.call(request_type(a=1, b=1), timeout=0.5)


def test_service_handler_error_is_reported(make_context: Callable[..., Context]) -> None:
    server = Node("server", context=make_context("c3po"))
    caller = Node("caller", context=make_context())

    def fail(_: object) -> object:
        raise RuntimeError("motor driver offline")

    server.create_service("std_srvs/srv/Trigger", "reset", fail)
    client = caller.create_client("std_srvs/srv/Trigger", "/c3po/reset")
    assert client.wait_for_service(5.0)
    with pytest.raises(ServiceError, match="motor driver offline"):
        client.call(get_type("std_srvs/srv/Trigger_Request")(), timeout=3.0)
    # The server node is still alive and answers the next request with a working handler.
    server.create_service(
        "std_srvs/srv/Trigger", "ok", lambda _: get_type("std_srvs/srv/Trigger_Response")(success=True, message="")
    )
    ok = caller.create_client("std_srvs/srv/Trigger", "/c3po/ok")
    assert ok.wait_for_service(5.0)
    assert ok.call(get_type("std_srvs/srv/Trigger_Request")(), timeout=3.0).success


def test_transient_local_late_joiner(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context("c3po"))
    latched = talker.create_publisher(
        "std_msgs/msg/String", "map_meta", QoSProfile(durability="transient_local", depth=2)
    )
    for text in ("old", "newer", "newest"):
        latched.publish(String(data=text))
    time.sleep(0.2)
    late = Node("late", context=make_context())
    got: list[str] = []
    late.create_subscription(
        "std_msgs/msg/String", "/c3po/map_meta", lambda m: got.append(m.data),
        QoSProfile(durability="transient_local", depth=2),
    )  # fmt: skip
    assert wait_until(lambda: got == ["newer", "newest"], timeout_s=5.0), got


def test_timer_rate_and_serial_executor(make_context: Callable[..., Context]) -> None:
    node = Node("ticker", context=make_context(), statistics_period_s=0)
    ticks: list[float] = []
    active = threading.Lock()
    overlaps = []

    def tick() -> None:
        if not active.acquire(blocking=False):
            overlaps.append(1)
            return
        try:
            ticks.append(time.monotonic())
            time.sleep(0.005)
        finally:
            active.release()

    node.create_timer(0.02, tick)
    node.create_timer(0.03, tick)
    time.sleep(1.0)
    node.destroy()
    assert not overlaps
    assert 70 <= len(ticks) <= 90  # 50 + 33 per second


def test_graph_tracks_entities_and_their_removal(make_context: Callable[..., Context]) -> None:
    observer = make_context()
    ctx = make_context("c3po")
    node = Node("slam", context=ctx)
    node.create_publisher("fleetslam_msgs/msg/KeyframeGraph", "graph", QoSProfile(depth=3))
    node.create_subscription("nav_msgs/msg/Odometry", "odom", lambda m: None)
    node.create_service("std_srvs/srv/Trigger", "slam/reset", lambda r: r)
    graph = observer.graph
    assert graph.wait_for(
        lambda g: "/c3po/slam" in g.node_fq_names() and "/c3po/slam/reset" in g.service_names_and_types(), 5
    )
    topics = graph.topic_names_and_types()
    assert topics["/c3po/graph"] == ["fleetslam_msgs/msg/KeyframeGraph"]
    assert topics["/c3po/odom"] == ["nav_msgs/msg/Odometry"]
    (info,) = graph.publishers_info("/c3po/graph")
    assert info.node_fq_name == "/c3po/slam" and info.qos.depth == 3
    assert graph.entity_by_gid(info.gid) is not None
    ctx.close()
    assert graph.wait_for(lambda g: "/c3po/slam" not in g.node_fq_names() and not g.publishers_info("/c3po/graph"), 5)


def test_statistics_count_drops_and_ages(make_context: Callable[..., Context], router_endpoint: str) -> None:
    listener = Node("listener", context=make_context("r2d2"), statistics_period_s=0.5)
    reports = []
    listener.create_subscription("fleetslam_msgs/msg/TopicStatistics", "/statistics", reports.append)
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m: None)
    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([router_endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    gid = bytes(range(16))
    with zenoh.open(config) as plain:
        time.sleep(0.3)
        key = topic_key(0, "/c3po/chatter", "std_msgs/msg/String")
        payload = serialize(String(data="x"), "std_msgs/msg/String")
        for seq in (1, 2, 5, 6, 10):  # gaps: 3,4 and 7,8,9 -> 5 dropped
            plain.put(key, payload, attachment=encode_attachment(seq, time.time_ns() - 2_000_000, gid))
            time.sleep(0.01)
        assert wait_until(lambda: any(r.topic == "/c3po/chatter" for r in reports), timeout_s=5)
    (report,) = [r for r in reports if r.topic == "/c3po/chatter"]
    assert report.delivered_msgs == 5 and report.dropped_msgs == 5 and report.error_msgs == 0
    assert report.traffic == 5 * len(payload)
    assert report.node_sub == "/r2d2/listener" and report.agent_sub == "r2d2" and report.agent_pub == "c3po"
    assert bytes(report.publisher_gid) == gid
    age_ms = report.stamp_age_mean.sec * 1e3 + report.stamp_age_mean.nanosec / 1e6
    assert 2.0 <= age_ms < 1000.0
    assert report.period_mean.nanosec > 0


def test_bad_input_is_dropped_counted_and_survived(make_context: Callable[..., Context], router_endpoint: str) -> None:
    node = Node("robust", context=make_context("c3po"), statistics_period_s=0)
    good: list[str] = []

    def callback(m: object) -> None:
        if m.data == "boom":  # type: ignore[attr-defined]
            raise ValueError("user code failed")
        good.append(m.data)  # type: ignore[attr-defined]

    sub = node.create_subscription("std_msgs/msg/String", "chatter", callback, max_payload_bytes=64)
    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([router_endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    gid = bytes(16)
    key = topic_key(0, "/c3po/chatter", "std_msgs/msg/String")
    with zenoh.open(config) as plain:
        time.sleep(0.3)
        att = lambda seq: encode_attachment(seq, time.time_ns(), gid)  # noqa: E731
        plain.put(key, b"\x00\x01\x00\x00\xff\xff\xff\xff", attachment=att(1))  # malformed CDR
        plain.put(key, serialize(String(data="no attachment"), "std_msgs/msg/String"))  # no attachment
        plain.put(key, serialize(String(data="x" * 100), "std_msgs/msg/String"), attachment=att(2))  # too big
        plain.put(key, serialize(String(data="boom"), "std_msgs/msg/String"), attachment=att(3))  # callback raises
        plain.put(key, serialize(String(data="fine"), "std_msgs/msg/String"), attachment=att(4))
        plain.put(key, serialize(String(data="x"), "std_msgs/msg/String"), attachment=b"short")  # bad attachment
        plain.put(key, serialize(String(data="still fine"), "std_msgs/msg/String"), attachment=att(5))
        assert wait_until(lambda: good == ["fine", "still fine"])
    assert sub.statistics.total_errors == 5
    assert sub.statistics.total_delivered == 3


def test_untyped_raw_subscription_learns_type_from_key(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context("c3po"))
    listener = Node("listener", context=make_context())
    got: list[tuple[bytes, str]] = []
    listener.create_subscription(
        None, "/c3po/anything", lambda data, info: got.append((data, info.type_name)), raw=True
    )
    time.sleep(0.3)
    talker.create_publisher("std_msgs/msg/String", "anything").publish(String(data="hey"))
    assert wait_until(lambda: len(got) == 1)
    assert got[0] == (serialize(String(data="hey"), "std_msgs/msg/String"), "std_msgs/msg/String")


class BaseParams(ConfigModel):
    rate_hz: float = 10.0
    """Rate."""
    frame_id: str = "odom"
    """Frame."""


def test_parameters_from_file_overrides_and_ros_args(make_context: Callable[..., Context], tmp_path: Path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text("base:\n  rate_hz: 25\n")
    node = Node(
        "base", context=make_context("c3po"), parameters=BaseParams, parameter_file=path,
        ros_args=["--ros-args", "-p", "frame_id:=wheel_odom", "-r", "odom:=/x/odom"],
    )  # fmt: skip
    assert node.parameters.rate_hz == 25.0 and node.parameters.frame_id == "wheel_odom"
    assert node.resolve("odom") == "/x/odom"
    path.write_text("base:\n  rate_hz: fast\n")
    with pytest.raises(ConfigError, match=r"params.yaml.*key 'rate_hz' = 'fast'"):
        Node("base", context=make_context(), parameters=BaseParams, parameter_file=path)


def test_no_router_fails_fast_with_instructions() -> None:
    start = time.monotonic()
    with pytest.raises(RouterUnreachableError, match="start one with `fleetslam router`"):
        Context(router=f"tcp/127.0.0.1:{free_port()}", listen="tcp/127.0.0.1:0", environ={}, router_timeout_s=1.0)
    assert time.monotonic() - start < 10


def test_subprocess_publisher_configured_by_environment(
    router_endpoint: str, make_context: Callable[..., Context]
) -> None:
    listener = Node("listener", context=make_context())
    got: list[str] = []
    listener.create_subscription("std_msgs/msg/String", "/r2d2/chatter", lambda m: got.append(m.data))
    script = textwrap.dedent(
        """
        import time
        from fleetslam.middleware import Context, Node
        from fleetslam.middleware.typesys import get_type
        with Context() as ctx, Node("talker", context=ctx) as node:
            pub = node.create_publisher("std_msgs/msg/String", "chatter")
            time.sleep(0.5)
            for i in range(3):
                pub.publish(get_type("std_msgs/msg/String")(data=f"from {ctx.namespace} {i}"))
                time.sleep(0.05)
            time.sleep(0.3)
        """
    )
    env = {"FLEETSLAM_ROUTER": router_endpoint, "FLEETSLAM_AGENT": "r2d2", "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0"}
    import os

    subprocess.run([sys.executable, "-c", script], env={**os.environ, **env}, check=True, timeout=60)
    assert wait_until(lambda: len(got) == 3)
    assert got[0] == "from /r2d2 0"
