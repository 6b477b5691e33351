"""The statistics table: the latest window per pair, and every window of a run summed."""

import statistics as pystats

import numpy as np
import pytest

from fleetslam.middleware.stats_table import StatsTable
from fleetslam.msg.typesys import duration_from_ns, get_type, stamp_from_ns

SECOND = 1_000_000_000


def _window(start_s: float, stop_s: float, ages_ms: list[float], size: int, dropped: int = 0) -> object:
    """A TopicStatistics report of one window of /c3po/fleet_path from /fleet_backend to /c3po/slam."""
    mean = pystats.fmean(ages_ms) if ages_ms else 0.0
    std = pystats.pstdev(ages_ms) if ages_ms else 0.0
    return get_type("fleetslam_msgs/msg/TopicStatistics")(
        topic="/c3po/fleet_path",
        type="nav_msgs/msg/Path",
        node_pub="/fleet_backend",
        node_sub="/c3po/slam",
        agent_pub="fleet_backend",
        agent_sub="c3po",
        publisher_gid=np.zeros(16, np.uint8),
        window_start=stamp_from_ns(int(start_s * SECOND)),
        window_stop=stamp_from_ns(int(stop_s * SECOND)),
        delivered_msgs=len(ages_ms),
        dropped_msgs=dropped,
        error_msgs=0,
        traffic=size * len(ages_ms),
        period_mean=duration_from_ns(SECOND),
        period_stddev=duration_from_ns(0),
        period_max=duration_from_ns(SECOND),
        stamp_age_mean=duration_from_ns(int(mean * 1e6)),
        stamp_age_stddev=duration_from_ns(int(std * 1e6)),
        stamp_age_max=duration_from_ns(int(max(ages_ms, default=0.0) * 1e6)),
    )


def test_run_totals_span_the_run_where_the_latest_window_is_a_short_one() -> None:
    """A 1 Hz topic: a window closed late by a busy executor (1.0–1.92 s) is followed by a short one holding one
    message, and a second without traffic reports nothing. The latest window reads 12.5 Hz; the run 1 Hz."""
    table = StatsTable(stale_s=1e9)
    ages = [[2.0], [4.0], [3.0], [9.0]]
    for (start, stop), window_ages in zip([(0.0, 1.0), (1.0, 1.92), (1.92, 2.0), (3.0, 4.0)], ages, strict=True):
        table.update(_window(start, stop, window_ages, size=50_000, dropped=1 if start == 3.0 else 0))
    (latest,) = table.rows()
    assert latest.rate_hz == pytest.approx(1.0)  # the window 3–4 s
    (run,) = table.totals()
    assert run.window_s == pytest.approx(4.0)
    assert run.delivered == 4 and run.dropped == 1
    assert run.rate_hz == pytest.approx(1.0)
    assert run.bandwidth_bps == pytest.approx(50_000.0)
    every_age = [a for window in ages for a in window]
    assert run.age_mean_ms == pytest.approx(pystats.fmean(every_age), abs=1e-6)
    assert run.age_std_ms == pytest.approx(pystats.pstdev(every_age), abs=1e-6)
    assert run.age_max_ms == pytest.approx(9.0)
    assert (run.topic, run.node_pub, run.node_sub) == ("/c3po/fleet_path", "/fleet_backend", "/c3po/slam")


def test_run_totals_pool_windows_of_several_messages_and_keep_pairs_apart() -> None:
    table = StatsTable()
    first, second = [1.0, 3.0, 5.0], [10.0, 20.0]
    table.update(_window(0.0, 1.0, first, size=100))
    table.update(_window(1.0, 2.0, second, size=100))
    other = _window(0.0, 2.0, [7.0], size=10)
    other.node_sub = "/c3po/mapping"
    table.update(other)
    totals = {r.node_sub: r for r in table.totals()}
    assert set(totals) == {"/c3po/slam", "/c3po/mapping"}
    slam = totals["/c3po/slam"]
    assert slam.delivered == 5 and slam.rate_hz == pytest.approx(2.5)
    assert slam.age_mean_ms == pytest.approx(pystats.fmean(first + second), abs=1e-6)
    assert slam.age_std_ms == pytest.approx(pystats.pstdev(first + second), abs=1e-6)
    assert totals["/c3po/mapping"].rate_hz == pytest.approx(0.5)
