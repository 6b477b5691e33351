"""Per-subscription network statistics, as ROS 1's TopicStatistics, for each publisher (by GID) and window.

For every received sample the subscription records its size, the gap in the publisher's sequence numbers
(dropped messages), the period since the publisher's previous sample, and the age (receive time minus the
attachment's source timestamp). Each update is O(1) and creates no container: one lock, a comparison with the
previous sample's publisher (else a dictionary lookup), the size added up and the sequence number, source and
receive times appended to three preallocated ``int64`` arrays. The arrays are folded into the window's counts and
running statistics in batches (NumPy, Chan's combination of means and squared deviations) when
:data:`FOLD_BATCH` samples have gathered, and before anything reads them (a report, a total, an eviction); the
result is what Welford's update sample by sample gives (to rounding), for half the cost per sample on the
receiving thread. Small batches, and values too large for exact ``int64`` arithmetic (forged sequence numbers or
stamps), are folded sample by sample in Python, exactly as before.
Pure and thread-safe; no Zenoh here (the subscription feeds it, the node publishes its reports).

Bounded: the publisher GID comes from the sample's attachment, which anyone can forge, so at most
``max_publishers`` are tracked per subscription (the most recently heard). A new one evicts the least recently
heard, whose unreported counts move to the "other publishers" entry (the all-zero GID, also used for samples
whose attachment could not be read), so no count is lost and a window reports at most ``max_publishers + 1``
publishers however many GIDs were forged.
"""

from __future__ import annotations

import math
import struct
import threading
from array import array
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np


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

    def merge(self, count: int, mean: float, m2: float, maximum: float) -> None:
        """Add a batch given by its count, mean, sum of squared deviations from that mean and max (Chan et al.)."""
        if count <= 0:
            return
        if self.count == 0:
            self.count, self.mean, self._m2, self.maximum = count, mean, m2, maximum
            return
        n = self.count + count
        delta = mean - self.mean
        self.mean += delta * count / n
        self._m2 += m2 + delta * delta * self.count * count / n
        self.count = n
        if maximum > self.maximum:
            self.maximum = maximum

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


_pack = struct.pack
_NO_GID = b"\x00" * 16
"""Samples of no readable GID, and the publishers evicted from a full table ("other publishers")."""
DEFAULT_MAX_PUBLISHERS = 32


FOLD_BATCH = 1024
"""Samples gathered per publisher before they are folded into the window (24 KiB of arrays at most)."""
_EXACT_BELOW = 32
"""Batches smaller than this are folded sample by sample (NumPy's fixed cost would dominate: a flood of forged
GIDs folds one sample per eviction)."""
_SAFE = 2**40
"""Sequence numbers below this, and times within ``2**62`` ns, keep every difference and sum inside int64."""


def _within(values: np.ndarray, last: int | None, bound: int) -> bool:
    """Whether every value (and the last one before them) lies strictly between -bound and bound."""
    low, high = int(values.min()), int(values.max())
    if last is not None:
        low, high = min(low, last), max(high, last)
    return low > -bound and high < bound


