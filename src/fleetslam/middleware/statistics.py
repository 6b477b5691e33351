"""Per-subscription network statistics, as ROS 1's TopicStatistics, for each publisher (by GID) and window.

For every received sample the subscription records its size, the gap in the publisher's sequence numbers
(dropped messages), the period since the publisher's previous sample, and the age (receive time minus the
attachment's source timestamp). Each update is O(1) and creates no container: one lock, a comparison with the
previous sample's publisher (else a dictionary lookup) and Welford's update of two running statistics.
Pure and thread-safe; no Zenoh here (the subscription feeds it, the node publishes its reports).

Bounded: the publisher GID comes from the sample's attachment, which anyone can forge, so at most
``max_publishers`` are tracked per subscription (the most recently heard). A new one evicts the least recently
heard, whose unreported counts move to the "other publishers" entry (the all-zero GID, also used for samples
whose attachment could not be read), so no count is lost and a window reports at most ``max_publishers + 1``
publishers however many GIDs were forged.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field


@dataclass
class RunningStats:
    """Count, mean, sample standard deviation and max of a stream of values (Welford's update, O(1))."""

    count: int = 0
    mean: float = 0.0
    _m2: float = 0.0
    maximum: float = 0.0

    def add(self, value: float) -> None:
        # SubscriptionStatistics.on_sample inlines this update; keep the two the same.
        self.count += 1
        delta = value - self.mean
        self.mean += delta / self.count
        self._m2 += delta * (value - self.mean)
        if value > self.maximum or self.count == 1:
            self.maximum = value

    @property
    def stddev(self) -> float:
        return math.sqrt(max(self._m2, 0.0) / (self.count - 1)) if self.count >= 2 else 0.0


@dataclass
class PublisherWindow:
    """What one subscription saw from one publisher in the current window."""

    delivered: int = 0
    dropped: int = 0
    errors: int = 0
    traffic_bytes: int = 0
    period: RunningStats = field(default_factory=RunningStats)
    age: RunningStats = field(default_factory=RunningStats)

    def absorb(self, other: PublisherWindow) -> None:
        """Add another window's counts (an evicted publisher's, into "other publishers"; periods and ages are not
        comparable across publishers and stay its own)."""
        self.delivered += other.delivered
        self.dropped += other.dropped
        self.errors += other.errors
        self.traffic_bytes += other.traffic_bytes


@dataclass(frozen=True)
class WindowReport:
    """A closed window of one (publisher GID, subscription) pair."""

    publisher_gid: bytes
    window_start_ns: int
    window_stop_ns: int
    delivered: int
    dropped: int
    errors: int
    traffic_bytes: int
    period_mean_ns: float
    period_stddev_ns: float
    period_max_ns: float
    age_mean_ns: float
    age_stddev_ns: float
    age_max_ns: float


_NO_GID = b"\x00" * 16
"""Samples of no readable GID, and the publishers evicted from a full table ("other publishers")."""
DEFAULT_MAX_PUBLISHERS = 32


class _PublisherState:
    """What a subscription remembers of one publisher across windows, and its current window."""

    __slots__ = ("last_receive", "last_seq", "window")

    def __init__(self) -> None:
        self.last_seq: int | None = None
        self.last_receive: int | None = None
        self.window = PublisherWindow()


class SubscriptionStatistics:
    """Statistics of one subscription, per publisher GID (at most ``max_publishers``, see the module docstring),
    over windows closed by :meth:`close_window`."""

    def __init__(self, now_ns: int, max_publishers: int = DEFAULT_MAX_PUBLISHERS) -> None:
        if max_publishers < 1:
            raise ValueError(f"max_publishers must be at least 1, got {max_publishers}")
        self.max_publishers = max_publishers
        self._lock = threading.Lock()
        self._window_start = now_ns
        self._publishers: OrderedDict[bytes, _PublisherState] = OrderedDict()
        """Least recently heard first."""
        self._others = _PublisherState()
        self._last_gid = _NO_GID
        self._last_state = self._others
        """The publisher of the previous sample: most samples come from it, and it is already the most recent."""
        self.total_delivered = 0
        self.total_dropped = 0
        self.total_errors = 0
        self.evicted = 0
        """Publishers forgotten because the table was full."""

    @property
    def publishers(self) -> int:
        """GIDs tracked now."""
        with self._lock:
            return len(self._publishers)

    def _state(self, gid: bytes) -> _PublisherState:
        if gid == self._last_gid:
            return self._last_state
        if gid == _NO_GID:
            return self._others
        state = self._publishers.get(gid)
        if state is None:
            if len(self._publishers) >= self.max_publishers:
                _, oldest = self._publishers.popitem(last=False)
                self._others.window.absorb(oldest.window)
                self.evicted += 1
            state = self._publishers[gid] = _PublisherState()
        else:
            self._publishers.move_to_end(gid)
        self._last_gid, self._last_state = gid, state
        return state

    def on_sample(self, gid: bytes, sequence_number: int, source_ns: int, receive_ns: int, size: int) -> None:
        """Record a delivered sample (a sequence number above the last + 1 counts the gap as dropped)."""
        with self._lock:
            state = self._state(gid)
            window = state.window
            window.delivered += 1
            window.traffic_bytes += size
            self.total_delivered += 1
            previous = state.last_seq
            if previous is None or sequence_number > previous:
                if previous is not None and sequence_number > previous + 1:
                    gap = sequence_number - previous - 1
                    window.dropped += gap
                    self.total_dropped += gap
                state.last_seq = sequence_number
            last_receive = state.last_receive
            if last_receive is not None:  # RunningStats.add, inlined (the hot path of every sample)
                stats = window.period
                value = receive_ns - last_receive
                n = stats.count = stats.count + 1
                delta = value - stats.mean
                stats.mean += delta / n
                stats._m2 += delta * (value - stats.mean)
                if value > stats.maximum or n == 1:
                    stats.maximum = value
            state.last_receive = receive_ns
            stats = window.age
            value = receive_ns - source_ns
            n = stats.count = stats.count + 1
            delta = value - stats.mean
            stats.mean += delta / n
            stats._m2 += delta * (value - stats.mean)
            if value > stats.maximum or n == 1:
                stats.maximum = value

    def on_error(self, gid: bytes | None, size: int = 0) -> None:
        """Record a sample that was dropped as malformed, oversized or unprocessable."""
        with self._lock:
            window = self._state(gid or _NO_GID).window
            window.errors += 1
            window.traffic_bytes += size
            self.total_errors += 1

    def on_malformed(self, gid: bytes) -> None:
        """A sample counted by :meth:`on_sample` turned out undecodable: count it as an error instead."""
        with self._lock:
            window = self._state(gid).window
            if window.delivered > 0:  # else it was delivered in the previous window; leave that report as sent
                window.delivered -= 1
                self.total_delivered -= 1
            window.errors += 1
            self.total_errors += 1

    def close_window(self, now_ns: int) -> list[WindowReport]:
        """Reports of the window that ends now (only publishers with activity), and start a new window."""
        with self._lock:
            start, self._window_start = self._window_start, now_ns
            windows = []
            for gid, state in [*self._publishers.items(), (_NO_GID, self._others)]:
                w = state.window
                if w.delivered or w.errors or w.dropped:
                    windows.append((gid, w))
                    state.window = PublisherWindow()
        return [
            WindowReport(
                publisher_gid=gid,
                window_start_ns=start,
                window_stop_ns=now_ns,
                delivered=w.delivered,
                dropped=w.dropped,
                errors=w.errors,
                traffic_bytes=w.traffic_bytes,
                period_mean_ns=w.period.mean,
                period_stddev_ns=w.period.stddev,
                period_max_ns=w.period.maximum,
                age_mean_ns=w.age.mean,
                age_stddev_ns=w.age.stddev,
                age_max_ns=w.age.maximum,
            )
            for gid, w in windows
        ]
