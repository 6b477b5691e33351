"""Whatever arrives, a node survives: bad samples are dropped, counted in the statistics and logged sparingly."""

import logging
import threading
import time
from collections.abc import Callable

import pytest
import zenoh

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.wire import decode_attachment, encode_attachment, topic_key
from fleetslam.msg.typesys import get_type, serialize

from ..support import wait_until

String = get_type("std_msgs/msg/String")
GID = bytes(range(16))


def string(text: str) -> bytes:
    return serialize(String(data=text), "std_msgs/msg/String")


def att(seq: int) -> bytes:
    return encode_attachment(seq, time.time_ns(), GID)


def test_bad_samples_are_dropped_counted_and_survived(
    make_context: Callable[..., Context], raw_session: zenoh.Session, caplog: pytest.LogCaptureFixture
) -> None:
    node = Node("robust", context=make_context("c3po"), statistics_period_s=0)
    good: list[str] = []

    def callback(m: object) -> None:
        if m.data == "boom":  # type: ignore[attr-defined]
            raise ValueError("user code failed")
        good.append(m.data)  # type: ignore[attr-defined]

    sub = node.create_subscription("std_msgs/msg/String", "chatter", callback, max_payload_bytes=64)
    key = topic_key(0, "/c3po/chatter", "std_msgs/msg/String")
    time.sleep(0.3)
    with caplog.at_level(logging.WARNING):
        raw_session.put(key, b"\x00\x01\x00\x00\xff\xff\xff\xff", attachment=att(1))  # malformed CDR
        raw_session.put(key, b"", attachment=att(2))  # empty payload
        raw_session.put(key, string("no attachment"))
        raw_session.put(key, string("x" * 100), attachment=att(3))  # over the size limit
        raw_session.put(key, string("boom"), attachment=att(4))  # the callback raises
        raw_session.put(key, string("fine"), attachment=att(5))
        raw_session.put(key, string("x"), attachment=b"short")  # malformed attachment
        raw_session.put(key, string("still fine"), attachment=att(6))
        assert wait_until(lambda: good == ["fine", "still fine"])
    assert sub.statistics.total_errors == 6
    assert sub.statistics.total_delivered == 3  # boom, fine, still fine reached the subscription
    for cause in ("malformed", "without attachment", "over the 64-byte limit", "user code failed", "33"):
        assert cause in caplog.text, cause
    (report,) = [r for r in sub.statistics.close_window(time.time_ns()) if r.publisher_gid == GID]
    assert (report.delivered, report.errors) == (3, 4)  # the attachment-less ones have no publisher GID


def test_unknown_type_and_bad_key_on_an_untyped_subscription(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    node = Node("echo", context=make_context(), statistics_period_s=0)
    got: list[object] = []
    sub = node.create_subscription(None, "/anything", got.append)
    time.sleep(0.3)
    raw_session.put("0/anything/nope_msgs::msg::dds_::Thing_/RIHS01_00", string("x"), attachment=att(1))
    raw_session.put("0/anything/not-a-type/RIHS01_00", string("x"), attachment=att(2))
    raw_session.put(topic_key(0, "/anything", "std_msgs/msg/String"), string("known"), attachment=att(3))
    assert wait_until(lambda: len(got) == 1)
    assert got == [String(data="known")]
    assert sub.statistics.total_errors == 2


def test_errors_are_logged_at_a_bounded_rate(
    make_context: Callable[..., Context], raw_session: zenoh.Session, caplog: pytest.LogCaptureFixture
) -> None:
    node = Node("flooded", context=make_context(), statistics_period_s=0)
    sub = node.create_subscription("std_msgs/msg/String", "/flood", lambda m: None, QoSProfile(history="keep_all"))
    key = topic_key(0, "/flood", "std_msgs/msg/String")
    time.sleep(0.3)
    with caplog.at_level(logging.WARNING, logger="fleetslam.middleware"):
        for seq in range(1, 201):
            raw_session.put(key, b"\x00\x01\x00\x00\x05", attachment=att(seq))
        assert wait_until(lambda: sub.statistics.total_errors == 200)
    lines = [r for r in caplog.records if "/flood" in r.getMessage()]
    assert 1 <= len(lines) <= 5  # the first 3 of each cause, then one line per 10 s (3 measured)


def test_timer_and_service_errors_do_not_stop_the_node(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    node = Node("server", context=make_context(), statistics_period_s=0)
    ticks: list[int] = []

    def tick() -> None:
        ticks.append(1)
        if len(ticks) % 2:
            raise RuntimeError("every other tick fails")

    node.create_timer(0.02, tick)
    response = get_type("std_srvs/srv/Trigger_Response")
    service = node.create_service("std_srvs/srv/Trigger", "/trigger", lambda r: response(success=True, message="ok"))
    time.sleep(0.2)
    # A request without attachment and one with garbage CDR: both are rejected with an error reply.
    for attachment, payload in ((None, b"\x00\x01\x00\x00"), (att(1), b"garbage")):
        start = time.monotonic()
        replies = list(raw_session.get(service.key, payload=payload, attachment=attachment, timeout=3.0))
        assert time.monotonic() - start < 1.0  # answered at once (< 1 ms measured), not after the 3 s timeout
        assert len(replies) == 1 and replies[0].err is not None
    caller = Node("caller", context=make_context(), statistics_period_s=0)
    client = caller.create_client("std_srvs/srv/Trigger", "/trigger")
    assert client.call(get_type("std_srvs/srv/Trigger_Request")(), timeout=3.0).message == "ok"
    assert wait_until(lambda: len(ticks) >= 10)
    assert node.callback_errors >= 5
    request = serialize(get_type("std_srvs/srv/Trigger_Request")(), "std_srvs/srv/Trigger_Request")
    (reply,) = list(raw_session.get(service.key, payload=request, attachment=att(9), timeout=3.0))
    assert reply.ok is not None and decode_attachment(reply.ok.attachment.to_bytes()).sequence_number == 9


def test_samples_dropped_by_keep_last_are_never_decoded(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    node = Node("slow", context=make_context(), statistics_period_s=0)
    release = threading.Event()
    node.call_soon(release.wait)
    got: list[str] = []
    sub = node.create_subscription("std_msgs/msg/String", "/img", lambda m: got.append(m.data), QoSProfile(depth=1))
    key = topic_key(0, "/img", "std_msgs/msg/String")
    time.sleep(0.3)
    raw_session.put(key, b"\x00\x01\x00\x00\x05", attachment=att(1))  # malformed, but overtaken before decoding
    raw_session.put(key, string("newest"), attachment=att(2))
    assert wait_until(lambda: sub.statistics.total_delivered == 2)
    release.set()
    assert wait_until(lambda: got == ["newest"])
    assert (sub.statistics.total_errors, sub.queue_overflows) == (0, 1)
