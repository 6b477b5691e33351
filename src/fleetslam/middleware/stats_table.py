"""Aggregation of /statistics reports into per-agent, per-topic rows (for `fleetslam stats` and the station)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.msg.typesys import ns_from_stamp


@dataclass(frozen=True)
class StatsRow:
    """One window of one (topic, publisher node, subscriber node) pair, or all its windows summed
    (:meth:`StatsTable.totals`)."""

    agent: str
    topic: str
    type: str
    node_pub: str
    node_sub: str
    window_s: float
    bandwidth_bps: float
    """Bytes per second over the window."""
    delivered: int
    dropped: int
    errors: int
    rate_hz: float
    age_mean_ms: float
    age_std_ms: float
    age_max_ms: float
    period_mean_ms: float
    period_std_ms: float
    period_max_ms: float
    stamp_ns: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def row_from_message(msg: Any) -> StatsRow:
    """A row from a fleetslam_msgs/msg/TopicStatistics."""
    start, stop = ns_from_stamp(msg.window_start), ns_from_stamp(msg.window_stop)
    window_s = max((stop - start) / 1e9, 1e-9)
    agent = msg.agent_pub or msg.topic.strip("/").split("/")[0]
    return StatsRow(
        agent=agent,
        topic=msg.topic,
        type=msg.type,
        node_pub=msg.node_pub,
        node_sub=msg.node_sub,
        window_s=window_s,
        bandwidth_bps=msg.traffic / window_s,
        delivered=int(msg.delivered_msgs),
        dropped=int(msg.dropped_msgs),
        errors=int(msg.error_msgs),
        rate_hz=msg.delivered_msgs / window_s,
        age_mean_ms=ns_from_stamp(msg.stamp_age_mean) / 1e6,
        age_std_ms=ns_from_stamp(msg.stamp_age_stddev) / 1e6,
        age_max_ms=ns_from_stamp(msg.stamp_age_max) / 1e6,
        period_mean_ms=ns_from_stamp(msg.period_mean) / 1e6,
        period_std_ms=ns_from_stamp(msg.period_stddev) / 1e6,
        period_max_ms=ns_from_stamp(msg.period_max) / 1e6,
        stamp_ns=stop,
    )


class _RunTotals:
    """Every window of one (topic, publisher node, subscriber node) pair, summed: counts and bytes, and the age and
    period pooled as the moments of all the messages behind each window's mean and standard deviation."""

    def __init__(self, first: StatsRow) -> None:
        self.latest = first
        self.start_ns = first.stamp_ns - int(first.window_s * 1e9)
        self.traffic = self.delivered = self.dropped = self.errors = 0.0
        self.age, self.period = np.zeros(3), np.zeros(3)
        self.age_max_ms = self.period_max_ms = 0.0

    def add(self, row: StatsRow) -> None:
        self.latest = row
        self.start_ns = min(self.start_ns, row.stamp_ns - int(row.window_s * 1e9))
        self.traffic += row.bandwidth_bps * row.window_s
        self.delivered += row.delivered
        self.dropped += row.dropped
        self.errors += row.errors
        n = row.delivered
        self.age += (n, n * row.age_mean_ms, n * (row.age_std_ms**2 + row.age_mean_ms**2))
        self.period += (n, n * row.period_mean_ms, n * (row.period_std_ms**2 + row.period_mean_ms**2))
        self.age_max_ms = max(self.age_max_ms, row.age_max_ms)
        self.period_max_ms = max(self.period_max_ms, row.period_max_ms)

    def row(self) -> StatsRow:
        # The span from the first window's start to the latest's stop, not the sum of the windows: a window without
        # traffic is not reported, and a window closed late by a busy executor is followed by a short one.
        span_s = max((self.latest.stamp_ns - self.start_ns) / 1e9, 1e-9)
        (age_mean, age_std), (period_mean, period_std) = _pooled(self.age), _pooled(self.period)
        return replace(
            self.latest,
            window_s=span_s,
            bandwidth_bps=self.traffic / span_s,
            delivered=int(self.delivered),
            dropped=int(self.dropped),
            errors=int(self.errors),
            rate_hz=self.delivered / span_s,
            age_mean_ms=age_mean,
            age_std_ms=age_std,
            age_max_ms=self.age_max_ms,
            period_mean_ms=period_mean,
            period_std_ms=period_std,
            period_max_ms=self.period_max_ms,
        )


