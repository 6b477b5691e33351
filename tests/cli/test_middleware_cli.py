"""The ros2cli-like commands against a real router and real nodes."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from fleetslam.cli.main import main
from fleetslam.errors import MiddlewareError
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.typesys import get_type

from ..support import free_port, wait_until

String = get_type("std_msgs/msg/String")


@pytest.fixture
def talker(fleet_env: str, make_context: Callable[..., Context]) -> Iterator[Node]:
    node = Node("talker", context=make_context("c3po"))
    publisher = node.create_publisher("std_msgs/msg/String", "chatter")
    response_type = get_type("std_srvs/srv/SetBool_Response")
    node.create_service("std_srvs/srv/SetBool", "e_stop", lambda r: response_type(success=r.data, message="latched"))
    stop = threading.Event()

    def loop() -> None:
        i = 0
        while not stop.is_set():
            try:
                publisher.publish(String(data=f"m{i}"))
            except MiddlewareError:  # the test destroyed the node
                return
            i += 1
            time.sleep(0.02)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    yield node
    stop.set()
    thread.join()


def test_node_and_topic_listing(talker: Node, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["node", "list"]) == 0
    assert "/c3po/talker" in capsys.readouterr().out.split()
    assert main(["node", "info", "/c3po/talker"]) == 0
    out = capsys.readouterr().out
    assert "/c3po/chatter: std_msgs/msg/String" in out and "/c3po/e_stop: std_srvs/srv/SetBool" in out
    assert main(["topic", "list", "-t"]) == 0
    assert "/c3po/chatter [std_msgs/msg/String]" in capsys.readouterr().out
    assert main(["topic", "info", "/c3po/chatter", "-v"]) == 0
    out = capsys.readouterr().out
    assert "Publisher count: 1" in out and "Node: /c3po/talker" in out
    assert main(["service", "list", "-t"]) == 0
    assert "/c3po/e_stop [std_srvs/srv/SetBool]" in capsys.readouterr().out


def test_echo_finds_type_and_prints_yaml(talker: Node, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["topic", "echo", "/c3po/chatter", "--count", "3"]) == 0
    docs = capsys.readouterr().out.split("---\n")
    assert len([d for d in docs if d.startswith("data: m")]) == 3


def test_echo_times_out_with_error(fleet_env: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["topic", "echo", "/nobody", "std_msgs/msg/String", "--count", "1", "--timeout", "0.5"]) == 1
    assert "received 0 of 1" in capsys.readouterr().out


def test_pub_reaches_a_subscriber(
    fleet_env: str,
    make_context: Callable[..., Context],
    capsys: pytest.CaptureFixture[str],
) -> None:
    listener = Node("listener", context=make_context("c3po"))
    got: list[float] = []
    listener.create_subscription("geometry_msgs/msg/Twist", "cmd_vel", lambda m: got.append(m.linear.x))
    args = ["topic", "pub", "/c3po/cmd_vel", "geometry_msgs/msg/Twist", "{linear: {x: 0.25}}", "--count", "3"]
    assert main([*args, "--rate", "20"]) == 0
    assert wait_until(lambda: got == [0.25, 0.25, 0.25])
    assert main(["topic", "pub", "/x", "geometry_msgs/msg/Twist", "{linar: {}}", "--once"]) != 0
    assert "unknown field(s) ['linar']" in capsys.readouterr().err


def test_service_call(talker: Node, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["service", "call", "/c3po/e_stop", "std_srvs/srv/SetBool", "{data: true}"]) == 0
    out = capsys.readouterr().out
    assert "success: true" in out and "message: latched" in out


def test_hz_and_bw(talker: Node, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["topic", "hz", "/c3po/chatter", "--duration", "1.2"]) == 0
    out = capsys.readouterr().out
    rate = float(out.split("average rate: ")[1].split()[0])
    # published every 20 ms + the publish: ≤ 50 Hz (49.6 measured), 30 Hz if each sleep overran by 13 ms under load
    assert 30 < rate < 60
    assert main(["topic", "bw", "/c3po/chatter", "--duration", "1.2"]) == 0
    assert "B/s from" in capsys.readouterr().out


def test_record_and_play_round_trip(
    talker: Node,
    tmp_path: Path,
    make_context: Callable[..., Context],
) -> None:
    bag = tmp_path / "bag"
    assert main(["record", "-o", str(bag), "/c3po/chatter", "--duration", "1.5"]) == 0
    with AnyReader([bag]) as reader:
        (connection,) = reader.connections
        assert connection.topic == "/c3po/chatter" and connection.msgtype == "std_msgs/msg/String"
        recorded = [(t, reader.deserialize(raw, connection.msgtype).data) for _, t, raw in reader.messages()]
    assert len(recorded) > 20  # ≤ 50 Hz for 1.5 s: 74 measured
    stamps = [t for t, _ in recorded]
    listener = Node("replay_listener", context=make_context())
    got: list[tuple[float, str]] = []
    listener.create_subscription("std_msgs/msg/String", "/replay/chatter", lambda m: None)
    listener.create_subscription(
        "std_msgs/msg/String", "/c3po/chatter", lambda m: got.append((time.monotonic(), m.data)), QoSProfile(depth=1000)
    )
    talker.destroy()  # only the replay publishes now
    time.sleep(0.3)
    got.clear()
    assert main(["play", str(bag), "--rate", "2"]) == 0
    assert wait_until(lambda: len(got) == len(recorded))
    assert [d for _, d in got] == [d for _, d in recorded]
    recorded_span = (stamps[-1] - stamps[0]) / 1e9
    replay_span = got[-1][0] - got[0][0]
    # paced by sleeps: 1 % off measured; 25 % of the ~0.74 s span leaves 0.18 s for scheduling delays
    assert replay_span == pytest.approx(recorded_span / 2, rel=0.25)


def test_record_gets_what_latched_publishers_sent_before_it_started(
    fleet_env: str, make_context: Callable[..., Context], tmp_path: Path
) -> None:
    """tf_static-like topics are published once, transient local: the recorder subscribes the same way and gets
    the message from before it started; a volatile topic's old message is not replayed."""
    node = Node("mounting", context=make_context("c3po"))
    latched = node.create_publisher(
        "std_msgs/msg/String", "tf_static_like", QoSProfile(depth=1, durability="transient_local")
    )
    plain = node.create_publisher("std_msgs/msg/String", "plain")
    latched.publish(String(data="mounted"))
    plain.publish(String(data="gone"))
    time.sleep(0.3)
    bag = tmp_path / "bag"
    assert main(["record", "-o", str(bag), "/c3po/tf_static_like", "/c3po/plain", "--duration", "1.5"]) == 0
    with AnyReader([bag]) as reader:
        recorded = {c.topic: [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages([c])]
                    for c in reader.connections}  # fmt: skip
    assert recorded["/c3po/tf_static_like"] == ["mounted"]
    assert recorded.get("/c3po/plain", []) == []


