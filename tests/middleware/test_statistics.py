import statistics as pystats
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import zenoh

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.statistics import RunningStats, SubscriptionStatistics
from fleetslam.middleware.subscription import RECEIVE_RING_CAPACITY
from fleetslam.middleware.wire import encode_attachment, topic_key
from fleetslam.msg.typesys import get_type, ns_from_stamp, serialize

from ..support import wait_until

String = get_type("std_msgs/msg/String")
GID_A = bytes(range(16))
GID_B = bytes(range(16, 32))


def test_running_stats_matches_the_textbook_formulas() -> None:
    values = [1e9 + v for v in np.random.default_rng(1).normal(0, 1e6, 500)]  # large offset: catastrophic for sums
    stats = RunningStats()
    for v in values:
        stats.add(v)
    assert stats.count == 500
    # Welford: mean within n·eps·|x| = 6e-5 at worst (6e-7 measured), σ to ~5e-14; sums of squares lose
    # (mean/σ)²·eps per term and miss by 1e-9 here
    assert abs(stats.mean - pystats.fmean(values)) < 1e-3
    assert abs(stats.stddev - pystats.stdev(values)) / pystats.stdev(values) < 1e-11
    assert stats.maximum == max(values)
    single = RunningStats()
    single.add(-5.0)
    assert (single.mean, single.stddev, single.maximum) == (-5.0, 0.0, -5.0)


def test_window_counts_gaps_periods_ages_per_publisher() -> None:
    acc = SubscriptionStatistics(now_ns=0)
    # publisher A: seq 1,2,5 at 10 ms period, each 2 ms old on arrival; B: seq 7,8 (its first seq is not a gap)
    for seq, t_ms in ((1, 100), (2, 110), (5, 120)):
        acc.on_sample(GID_A, seq, source_ns=(t_ms - 2) * 1_000_000, receive_ns=t_ms * 1_000_000, size=100)
    acc.on_sample(GID_B, 7, source_ns=0, receive_ns=50_000_000, size=10)
    acc.on_sample(GID_B, 8, source_ns=0, receive_ns=80_000_000, size=10)
    acc.on_sample(GID_B, 8, source_ns=0, receive_ns=90_000_000, size=10)  # duplicate: no drop, no rewind
    acc.on_error(GID_A, size=7)
    acc.on_error(None)
    reports = {r.publisher_gid: r for r in acc.close_window(now_ns=1_000_000_000)}
    a, b, unknown = reports[GID_A], reports[GID_B], reports[bytes(16)]
    assert (a.delivered, a.dropped, a.errors, a.traffic_bytes) == (3, 2, 1, 307)
    assert (a.window_start_ns, a.window_stop_ns) == (0, 1_000_000_000)
    assert a.period_mean_ns == 10_000_000 and a.period_stddev_ns == 0 and a.period_max_ns == 10_000_000
    assert a.age_mean_ns == 2_000_000 and a.age_max_ns == 2_000_000
    assert (b.delivered, b.dropped) == (3, 0) and b.period_max_ns == 30_000_000
    assert (unknown.delivered, unknown.errors) == (0, 1)
    assert (acc.total_delivered, acc.total_dropped, acc.total_errors) == (6, 2, 2)
    # The next window starts where the last stopped, forgets the counts, but remembers sequence numbers.
    acc.on_sample(GID_A, 7, source_ns=0, receive_ns=1_100_000_000, size=1)
    (next_a,) = acc.close_window(now_ns=2_000_000_000)
    assert next_a.window_start_ns == 1_000_000_000 and next_a.delivered == 1 and next_a.dropped == 1
    assert acc.close_window(now_ns=3_000_000_000) == []