class _PublisherState:
    """What a subscription remembers of one publisher across windows, its current window and its unfolded samples."""

    __slots__ = ("last_receive", "last_seq", "receives", "sequences", "sources", "window")

    def __init__(self) -> None:
        self.last_seq: int | None = None
        self.last_receive: int | None = None
        self.window = PublisherWindow()
        self.sequences = array("q")
        self.sources = array("q")
        self.receives = array("q")

    def add_exact(self, sequence_number: int, source_ns: int, receive_ns: int) -> int:
        """Fold one sample into the window (Welford); returns the sequence gap it counted as dropped."""
        window = self.window
        window.delivered += 1
        gap = 0
        previous = self.last_seq
        if previous is None or sequence_number > previous:
            if previous is not None and sequence_number > previous + 1:
                gap = sequence_number - previous - 1
                window.dropped += gap
            self.last_seq = sequence_number
        if self.last_receive is not None:
            window.period.add(receive_ns - self.last_receive)
        self.last_receive = receive_ns
        window.age.add(receive_ns - source_ns)
        return gap

    def fold(self) -> tuple[int, int]:
        """Fold the gathered samples into the window, in arrival order; returns (delivered, dropped) added."""
        count = len(self.receives)
        if count == 0:
            return 0, 0
        sequences = np.frombuffer(self.sequences, dtype=np.int64)
        sources = np.frombuffer(self.sources, dtype=np.int64)
        receives = np.frombuffer(self.receives, dtype=np.int64)
        exact = count < _EXACT_BELOW or not (
            _within(sequences, self.last_seq, _SAFE)
            and _within(sources, None, 2**62)
            and _within(receives, self.last_receive, 2**62)
        )
        if exact:
            dropped = 0
            for sequence_number, source_ns, receive_ns in zip(
                self.sequences.tolist(), self.sources.tolist(), self.receives.tolist(), strict=True
            ):
                dropped += self.add_exact(sequence_number, source_ns, receive_ns)
        else:
            dropped = self._fold_vectorised(sequences, sources, receives)
        del sequences, sources, receives  # views of the arrays: an array that exports its buffer cannot shrink
        del self.sequences[:], self.sources[:], self.receives[:]
        return count, dropped

    def _fold_vectorised(self, sequences: np.ndarray, sources: np.ndarray, receives: np.ndarray) -> int:
        window = self.window
        window.delivered += len(receives)
        # The last sequence number is the running maximum: a sample above it by more than one shows a gap.
        if self.last_seq is None:
            before = np.maximum.accumulate(sequences)[:-1]
            gaps = sequences[1:] - before - 1
        else:
            before = np.maximum.accumulate(np.concatenate(([self.last_seq], sequences)))[:-1]
            gaps = sequences - before - 1
        dropped = int(gaps[gaps > 0].sum())
        window.dropped += dropped
        self.last_seq = max(int(sequences.max()), self.last_seq if self.last_seq is not None else -(2**63))
        periods = np.diff(receives) if self.last_receive is None else np.diff(receives, prepend=self.last_receive)
        self.last_receive = int(receives[-1])
        for stats, values in ((window.period, periods), (window.age, receives - sources)):
            if len(values):
                floats = values.astype(np.float64)
                mean = float(floats.mean())
                stats.merge(len(values), mean, float(np.square(floats - mean).sum()), int(values.max()))
        return dropped


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
        self._total_delivered = 0
        self._total_dropped = 0
        self.total_errors = 0
        self.evicted = 0
        """Publishers forgotten because the table was full."""

    @property
    def publishers(self) -> int:
        """GIDs tracked now."""
        with self._lock:
            return len(self._publishers)

    @property
    def total_delivered(self) -> int:
        """Samples delivered since the subscription began (all windows)."""
        with self._lock:
            self._fold_all()
            return self._total_delivered

    @property
    def total_dropped(self) -> int:
        """Samples missing from the publishers' sequence numbers since the subscription began."""
        with self._lock:
            self._fold_all()
            return self._total_dropped

    def _fold(self, state: _PublisherState) -> None:
        delivered, dropped = state.fold()
        self._total_delivered += delivered
        self._total_dropped += dropped

    def _fold_all(self) -> None:
        for state in self._publishers.values():
            self._fold(state)
        self._fold(self._others)

    def _state(self, gid: bytes) -> _PublisherState:
        if gid == self._last_gid:
            return self._last_state
        if gid == _NO_GID:
            return self._others
        state = self._publishers.get(gid)
        if state is None:
            if len(self._publishers) >= self.max_publishers:
                _, oldest = self._publishers.popitem(last=False)
                self._fold(oldest)
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
            state = self._last_state if gid == self._last_gid else self._state(gid)
            state.window.traffic_bytes += size
            receives = state.receives
            try:
                state.sequences.append(sequence_number)
                state.sources.append(source_ns)
                receives.append(receive_ns)
            except OverflowError:  # beyond int64 (only a direct caller can pass such numbers): fold it exactly
                del state.sequences[len(receives) :], state.sources[len(receives) :]
                self._fold(state)
                self._total_delivered += 1
                self._total_dropped += state.add_exact(sequence_number, source_ns, receive_ns)
                return
            if len(receives) >= FOLD_BATCH:
                self._fold(state)

    def on_samples(
        self,
        gid: bytes,
        sequence_numbers: Sequence[int],
        sources_ns: Sequence[int],
        receives_ns: Sequence[int],
        size: int,
    ) -> None:
        """Record a run of delivered samples of one publisher, in arrival order (``size``: their bytes in all);
        the same as :meth:`on_sample` for each of them, for one lock and one lookup."""
        # Packed in one call per column and appended as bytes: array.extend converts int by int (0.1 µs more per
        # sample for the three columns).
        layout = f"{len(receives_ns)}q"  # native int64s, the arrays' own layout
        try:
            columns = (_pack(layout, *sequence_numbers), _pack(layout, *sources_ns), _pack(layout, *receives_ns))
        except struct.error:  # beyond int64 (forged): the run goes in sample by sample, exactly
            columns = None
        with self._lock:
            state = self._last_state if gid == self._last_gid else self._state(gid)
            exact = columns is None
            if columns is not None:
                state.sequences.frombytes(columns[0])
                state.sources.frombytes(columns[1])
                state.receives.frombytes(columns[2])
                state.window.traffic_bytes += size
                if len(state.receives) >= FOLD_BATCH:
                    self._fold(state)
        if exact:
            for sequence_number, source_ns, receive_ns in zip(sequence_numbers, sources_ns, receives_ns, strict=True):
                self.on_sample(gid, sequence_number, source_ns, receive_ns, 0)
            with self._lock:
                self._state(gid).window.traffic_bytes += size

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
            state = self._state(gid)
            self._fold(state)
            window = state.window
            if window.delivered > 0:  # else it was delivered in the previous window; leave that report as sent
                window.delivered -= 1
                self._total_delivered -= 1
            window.errors += 1
            self.total_errors += 1

    def close_window(self, now_ns: int) -> list[WindowReport]:
        """Reports of the window that ends now (only publishers with activity), and start a new window."""
        with self._lock:
            self._fold_all()
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
