import os
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from fleetslam.config import ConfigModel
from fleetslam.errors import ConfigError, MessageError, MiddlewareError, ServiceError
from fleetslam.middleware import Context, MessageInfo, Node, QoSProfile
from fleetslam.middleware.wire import LivelinessToken, decode_attachment, encode_attachment, gid_from_key
from fleetslam.msg.typesys import get_type, header, serialize, stamp_from_ns

from ..support import wait_until

String = get_type("std_msgs/msg/String")
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
AddRequest = get_type("example_interfaces/srv/AddTwoInts_Request")
AddResponse = get_type("example_interfaces/srv/AddTwoInts_Response")


def test_pub_sub_across_sessions_with_info(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context("c3po"))
    listener = Node("listener", context=make_context("r2d2"))
    got: list[tuple[str, MessageInfo]] = []
    plain: list[str] = []
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m, i: got.append((m.data, i)))
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m: plain.append(m.data))
    pub = talker.create_publisher("std_msgs/msg/String", "chatter")
    assert pub.topic == "/c3po/chatter"
    assert wait_until(lambda: pub.matched_subscriptions == 2)
    for i in range(4):
        pub.publish(String(data=f"m{i}"))
    pub.publish(serialize(String(data="m4"), "std_msgs/msg/String"))  # pre-serialized bytes
    assert wait_until(lambda: len(got) == 5 and len(plain) == 5)
    assert [d for d, _ in got] == plain == [f"m{i}" for i in range(5)]
    infos = [i for _, i in got]
    assert [i.sequence_number for i in infos] == [1, 2, 3, 4, 5]
    assert all(i.publisher_gid == pub.gid and i.received_timestamp_ns >= i.source_timestamp_ns for i in infos)
    assert infos[0].size == len(serialize(String(data="m0"), "std_msgs/msg/String"))
    assert (infos[0].topic, infos[0].type_name) == ("/c3po/chatter", "std_msgs/msg/String")