def test_published_statistics_count_injected_gaps_and_positive_ages(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    listener = Node("listener", context=make_context("r2d2"), statistics_period_s=0.3)
    reports: list[Any] = []
    listener.create_subscription("fleetslam_msgs/msg/TopicStatistics", "/statistics", reports.append)
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m: None)
    time.sleep(0.3)
    key = topic_key(0, "/c3po/chatter", "std_msgs/msg/String")
    payload = serialize(String(data="x"), "std_msgs/msg/String")
    for seq in (1, 2, 5, 6, 10):  # gaps: 3,4 and 7,8,9 → 5 dropped
        raw_session.put(key, payload, attachment=encode_attachment(seq, time.time_ns() - 2_000_000, GID_A))
        time.sleep(0.01)

    def chatter() -> list[Any]:
        return [r for r in reports if r.topic == "/c3po/chatter"]

    # The samples may straddle a window boundary: add the windows up.
    assert wait_until(lambda: sum(r.delivered_msgs for r in chatter()) == 5, timeout_s=5)
    windows = chatter()
    assert sum(r.dropped_msgs for r in windows) == 5 and sum(r.error_msgs for r in windows) == 0
    assert sum(r.traffic for r in windows) == 5 * len(payload)
    for report in windows:
        assert report.type == "std_msgs/msg/String"
        assert (report.node_sub, report.agent_sub, report.agent_pub) == ("/r2d2/listener", "r2d2", "c3po")
        assert report.node_pub == ""  # a raw session has no token: no publishing node to name
        assert bytes(report.publisher_gid) == GID_A
        assert 2_000_000 <= ns_from_stamp(report.stamp_age_mean) < 1_000_000_000  # stamped 2 ms old, + transit
        assert ns_from_stamp(report.stamp_age_max) >= ns_from_stamp(report.stamp_age_mean)
        assert ns_from_stamp(report.window_stop) > ns_from_stamp(report.window_start)
    busiest = max(windows, key=lambda r: r.delivered_msgs)
    # put every 10 ms (+ the put): 5 ms below that, and 0.5 s allows sleeps overrunning 50× under load
    assert busiest.delivered_msgs >= 2 and 5_000_000 < ns_from_stamp(busiest.period_mean) < 500_000_000


def test_a_forged_sequence_jump_or_stamp_cannot_silence_the_statistics(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    """One sample claiming sequence 2**40 (a 2**40 gap) and one stamped 100 years ahead overflow the message's
    int32 fields: the report is published with them clamped, and the next windows still come."""
    listener = Node("listener", context=make_context("r2d2"), statistics_period_s=0.3)
    reports: list[Any] = []
    listener.create_subscription("fleetslam_msgs/msg/TopicStatistics", "/statistics", reports.append)
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m: None)
    time.sleep(0.3)
    key = topic_key(0, "/c3po/chatter", "std_msgs/msg/String")
    payload = serialize(String(data="x"), "std_msgs/msg/String")
    century_ns = 100 * 365 * 24 * 3600 * 1_000_000_000
    raw_session.put(key, payload, attachment=encode_attachment(1, time.time_ns(), GID_A))
    raw_session.put(key, payload, attachment=encode_attachment(2**40, time.time_ns() - century_ns, GID_A))

    def chatter() -> list[Any]:
        return [r for r in reports if r.topic == "/c3po/chatter"]

    assert wait_until(lambda: sum(r.delivered_msgs for r in chatter()) == 2, timeout_s=5)
    assert max(r.dropped_msgs for r in chatter()) == 2**31 - 1
    assert max(ns_from_stamp(r.stamp_age_max) for r in chatter()) > 10 * 365 * 24 * 3600 * 1_000_000_000
    raw_session.put(key, payload, attachment=encode_attachment(2**40 + 1, time.time_ns(), GID_A))
    assert wait_until(lambda: sum(r.delivered_msgs for r in chatter()) == 3, timeout_s=5)


