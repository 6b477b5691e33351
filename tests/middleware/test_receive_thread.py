"""KEEP_LAST subscriptions take their samples from a Zenoh ring channel on a receive thread of their own and hand
them to the node's executor in batches, or deliver them themselves while the executor is idle and the callback is
quick: the node's guarantees (one callback at a time, in order, KEEP_LAST, statistics) hold, Zenoh never waits for
a slow node, and undeclaring ends the thread."""

import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from fleetslam.middleware import Context, Node, Publisher, QoSProfile, Subscription
from fleetslam.middleware.subscription import LARGE_SAMPLE_BYTES
from fleetslam.msg.typesys import get_type

from ..support import wait_until

String = get_type("std_msgs/msg/String")


def test_a_slow_callback_gets_the_newest_samples_and_every_sample_is_counted(
    make_context: Callable[..., Context],
) -> None:
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("slow", context=make_context(), statistics_period_s=0)
    release = threading.Event()
    got: list[str] = []

    def on_message(msg: Any) -> None:
        got.append(msg.data)
        release.wait(10.0)  # the first callback holds the executor while the rest arrive

    sub = node.create_subscription("std_msgs/msg/String", "/cmd", on_message, QoSProfile(depth=3))
    pub = talker.create_publisher("std_msgs/msg/String", "/cmd")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    time.sleep(0.1)
    pub.publish(String(data="0"))
    assert wait_until(lambda: got == ["0"])
    for i in range(1, 41):
        pub.publish(String(data=str(i)))
    # The receive thread goes on counting while the callback runs (the ring is far from full).
    assert wait_until(lambda: sub.statistics.total_delivered == 41)
    release.set()
    assert wait_until(lambda: got == ["0", "38", "39", "40"])
    assert sub.queue_overflows == 37
    assert sub.statistics.total_dropped == 0  # KEEP_LAST's own drops are no sequence gaps
    time.sleep(0.1)
    assert got == ["0", "38", "39", "40"]


