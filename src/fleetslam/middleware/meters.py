"""Rate and bandwidth meters over a sliding window of samples (for `topic hz` / `topic bw`)."""

from __future__ import annotations

import collections
import itertools
import math
from dataclasses import dataclass


@dataclass(frozen=True)
class RateReport:
    """As `ros2 topic hz` prints it."""

    rate_hz: float
    min_period_s: float
    max_period_s: float
    std_period_s: float
    window: int


@dataclass(frozen=True)
class BandwidthReport:
    """As `ros2 topic bw` prints it."""

    bytes_per_s: float
    mean_size: float
    min_size: int
    max_size: int
    window: int


class RateMeter:
    """Message rate from receive times (seconds) over the last ``window`` messages."""

    def __init__(self, window: int = 100) -> None:
        self._times: collections.deque[float] = collections.deque(maxlen=window + 1)

    def add(self, t: float) -> None:
        self._times.append(t)

    def report(self) -> RateReport | None:
        if len(self._times) < 2:
            return None
        times = list(self._times)
        periods = [b - a for a, b in itertools.pairwise(times)]
        mean = sum(periods) / len(periods)
        std = math.sqrt(sum((p - mean) ** 2 for p in periods) / len(periods))
        return RateReport(1.0 / mean if mean > 0 else math.inf, min(periods), max(periods), std, len(periods))


class BandwidthMeter:
    """Bytes per second from (receive time, size) over the last ``window`` messages."""

    def __init__(self, window: int = 100) -> None:
        self._samples: collections.deque[tuple[float, int]] = collections.deque(maxlen=window)

    def add(self, t: float, size: int) -> None:
        self._samples.append((t, size))

    def report(self, now: float) -> BandwidthReport | None:
        if not self._samples:
            return None
        sizes = [s for _, s in self._samples]
        span = max(now - self._samples[0][0], 1e-9)
        return BandwidthReport(sum(sizes) / span, sum(sizes) / len(sizes), min(sizes), max(sizes), len(sizes))


def human_bytes(value: float) -> str:
    """1536 → '1.50 KB' (binary multiples, as ros2 topic bw)."""
    for unit in ("B", "KB", "MB", "GB"):
        if abs(value) < 1024 or unit == "GB":
            return f"{value:.2f} {unit}" if unit != "B" else f"{value:.0f} B"
        value /= 1024
    return f"{value:.2f} GB"