def test_statistics_name_the_publishing_node_and_can_be_turned_off(make_context: Callable[..., Context]) -> None:
    talker = Node("talker", context=make_context("c3po"), statistics_period_s=0)
    listener = Node("listener", context=make_context(), statistics_period_s=0.2)
    quiet = Node("quiet", context=make_context(statistics=False), statistics_period_s=0.2)
    reports = []
    listener.create_subscription("fleetslam_msgs/msg/TopicStatistics", "/statistics", reports.append)
    listener.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m: None)
    quiet.create_subscription("std_msgs/msg/String", "/c3po/chatter", lambda m: None)
    pub = talker.create_publisher("std_msgs/msg/String", "chatter")
    assert wait_until(lambda: pub.matched_subscriptions == 2)
    for _ in range(5):
        pub.publish(String(data="x"))
        time.sleep(0.02)
    assert wait_until(lambda: any(r.delivered_msgs for r in reports), timeout_s=5)
    time.sleep(0.5)
    assert {r.node_sub for r in reports} == {"/listener"}
    assert {r.node_pub for r in reports} == {"/c3po/talker"}
    assert sum(r.delivered_msgs for r in reports) == 5 and all(r.dropped_msgs == 0 for r in reports)
    assert all(bytes(r.publisher_gid) == pub.gid for r in reports)


def test_forged_publishers_are_bounded_and_their_counts_kept_as_other_publishers() -> None:
    acc = SubscriptionStatistics(now_ns=0, max_publishers=4)
    for k in range(1000):
        acc.on_sample((k + 1).to_bytes(16, "little"), 1, 0, 1_000 + k, 10)
    acc.on_sample(GID_A, 1, 0, 2_000, 10)
    assert acc.publishers == 4 and acc.evicted == 1000 + 1 - 4
    reports = acc.close_window(now_ns=10_000)
    assert len(reports) == 5  # the four most recent GIDs and "other publishers"
    others = [r for r in reports if r.publisher_gid == bytes(16)]
    assert len(others) == 1 and others[0].delivered == 1000 + 1 - 4
    assert sum(r.delivered for r in reports) == 1001 and sum(r.traffic_bytes for r in reports) == 10_010
    assert GID_A in {r.publisher_gid for r in reports}