def _pooled(moments: NDArray[np.float64]) -> tuple[float, float]:
    """Mean and standard deviation from (count, sum, sum of squares)."""
    n, total, squares = moments
    if n <= 0:
        return 0.0, 0.0
    mean = total / n
    return float(mean), float(np.sqrt(max(squares / n - mean**2, 0.0)))


class StatsTable:
    """Latest row per (topic, node_pub, node_sub), rows older than ``stale_s`` dropped on read; and every window
    summed per pair since the table was made (:meth:`totals`)."""

    def __init__(self, stale_s: float = 5.0) -> None:
        self._rows: dict[tuple[str, str, str], StatsRow] = {}
        self._totals: dict[tuple[str, str, str], _RunTotals] = {}
        self._stale_ns = int(stale_s * 1e9)

    def update(self, msg: Any) -> StatsRow:
        row = row_from_message(msg)
        key = (row.topic, row.node_pub, row.node_sub)
        self._rows[key] = row
        self._totals.setdefault(key, _RunTotals(row)).add(row)
        return row

    def totals(self) -> list[StatsRow]:
        """One row per pair over every window it reported: counts summed, kB/s and Hz over the span from its first
        window's start to its latest window's stop, age and period pooled over the messages. One window is a second
        of traffic; a run's report wants the whole run."""
        return sorted((t.row() for t in self._totals.values()), key=lambda r: (r.agent, r.topic, r.node_sub))

    def rows(self, *, agent: str | None = None, now_ns: int | None = None) -> list[StatsRow]:
        rows = list(self._rows.values())
        if now_ns is not None:
            rows = [r for r in rows if now_ns - r.stamp_ns <= self._stale_ns]
        if agent:
            rows = [r for r in rows if r.agent == agent or r.node_sub.strip("/").split("/")[0] == agent]
        return sorted(rows, key=lambda r: (r.agent, r.topic, r.node_sub))

    def per_agent(self, **kwargs: Any) -> dict[str, dict[str, float]]:
        """Totals per publishing agent: bandwidth, delivered, dropped, errors."""
        totals: dict[str, dict[str, float]] = {}
        for row in self.rows(**kwargs):
            t = totals.setdefault(row.agent, {"bandwidth_bps": 0.0, "delivered": 0, "dropped": 0, "errors": 0})
            t["bandwidth_bps"] += row.bandwidth_bps
            t["delivered"] += row.delivered
            t["dropped"] += row.dropped
            t["errors"] += row.errors
        return totals


def format_table(rows: list[StatsRow]) -> str:
    """A text table grouped by agent."""
    header = (
        f"{'topic':<34} {'pub → sub':<40} {'kB/s':>9} {'Hz':>7} {'deliv':>6} {'drop':>5} {'err':>4} "
        f"{'age ms':>13} {'period ms':>13}"
    )
    lines: list[str] = []
    current = None
    for row in rows:
        if row.agent != current:
            current = row.agent
            lines += ["", f"agent {current or '(root)'}", header]
        link = f"{row.node_pub or '?'} → {row.node_sub}"
        lines.append(
            f"{row.topic:<34} {link:<40} {row.bandwidth_bps / 1e3:>9.1f} {row.rate_hz:>7.1f} {row.delivered:>6} "
            f"{row.dropped:>5} {row.errors:>4} {row.age_mean_ms:>6.1f}±{row.age_std_ms:<6.1f}"
            f"{row.period_mean_ms:>6.1f}±{row.period_std_ms:<6.1f}"
        )
    return "\n".join(lines).lstrip("\n")