def test_recording_qos_follows_the_publishers() -> None:
    from fleetslam.middleware.recorder import recording_qos

    latched, plain = QoSProfile(durability="transient_local"), QoSProfile()
    assert recording_qos([latched, latched]).durability == "transient_local"
    assert (
        recording_qos([latched, plain]).durability == "volatile"
    )  # one volatile publisher: its late joiners get nothing
    assert recording_qos([plain, QoSProfile(reliability="best_effort")]).reliability == "best_effort"
    assert recording_qos([plain]).reliability == "reliable" and recording_qos([plain]).depth == 1000


def test_stats_shows_agents(
    talker: Node,
    make_context: Callable[..., Context],
    capsys: pytest.CaptureFixture[str],
) -> None:
    listener = Node("viewer", context=make_context("r2d2"), statistics_period_s=0.5)
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m: None)
    assert main(["stats", "--once", "--json", "--wait", "2"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    row = next(r for r in rows if r["topic"] == "/c3po/chatter")
    assert row["agent"] == "c3po" and row["node_pub"] == "/c3po/talker" and row["node_sub"] == "/r2d2/viewer"
    assert row["delivered"] > 5 and row["bandwidth_bps"] > 0 and row["dropped"] == 0  # ~25 per 0.5 s window at 50 Hz
    assert main(["stats", "--once", "--wait", "1.5", "--agent", "c3po"]) == 0
    assert "agent c3po" in capsys.readouterr().out


def test_tools_fail_fast_without_router(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("FLEETSLAM_ROUTER", f"tcp/127.0.0.1:{free_port()}")
    monkeypatch.setenv("FLEETSLAM_LISTEN", "tcp/127.0.0.1:0")
    assert main(["topic", "list"]) == 3
    assert "start one with `fleetslam router`" in capsys.readouterr().err