def test_a_flood_of_forged_gids_leaves_statistics_bounded_and_the_node_delivering(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    """Issue 18, D4: 50,000 forged GIDs grew the SLAM node by 33.9 MB, 2,000 made 2,024 reports in 5 s."""
    listener = Node("listener", context=make_context("r2d2"), statistics_period_s=0.5)
    reports: list[Any] = []
    listener.create_subscription(
        "fleetslam_msgs/msg/TopicStatistics", "/statistics", reports.append, QoSProfile(depth=1000)
    )
    received: list[float] = []
    chatter = listener.create_subscription(
        "std_msgs/msg/String", "/c3po/chatter", lambda m: received.append(time.monotonic())
    )
    time.sleep(0.3)
    key = topic_key(0, "/c3po/chatter", "std_msgs/msg/String")
    payload = serialize(String(data="x"), "std_msgs/msg/String")
    forged = 20_000
    for k in range(forged):
        raw_session.put(key, payload, attachment=encode_attachment(1, time.time_ns(), (k + 1).to_bytes(16, "big")))
    # KEEP_LAST: what the receive thread could not take in time, Zenoh's ring dropped before it was counted.
    counted = -1
    while counted != chatter.statistics.total_delivered:  # until the flood is taken in
        counted = chatter.statistics.total_delivered
        time.sleep(0.5)
    assert RECEIVE_RING_CAPACITY <= counted <= forged
    assert chatter.statistics.publishers <= chatter.statistics.max_publishers
    assert len(chatter.publisher_types) <= chatter.statistics.max_publishers
    time.sleep(1.2)  # the flood's windows are reported
    flood_windows: dict[int, int] = {}
    for report in reports:
        if report.topic == "/c3po/chatter":
            start = ns_from_stamp(report.window_start)
            flood_windows[start] = flood_windows.get(start, 0) + 1
    assert flood_windows and max(flood_windows.values()) <= chatter.statistics.max_publishers + 1, flood_windows
    assert sum(r.delivered_msgs for r in reports if r.topic == "/c3po/chatter") == counted  # every count reported
    # After the flood, a genuine publisher is heard at its rate and gets its own report.
    before = len(received)
    for seq in range(1, 21):
        raw_session.put(key, payload, attachment=encode_attachment(seq, time.time_ns(), GID_A))
        time.sleep(0.02)
    assert wait_until(lambda: len(received) - before == 20, 5.0)
    assert wait_until(lambda: any(bytes(r.publisher_gid) == GID_A for r in reports), 5.0)


def test_interleaved_publishers_keep_their_own_periods_and_ages() -> None:
    # The fast path remembers the previous sample's publisher: alternating GIDs must still be kept apart.
    acc = SubscriptionStatistics(now_ns=0)
    for i in range(10):
        t = 1_000_000 * (i + 1)
        acc.on_sample(GID_A, i + 1, source_ns=t - 1000, receive_ns=t, size=10)  # A: every 1 ms, 1 µs old
        if i % 2 == 0:
            acc.on_sample(GID_B, i // 2 + 1, source_ns=t - 3000, receive_ns=t + 10, size=20)  # B: 2 ms, 3 µs
    reports = {r.publisher_gid: r for r in acc.close_window(now_ns=10**9)}
    a, b = reports[GID_A], reports[GID_B]
    assert (a.delivered, a.dropped, a.traffic_bytes) == (10, 0, 100)
    assert (b.delivered, b.dropped, b.traffic_bytes) == (5, 0, 100)
    assert a.period_mean_ns == 1_000_000 and a.period_stddev_ns == 0 and a.age_mean_ns == 1000
    assert b.period_mean_ns == 2_000_000 and b.period_max_ns == 2_000_000 and b.age_mean_ns == 3010


def test_one_publisher_table_evicts_the_previous_publisher_into_others() -> None:
    acc = SubscriptionStatistics(now_ns=0, max_publishers=1)
    acc.on_sample(GID_A, 1, source_ns=0, receive_ns=10, size=1)
    acc.on_sample(GID_A, 3, source_ns=0, receive_ns=20, size=1)
    acc.on_sample(GID_B, 1, source_ns=0, receive_ns=30, size=2)  # evicts A, whose counts go to "others"
    acc.on_sample(GID_A, 4, source_ns=0, receive_ns=40, size=4)  # A again: new, its old sequence forgotten
    reports = {r.publisher_gid: r for r in acc.close_window(now_ns=100)}
    assert set(reports) == {GID_A, bytes(16)} and acc.evicted == 2
    assert (reports[GID_A].delivered, reports[GID_A].dropped, reports[GID_A].traffic_bytes) == (1, 0, 4)
    others = reports[bytes(16)]
    assert (others.delivered, others.dropped, others.traffic_bytes) == (3, 1, 4)  # A's 2 (1 gap) and B's 1
    assert acc.total_delivered == 4 and acc.total_dropped == 1


def _textbook_windows(events: list[tuple[Any, ...]]) -> list[dict[bytes, tuple[Any, ...]]]:
    """Each window's (delivered, dropped, traffic, period mean/σ/max, age mean/σ/max) per GID, from whole lists."""
    windows: list[dict[bytes, tuple[Any, ...]]] = []
    current: dict[bytes, dict[str, Any]] = {}
    last_seq: dict[bytes, int] = {}
    last_receive: dict[bytes, int] = {}
    for event in events:
        if event[0] == "close":
            windows.append(
                {
                    gid: (
                        w["delivered"], w["dropped"], w["traffic"],
                        *[(pystats.fmean(v), pystats.stdev(v) if len(v) > 1 else 0.0, max(v)) if v else (0.0, 0.0, 0.0)
                          for v in (w["periods"], w["ages"])],
                    )
                    for gid, w in current.items()
                }
            )  # fmt: skip
            current = {}
            continue
        _, gid, seq, source, receive, size = event
        w = current.setdefault(gid, {"delivered": 0, "dropped": 0, "traffic": 0, "periods": [], "ages": []})
        w["delivered"] += 1
        w["traffic"] += size
        if gid in last_seq and seq > last_seq[gid] + 1:
            w["dropped"] += seq - last_seq[gid] - 1
        last_seq[gid] = max(seq, last_seq.get(gid, seq))
        if gid in last_receive:
            w["periods"].append(receive - last_receive[gid])
        last_receive[gid] = receive
        w["ages"].append(receive - source)
    return windows


@pytest.mark.parametrize("runs", [False, True], ids=["on_sample", "on_samples"])
def test_batched_statistics_match_the_textbook_on_long_random_streams(runs: bool) -> None:
    """Samples are folded in batches (NumPy) or one by one (small batches, numbers beyond int64 arithmetic); every
    window must report what whole-list formulas give: counts exactly, means and σ to rounding. The same whether
    they come one by one or in runs of one publisher's (``on_samples``, what an executor's pull from the ring
    records), runs with a number beyond int64 included."""
    rng = np.random.default_rng(11)
    gids = [GID_A, GID_B, bytes(range(32, 48))]
    sequence = dict.fromkeys(gids, 0)
    now = 1_700_000_000_000_000_000
    events: list[tuple[Any, ...]] = []
    for i in range(12_000):
        gid = gids[0] if rng.random() < 0.8 else gids[int(rng.integers(1, 3))]
        sequence[gid] += int(rng.choice([1, 1, 1, 1, 1, 2, 7, 0, -2]))
        if i == 5_000:
            sequence[gid] = 2**41  # a forged jump: that batch is folded exactly, in Python
        now += int(rng.integers(0, 3_000_000))
        source = now - int(rng.integers(0, 20_000_000)) if i != 7_000 else -(2**64)  # beyond int64
        events.append(("sample", gid, sequence[gid], source, now, int(rng.integers(1, 100))))
        if rng.random() < 0.0015:
            events.append(("close",))
    events.append(("close",))
    acc = SubscriptionStatistics(now_ns=0)
    got: list[dict[bytes, tuple[Any, ...]]] = []
    run: list[tuple[Any, ...]] = []
    run_length = 1

    def flush() -> None:
        if run:
            acc.on_samples(run[0][1], [e[2] for e in run], [e[3] for e in run], [e[4] for e in run],
                           sum(e[5] for e in run))  # fmt: skip
            run.clear()

    for event in events:
        if runs and event[0] == "sample" and (not run or (run[0][1] == event[1] and len(run) < run_length)):
            run.append(event)
            continue
        flush()
        run_length = int(rng.integers(1, 300))
        if runs and event[0] == "sample":
            run.append(event)
            continue
        if event[0] == "close":
            got.append(
                {
                    r.publisher_gid: (
                        r.delivered, r.dropped, r.traffic_bytes,
                        (r.period_mean_ns, r.period_stddev_ns, r.period_max_ns),
                        (r.age_mean_ns, r.age_stddev_ns, r.age_max_ns),
                    )
                    for r in acc.close_window(now)
                }
            )  # fmt: skip
        else:
            acc.on_sample(*event[1:])
    flush()
    expected = _textbook_windows(events)
    assert len(got) == len(expected) > 10
    for window_got, window_expected in zip(got, expected, strict=True):
        assert window_got.keys() == window_expected.keys()
        for gid, (*counts, period, age) in window_got.items():
            *want_counts, want_period, want_age = window_expected[gid]
            assert counts == want_counts
            for value, want in zip([*period, *age], [*want_period, *want_age], strict=True):
                assert value == pytest.approx(want, rel=1e-9, abs=1e-3)
    assert acc.total_delivered == sum(1 for e in events if e[0] == "sample")
    assert acc.total_dropped == sum(w[gid][1] for w in expected for gid in w)