def test_wire_format_seen_by_a_plain_zenoh_session(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    raw: list[zenoh.Sample] = []
    tokens: list[str] = []
    raw_session.declare_subscriber("0/**", raw.append)
    raw_session.liveliness().declare_subscriber("@ros2_lv/0/**", lambda s: tokens.append(str(s.key_expr)))
    ctx = make_context()
    node = Node("talker", context=ctx, statistics_period_s=0)
    pub = node.create_publisher("std_msgs/msg/String", "chatter", QoSProfile(depth=7))
    sub = node.create_subscription("std_msgs/msg/String", "/c3po/cmd", lambda m: None, QoSProfile(depth=10))
    node.create_service("example_interfaces/srv/AddTwoInts", "add", lambda r: AddResponse(sum=0))
    client = node.create_client("example_interfaces/srv/AddTwoInts", "/other/add")
    zid = ctx.zid
    expected = [
        f"@ros2_lv/0/{zid}/0/0/NN/%/%/talker",
        f"@ros2_lv/0/{zid}/0/1/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,",
        f"@ros2_lv/0/{zid}/0/2/MS/%/%/talker/%c3po%cmd/std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,",
        f"@ros2_lv/0/{zid}/0/3/SS/%/%/talker/%add/example_interfaces::srv::dds_::AddTwoInts_/{ADD_HASH}/::,10:,:,:,,",
        f"@ros2_lv/0/{zid}/0/4/SC/%/%/talker/%other%add/example_interfaces::srv::dds_::AddTwoInts_/{ADD_HASH}/"
        "::,10:,:,:,,",
    ]
    assert wait_until(lambda: all(t in tokens for t in expected)), tokens
    assert pub.gid == gid_from_key(expected[1]) and sub.gid == gid_from_key(expected[2])
    assert client.gid == gid_from_key(expected[4])
    assert wait_until(lambda: pub.matched_subscriptions == 0 and node.context.graph.publishers_info("/chatter"))
    time.sleep(0.2)  # the raw subscriber's interest reaches the publisher through the router
    pub.publish(String(data="hi"))
    pub.publish(String(data="again"))
    assert wait_until(lambda: len(raw) == 2)
    assert str(raw[0].key_expr) == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert raw[0].payload.to_bytes() == bytes.fromhex("0001000003000000686900")
    assert raw[0].attachment is not None and len(raw[0].attachment.to_bytes()) == 33
    first = decode_attachment(raw[0].attachment.to_bytes())
    assert first.sequence_number == 1 and first.gid == pub.gid
    assert decode_attachment(raw[1].attachment.to_bytes()).sequence_number == 2
    assert abs(first.source_timestamp_ns - time.time_ns()) < 5e9  # wall-clock stamp (22 ms old), not 0 or monotonic


def test_service_round_trip_and_timeout(make_context: Callable[..., Context]) -> None:
    server = Node("server", context=make_context("c3po"))
    caller = Node("caller", context=make_context("r2d2"))
    server.create_service("example_interfaces/srv/AddTwoInts", "add", lambda r: AddResponse(sum=r.a + r.b))
    client = caller.create_client("example_interfaces/srv/AddTwoInts", "/c3po/add")
    assert client.wait_for_service(5.0) and client.service_is_ready()
    assert client.call(AddRequest(a=2, b=40), timeout=5.0).sum == 42
    assert client.call(AddRequest(a=-1, b=1), timeout=5.0).sum == 0
    missing = caller.create_client("example_interfaces/srv/AddTwoInts", "/nobody/add")
    assert not missing.wait_for_service(0.1)
    start = time.monotonic()
    with pytest.raises(ServiceError, match="/nobody/add"):
        missing.call(AddRequest(a=1, b=1), timeout=0.5)
    assert time.monotonic() - start < 3.0  # the 0.5 s call timeout (0.5 s measured), not the 600 s query default
    with pytest.raises(MessageError, match="not a service type"):
        caller.create_client("std_msgs/msg/String", "x")


def test_service_wire_format_against_plain_zenoh(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    node = Node("server", context=make_context(), statistics_period_s=0)
    service = node.create_service("example_interfaces/srv/AddTwoInts", "add", lambda r: AddResponse(sum=r.a * r.b))
    key = f"0/add/example_interfaces::srv::dds_::AddTwoInts_/{ADD_HASH}"
    assert service.key == key
    time.sleep(0.2)
    client_gid = bytes(range(100, 116))
    replies = list(
        raw_session.get(
            key,
            payload=serialize(AddRequest(a=6, b=7), "example_interfaces/srv/AddTwoInts_Request"),
            attachment=encode_attachment(41, time.time_ns(), client_gid),
            target=zenoh.QueryTarget.ALL_COMPLETE,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=5.0,
        )
    )
    (reply,) = replies
    assert reply.ok is not None and str(reply.ok.key_expr) == key
    assert reply.ok.payload.to_bytes() == serialize(AddResponse(sum=42), "example_interfaces/srv/AddTwoInts_Response")
    echoed = decode_attachment(reply.ok.attachment.to_bytes())
    assert (echoed.sequence_number, echoed.gid) == (41, client_gid)
    # And our client, seen by a plain queryable: sequence numbers from 1, its own GID, complete queryables only.
    seen = []

    def answer(query: zenoh.Query) -> None:
        att = decode_attachment(query.attachment.to_bytes())
        seen.append(att)
        stale = encode_attachment(att.sequence_number + 100, time.time_ns(), att.gid)
        query.reply(
            query.key_expr,
            serialize(AddResponse(sum=-1), "example_interfaces/srv/AddTwoInts_Response"),
            attachment=stale,
        )
        good = encode_attachment(att.sequence_number, time.time_ns(), att.gid)
        query.reply(
            query.key_expr, serialize(AddResponse(sum=7), "example_interfaces/srv/AddTwoInts_Response"), attachment=good
        )

    raw_session.declare_queryable("0/mul/**", answer, complete=True)
    client = node.create_client("example_interfaces/srv/AddTwoInts", "mul")
    time.sleep(0.2)
    assert client.call(AddRequest(a=1, b=2), timeout=5.0).sum == 7  # the reply with the wrong seq is ignored
    assert client.call(AddRequest(a=1, b=2), timeout=5.0).sum == 7
    assert [a.sequence_number for a in seen] == [1, 2] and all(a.gid == client.gid for a in seen)


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
    latched.publish(String(data="live"))
    assert wait_until(lambda: got == ["newer", "newest", "live"], timeout_s=5.0), got


def test_qos_maps_to_zenoh_reliability_and_congestion(make_context: Callable[..., Context]) -> None:
    node = Node("qos", context=make_context(), statistics_period_s=0)

    def zenoh_publisher(qos: QoSProfile) -> zenoh.Publisher:
        return node.create_publisher("std_msgs/msg/String", f"t{id(qos)}", qos)._publisher  # type: ignore[no-any-return]

    best_effort = zenoh_publisher(QoSProfile(reliability="best_effort", depth=5))
    assert best_effort.reliability == zenoh.Reliability.BEST_EFFORT
    assert best_effort.congestion_control == zenoh.CongestionControl.DROP
    keep_all = zenoh_publisher(QoSProfile(history="keep_all"))
    assert keep_all.reliability == zenoh.Reliability.RELIABLE
    assert keep_all.congestion_control == zenoh.CongestionControl.BLOCK
    keep_last = zenoh_publisher(QoSProfile(depth=10))
    assert keep_last.congestion_control == zenoh.CongestionControl.DROP


def test_timer_rate_and_one_callback_at_a_time(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("ticker", context=make_context(), statistics_period_s=0)
    ticks: list[float] = []
    received: list[str] = []
    active = threading.Lock()
    overlaps: list[str] = []
    threads: set[str] = set()

    def exclusive(what: str) -> None:
        threads.add(threading.current_thread().name)
        if not active.acquire(blocking=False):
            overlaps.append(what)
            return
        try:
            time.sleep(0.003)
        finally:
            active.release()

    def tick() -> None:
        ticks.append(time.monotonic())
        exclusive("timer")

    def on_msg(msg: object) -> None:
        received.append(msg.data)  # type: ignore[attr-defined]
        exclusive("subscription")

    node.create_subscription("std_msgs/msg/String", "/load", on_msg, QoSProfile(history="keep_all"))
    pub = talker.create_publisher("std_msgs/msg/String", "/load")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    node.create_timer(0.02, tick)
    node.create_timer(0.05, tick)
    start = time.monotonic()
    for i in range(100):
        pub.publish(String(data=str(i)))
        time.sleep(0.005)
    time.sleep(max(0.0, 1.0 - (time.monotonic() - start)))
    node.destroy()
    assert not overlaps
    assert threads == {"executor:/ticker"}
    assert 60 <= len(ticks) <= 75, len(ticks)  # 50 + 20 per second (69 measured); 10 skipped under load
    assert wait_until(lambda: len(received) == 100) and received == [str(i) for i in range(100)]
    with pytest.raises(MiddlewareError, match="period must be positive"):
        Node("bad", context=talker.context).create_timer(0, lambda: None)


def test_untyped_raw_subscription_learns_type_from_key(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context("c3po"))
    listener = Node("listener", context=make_context())
    got: list[tuple[bytes, str]] = []
    typed: list[object] = []
    listener.create_subscription(
        None, "/c3po/anything", lambda data, info: got.append((data, info.type_name)), raw=True
    )
    listener.create_subscription(None, "/c3po/anything", typed.append)
    time.sleep(0.3)
    talker.create_publisher("std_msgs/msg/String", "anything").publish(String(data="hey"))
    talker.create_publisher("std_msgs/msg/Bool", "anything").publish(get_type("std_msgs/msg/Bool")(data=True))
    assert wait_until(lambda: len(got) == 2 and len(typed) == 2)
    assert got[0] == (serialize(String(data="hey"), "std_msgs/msg/String"), "std_msgs/msg/String")
    assert got[1][1] == "std_msgs/msg/Bool"
    assert typed[0] == String(data="hey") and typed[1].data is True  # type: ignore[attr-defined]


def test_sim_time_follows_clock(make_context: Callable[..., Context]) -> None:
    sim = Node("sim", context=make_context(), statistics_period_s=0)
    node = Node("slam", context=make_context(), statistics_period_s=0, use_sim_time=True)
    wall = Node("wall", context=make_context(), statistics_period_s=0)
    assert node.now_ns() == 0 and abs(wall.now_ns() - time.time_ns()) < 1e9  # wall clock (µs apart), not sim time
    clock = sim.create_publisher("rosgraph_msgs/msg/Clock", "/clock")
    assert wait_until(lambda: clock.matched_subscriptions == 1)
    clock.publish(get_type("rosgraph_msgs/msg/Clock")(clock=stamp_from_ns(12_500_000_000)))
    assert wait_until(lambda: node.now_ns() == 12_500_000_000)


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
    assert node.resolve("odom") == "/x/odom" and node.resolve("~/debug") == "/c3po/base/debug"
    defaults = Node("base2", context=make_context(), parameters=BaseParams, parameter_overrides=["rate_hz=5"])
    assert defaults.parameters == BaseParams(rate_hz=5)
    path.write_text("base:\n  rate_hz: fast\n")
    with pytest.raises(ConfigError, match=r"params.yaml.*key 'rate_hz' = 'fast'"):
        Node("base", context=make_context(), parameters=BaseParams, parameter_file=path)
    path.write_text("base: [unclosed\n")
    with pytest.raises(ConfigError, match=r"params.yaml"):
        Node("base", context=make_context(), parameters=BaseParams, parameter_file=path)
    with pytest.raises(ConfigError, match=r"key 'typo'"):
        Node("base", context=make_context(), parameters=BaseParams, parameter_overrides=["typo=1"])


def test_node_context_manager_and_destroyed_entities(make_context: Callable[..., Context]) -> None:
    ctx = make_context()
    with Node("short", context=ctx, statistics_period_s=0) as node:
        pub = node.create_publisher("std_msgs/msg/String", "x")
        assert ctx.closables == [node]
    assert ctx.closables == []
    with pytest.raises(MiddlewareError, match="destroyed"):
        pub.publish(String(data="late"))
    with pytest.raises(MiddlewareError, match="destroyed"):
        node.create_publisher("std_msgs/msg/String", "y")
    assert LivelinessToken.parse(pub.token_info.key()).kind.value == "MP"


def test_subprocess_publisher_configured_by_environment(
    router_endpoint: str, make_context: Callable[..., Context]
) -> None:
    listener = Node("listener", context=make_context())
    got: list[str] = []
    listener.create_subscription("std_msgs/msg/String", "/r2d2/chatter", lambda m: got.append(m.data))
    script = textwrap.dedent(
        """
        from fleetslam.middleware import Context, Node
        from fleetslam.msg.typesys import get_type
        with Context() as ctx, Node("talker", context=ctx) as node:
            pub = node.create_publisher("std_msgs/msg/String", "chatter")
            ctx.graph.wait_for(lambda g: g.subscriptions_info("/r2d2/chatter"), 5.0)
            ctx.spin(0.2)
            for i in range(3):
                pub.publish(get_type("std_msgs/msg/String")(data=f"from {ctx.namespace} {i}"))
            ctx.spin(0.3)
        """
    )
    env = {"FLEETSLAM_ROUTER": router_endpoint, "FLEETSLAM_AGENT": "r2d2", "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0"}
    subprocess.run([sys.executable, "-c", script], env={**os.environ, **env}, check=True, timeout=60)
    assert wait_until(lambda: len(got) == 3)
    assert got == [f"from /r2d2 {i}" for i in range(3)]


def test_keep_last_queue_keeps_the_newest_when_the_executor_falls_behind(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("slow", context=make_context(), statistics_period_s=0)
    release = threading.Event()
    got: list[str] = []
    node.call_soon(release.wait)  # block the executor while samples arrive
    sub = node.create_subscription("std_msgs/msg/String", "/cmd", lambda m: got.append(m.data), QoSProfile(depth=2))
    pub = talker.create_publisher("std_msgs/msg/String", "/cmd")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    time.sleep(0.1)
    for i in range(50):
        pub.publish(String(data=str(i)))
    assert wait_until(lambda: sub.statistics.total_delivered == 50)
    release.set()
    assert wait_until(lambda: got == ["48", "49"])
    assert sub.queue_overflows == 48
    time.sleep(0.1)
    assert got == ["48", "49"]


def test_callbacks_with_defaulted_parameters_get_only_the_message(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context("c3po"))
    listener = Node("listener", context=make_context())
    got: list[tuple[str, str]] = []
    for key in ("first",):
        listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m, k=key: got.append((k, m.data)))
    time.sleep(0.3)
    talker.create_publisher("std_msgs/msg/String", "chatter").publish(String(data="hi"))
    assert wait_until(lambda: got == [("first", "hi")])


def test_inline_subscription_runs_on_zenoh_thread_and_keeps_views_valid(
    make_context: Callable[..., Context],
) -> None:
    import numpy as np

    talker = Node("talker", context=make_context("c3po"), statistics_period_s=0)
    listener = Node("listener", context=make_context("r2d2"), statistics_period_s=0)
    kept: list[tuple[Any, MessageInfo, str]] = []
    executor_threads: list[str] = []

    def on_image(msg: Any, info: MessageInfo) -> None:
        kept.append((msg, info, threading.current_thread().name))  # kept past the callback, arrays and all

    sub = listener.create_subscription("sensor_msgs/msg/Image", "/c3po/image", on_image, inline=True)
    listener.call_soon(lambda: executor_threads.append(threading.current_thread().name))
    pub = talker.create_publisher("sensor_msgs/msg/Image", "image")
    assert wait_until(lambda: pub.matched_subscriptions == 1 and bool(executor_threads))
    release = threading.Event()
    listener.call_soon(release.wait)  # the executor is blocked: inline callbacks do not wait for it
    image_type = get_type("sensor_msgs/msg/Image")
    frames = [np.full(64 * 48 * 3, i, dtype=np.uint8) for i in range(5)]
    for frame in frames:
        pub.publish(
            image_type(
                header=header("cam", 1), height=48, width=64, encoding="rgb8", is_bigendian=0, step=192, data=frame
            )
        )
    assert wait_until(lambda: len(kept) == 5)
    assert all(name != executor_threads[0] for _, _, name in kept)  # not the node's executor: Zenoh's thread
    for (msg, _, _), frame in zip(kept, frames, strict=True):
        np.testing.assert_array_equal(msg.data, frame)  # every view still holds its own sample's pixels
        assert not msg.data.flags.writeable
    assert [i.sequence_number for _, i, _ in kept] == [1, 2, 3, 4, 5]
    assert sub.statistics.total_delivered == 5 and sub.queue_overflows == 0
    release.set()


def test_inline_callback_errors_are_counted_not_raised(make_context: Callable[..., Context]) -> None:
    node = Node("solo", context=make_context(), statistics_period_s=0)
    seen: list[str] = []

    def fails(msg: Any) -> None:
        seen.append(msg.data)
        raise RuntimeError("boom")

    sub = node.create_subscription("std_msgs/msg/String", "/chatter", fails, inline=True)
    pub = node.create_publisher("std_msgs/msg/String", "/chatter")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    pub.publish(String(data="a"))
    pub.publish(String(data="b"))
    assert wait_until(lambda: seen == ["a", "b"] and sub.statistics.total_errors == 2)


def test_large_payloads_leave_zenoh_on_the_executor_and_stay_valid(make_context: Callable[..., Context]) -> None:
    import numpy as np

    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("slow", context=make_context(), statistics_period_s=0)
    kept: list[Any] = []
    release = threading.Event()
    node.call_soon(release.wait)  # samples wait in the KEEP_LAST queue, still inside Zenoh's buffers
    sub = node.create_subscription("sensor_msgs/msg/Image", "/image", kept.append, QoSProfile(depth=3))
    pub = talker.create_publisher("sensor_msgs/msg/Image", "/image")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    time.sleep(0.1)
    image_type = get_type("sensor_msgs/msg/Image")
    frames = [np.full(320 * 240 * 3, i, dtype=np.uint8) for i in range(6)]  # 230 KB each: over the 64 KiB cut
    for frame in frames:
        pub.publish(
            image_type(header=header("cam", 1), height=240, width=320, encoding="rgb8", is_bigendian=0, step=960,
                       data=frame)
        )  # fmt: skip
    assert wait_until(lambda: sub.statistics.total_delivered == 6)
    release.set()
    assert wait_until(lambda: len(kept) == 3)
    assert sub.queue_overflows == 3
    for msg, frame in zip(kept, frames[3:], strict=True):
        assert isinstance(msg.data, np.ndarray) and not msg.data.flags.writeable
        np.testing.assert_array_equal(msg.data, frame)