def test_a_nodes_callbacks_run_one_at_a_time(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("busy", context=make_context(), statistics_period_s=0)
    state = {"active": 0, "most": 0}
    threads: set[str] = set()
    got: dict[str, list[int]] = {"/a": [], "/b": []}

    def enter(what: str) -> None:
        state["active"] += 1
        state["most"] = max(state["most"], state["active"])
        threads.add(threading.current_thread().name)
        time.sleep(0.0002)  # gives up the GIL: a callback running beside this one would be seen
        state["active"] -= 1

    def on_topic(topic: str) -> Callable[[Any], None]:
        def callback(msg: Any) -> None:
            enter(topic)
            got[topic].append(int(msg.data))

        return callback

    for topic in got:
        node.create_subscription("std_msgs/msg/String", topic, on_topic(topic), QoSProfile(depth=1000))
    node.create_timer(0.002, lambda: enter("timer"))
    publishers = [talker.create_publisher("std_msgs/msg/String", topic) for topic in got]
    assert wait_until(lambda: all(p.matched_subscriptions == 1 for p in publishers))
    time.sleep(0.1)

    def publish(index: int) -> None:
        for i in range(300):
            publishers[index].publish(String(data=str(i)))
            node.call_soon(lambda: enter("call_soon"))
            if i % 20 == 0:
                time.sleep(0.002)

    senders = [threading.Thread(target=publish, args=(k,)) for k in range(2)]
    for sender in senders:
        sender.start()
    for sender in senders:
        sender.join()
    assert wait_until(lambda: all(values and values[-1] == 299 for values in got.values()), 10.0), got
    assert state["most"] == 1
    receivers = {sub._receiver.name for sub in node._subscriptions if sub._receiver is not None}
    assert len(receivers) == 2
    assert f"executor:{node.fq_name}" in threads and threads <= {f"executor:{node.fq_name}", *receivers}
    for values in got.values():
        assert values == sorted(values)  # in arrival order


def _lone_samples(
    make_context: Callable[..., Context], topic: str, on_message: Callable[[Any], None], got: list[tuple[str, str]]
) -> tuple[Node, Subscription, Publisher, Callable[[str], str]]:
    """A listener node subscribed to ``topic``, a talker's publisher of it, and ``send(data)``: publish one sample,
    wait until ``on_message`` has appended it to ``got`` as (data, thread name), let the executor go idle again,
    return that thread's name."""
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("listener", context=make_context(), statistics_period_s=0)
    sub = node.create_subscription("std_msgs/msg/String", topic, on_message, QoSProfile(depth=10))
    pub = talker.create_publisher("std_msgs/msg/String", topic)
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    time.sleep(0.1)

    def send(data: str) -> str:
        pub.publish(String(data=data))
        assert wait_until(lambda: got and got[-1][0] == data, timeout_s=2.0), f"{data} was not delivered"
        time.sleep(0.01)  # a lone sample each: the executor is idle again
        return got[-1][1]

    return node, sub, pub, send


def test_a_slow_callback_goes_back_to_the_executor_and_a_quick_one_to_the_receive_thread(
    make_context: Callable[..., Context],
) -> None:
    got: list[tuple[str, str]] = []

    def on_message(msg: Any) -> None:
        if msg.data.startswith("slow"):
            time.sleep(0.005)  # over QUICK_CALLBACK_S
        got.append((msg.data, threading.current_thread().name))

    node, sub, _, send = _lone_samples(make_context, "/pace", on_message, got)
    receiver, executor = sub._receiver.name, f"executor:{node.fq_name}"  # type: ignore[union-attr]
    for round_ in range(3):
        # Quick callbacks move to the receive thread (a quick one measured over 1 ms on a loaded machine delays
        # that by a sample: try a few).
        assert any(send(f"quick{round_}.{k}") == receiver for k in range(20))
        assert send(f"slow{round_}") == receiver  # its cost shows only once it has run
        assert send(f"after{round_}") == executor  # the slow one's successor: on the executor
    assert sub.statistics.total_delivered == len(got)


def test_a_callback_on_the_receive_thread_may_destroy_its_subscription_and_its_node(
    make_context: Callable[..., Context],
) -> None:
    got: list[tuple[str, str]] = []

    def on_message(msg: Any) -> None:
        got.append((msg.data, threading.current_thread().name))
        if msg.data == "stop":
            sub.destroy()
            node.destroy()  # stops the executor: must not wait for this very callback

    node, sub, pub, send = _lone_samples(make_context, "/end", on_message, got)
    receiver = sub._receiver
    assert receiver is not None
    # Until the receive thread delivers them (the first goes to the executor).
    assert any(send(str(k)) == receiver.name for k in range(20))
    started = time.monotonic()
    assert send("stop") == receiver.name
    assert wait_until(lambda: not receiver.is_alive() and not node._executor._thread.is_alive(), 2.0)
    assert time.monotonic() - started < 1.5  # no wait for itself (the executor's stop waits up to 2 s)
    pub.publish(String(data="after"))
    time.sleep(0.2)
    assert got[-1][0] == "stop"


def test_undeclaring_wakes_and_ends_a_waiting_receive_thread(make_context: Callable[..., Context]) -> None:
    node = Node("listener", context=make_context(), statistics_period_s=0)
    sub = node.create_subscription("std_msgs/msg/String", "/quiet", lambda m: None)
    receiver = sub._receiver
    assert receiver is not None and receiver.is_alive()
    time.sleep(0.3)  # waiting in recv, without the GIL
    started = time.monotonic()
    sub.destroy()
    assert wait_until(lambda: not receiver.is_alive(), 2.0)
    assert time.monotonic() - started < 1.0


def test_closing_the_context_ends_the_receive_threads(make_context: Callable[..., Context]) -> None:
    context = make_context()
    node = Node("listener", context=context, statistics_period_s=0)
    receivers = [node.create_subscription("std_msgs/msg/String", f"/t{k}", lambda m: None)._receiver for k in range(3)]
    assert all(r is not None and r.is_alive() for r in receivers)
    context.close()
    assert wait_until(lambda: not any(r is not None and r.is_alive() for r in receivers), 2.0)


def test_a_callback_may_destroy_its_own_subscription(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("listener", context=make_context(), statistics_period_s=0)
    got: list[str] = []

    def once(msg: Any) -> None:
        got.append(msg.data)
        sub.destroy()

    sub = node.create_subscription("std_msgs/msg/String", "/once", once, QoSProfile(depth=1))
    pub = talker.create_publisher("std_msgs/msg/String", "/once")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    pub.publish(String(data="first"))
    assert wait_until(lambda: got == ["first"])
    receiver = sub._receiver
    assert receiver is not None and wait_until(lambda: not receiver.is_alive(), 2.0)
    pub.publish(String(data="second"))
    time.sleep(0.3)
    assert got == ["first"]


def test_a_stalled_node_does_not_hold_back_its_session(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    context = make_context()
    stalled = Node("stalled", context=context, statistics_period_s=0)
    lively = Node("lively", context=context, statistics_period_s=0)
    release = threading.Event()
    stalled.call_soon(release.wait)
    got: list[str] = []
    flooded = stalled.create_subscription("std_msgs/msg/String", "/flood", lambda m: got.append(m.data),
                                          QoSProfile(depth=1))  # fmt: skip
    heard: list[str] = []
    lively.create_subscription("std_msgs/msg/String", "/ping", lambda m: heard.append(m.data))
    flood = talker.create_publisher("std_msgs/msg/String", "/flood", QoSProfile(history="keep_all"))
    ping = talker.create_publisher("std_msgs/msg/String", "/ping")
    assert wait_until(lambda: flood.matched_subscriptions == 1 and ping.matched_subscriptions == 1)
    time.sleep(0.1)
    for i in range(3000):
        flood.publish(String(data=str(i)))
    ping.publish(String(data="ping"))
    assert wait_until(lambda: heard == ["ping"], 5.0)
    assert not got  # the stalled node's executor is still held
    release.set()
    assert wait_until(lambda: got == ["2999"], 5.0)
    stats = flooded.statistics
    # A sample is counted (then delivered or overwritten in the queue) or, if Zenoh's ring overwrote it first, seen
    # missing as a gap; those before the first one counted are not seen at all (this thread held the GIL).
    assert stats.total_delivered >= 1 and stats.total_delivered + stats.total_dropped <= 3000
    assert flooded.queue_overflows == stats.total_delivered - 1


FLOODER = """
import sys, time
from fleetslam.middleware import Context, Node, Publisher, QoSProfile, Subscription
from fleetslam.msg.typesys import get_type, serialize
with Context(statistics=False) as context:
    node = Node("flooder", context=context, statistics_period_s=0)
    flood = node.create_publisher("std_msgs/msg/String", "/flood", QoSProfile(history="keep_all"))
    payload = serialize(get_type("std_msgs/msg/String")(data="x" * 56), "std_msgs/msg/String")
    print("ready", flush=True)
    deadline = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < deadline:
        for _ in range(100):
            flood.publish(payload)
"""


def test_a_flood_does_not_starve_the_nodes_timer_or_its_other_subscriptions(
    fleet_env: str, make_context: Callable[..., Context]
) -> None:
    talker = Node("talker", context=make_context(), statistics_period_s=0)
    node = Node("flooded", context=make_context(), statistics_period_s=0)
    started: list[float] = []
    flood_got = [0]
    ticks: list[float] = []
    pings: list[float] = []

    def on_flood(msg: Any) -> None:
        if not started:
            started.append(time.monotonic())
        flood_got[0] += 1
        spin_until = time.perf_counter() + 0.00002  # a callback with some work: the executor is the bottleneck
        while time.perf_counter() < spin_until:
            pass

    flooded = node.create_subscription("std_msgs/msg/String", "/flood", on_flood, QoSProfile(depth=1000))
    node.create_subscription("std_msgs/msg/String", "/ping", lambda m: pings.append(time.monotonic()))
    node.create_timer(0.01, lambda: ticks.append(time.monotonic()))
    ping = talker.create_publisher("std_msgs/msg/String", "/ping")
    # The flood comes from another process: a publisher in this one would share the GIL with the executor.
    flooder = subprocess.Popen([sys.executable, "-c", FLOODER, "3.0"], stdout=subprocess.PIPE, text=True)
    try:
        assert flooder.stdout is not None and flooder.stdout.readline().strip() == "ready"
        assert wait_until(lambda: bool(started), 10.0)
        for i in range(10):
            time.sleep(0.1)
            ping.publish(String(data=str(i)))
        time.sleep(0.2)
        flooding = (started[0], time.monotonic())
        received = flood_got[0]
    finally:
        flooder.kill()
        flooder.wait()
    # The flood kept the executor busy throughout, and the executor took its samples from the ring itself...
    assert received > 1000
    assert flooded._pulled > 0
    # ... a batch at a time: the timer (10 ms) and the other topic took their turns in between.
    ticks_during = [t for t in ticks if flooding[0] < t < flooding[1]]
    pings_during = [t for t in pings if flooding[0] < t < flooding[1]]
    assert len(ticks_during) >= 20, (len(ticks_during), received)
    assert len(pings_during) >= 8, (len(pings_during), received)


def _image(index: int, size: int) -> Any:
    from fleetslam.msg.typesys import header

    data = np.full(size, index, np.uint8)  # index < 256
    return get_type("sensor_msgs/msg/Image")(
        header=header("camera", 0), height=1, width=size, encoding="mono8", is_bigendian=0, step=size, data=data
    )


def test_large_samples_keep_keep_last_and_the_statistics_one_by_one(make_context: Callable[..., Context]) -> None:
    # Samples from LARGE_SAMPLE_BYTES on are taken from the ring one at a time (never pulled in a batch): a slow
    # callback still gets the newest, every sample is counted as it arrives, and a quick one gets each in order.
    size = LARGE_SAMPLE_BYTES + 1000
    talker = Node("camera", context=make_context(), statistics_period_s=0)
    node = Node("viewer", context=make_context(), statistics_period_s=0)
    release = threading.Event()
    slow: list[int] = []

    def on_slow(msg: Any) -> None:
        assert msg.data.size == size and msg.header.frame_id == "camera"
        slow.append(int(msg.data[-1]))
        release.wait(10.0)

    sub = node.create_subscription("sensor_msgs/msg/Image", "/slow", on_slow, QoSProfile(depth=3))
    pub = talker.create_publisher("sensor_msgs/msg/Image", "/slow")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    time.sleep(0.1)
    pub.publish(_image(0, size))
    assert wait_until(lambda: slow == [0])
    for i in range(1, 21):
        pub.publish(_image(i, size))
    assert wait_until(lambda: sub.statistics.total_delivered == 21)
    release.set()
    assert wait_until(lambda: slow == [0, 18, 19, 20])
    assert sub.queue_overflows == 17
    assert sub.statistics.total_dropped == 0

    quick: list[int] = []
    burst = node.create_subscription(
        "sensor_msgs/msg/Image", "/burst", lambda msg: quick.append(int(msg.data[-1])), QoSProfile(depth=100)
    )
    pub = talker.create_publisher("sensor_msgs/msg/Image", "/burst")
    assert wait_until(lambda: pub.matched_subscriptions == 1)
    time.sleep(0.1)
    for i in range(60):
        pub.publish(_image(i, size))
    assert wait_until(lambda: len(quick) == 60)
    assert quick == list(range(60))
    assert burst.statistics.total_delivered == 60
    assert burst._pulled == 0  # no sample was taken from the ring in a batch
